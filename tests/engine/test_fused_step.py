"""The one-launch cloth step (engine.integrators.cloth_kernels.cloth_step) does the generic path's
arithmetic in another order of loops but the same order of terms per vertex, so the states agree
bit for bit: symplectic Euler and velocity Verlet, with and without bending, for any number of
vertex blocks, launched directly or through Taichi's own call; and the two-pass membrane step likewise."""
import numpy as np
import pytest

from engine import tickets
from engine.integrators import cloth_kernels as C
from engine import launch
from engine.launch import BoundKernel
from engine.integrators.explicit import SymplecticEuler, VelocityVerlet, cloth_blocks, cloth_plan, cloth_stepper
from engine.integrators.stepper import Stepper
from engine.model import Model
from engine.scenes import cloth
from engine.stability import stable_dt_estimate

INTEGRATORS = {"symplectic-euler": SymplecticEuler, "velocity-verlet": VelocityVerlet}


def run(model, v0, dt, n, method, fused):
    st = model.make_state(None, v0)
    Stepper(model, INTEGRATORS[method](fused)).step(st, dt, n)
    s = st.numpy()
    return s.x, s.v, st.t


def one_launch_plan(model, method="symplectic-euler"):
    """The fast step (FastStep) a Stepper plans for ``method`` on ``model`` (None: generic path)."""
    return Stepper(model, INTEGRATORS[method]()).fast


def start(model, seed=3, scale=0.05):
    return scale * np.random.default_rng(seed).standard_normal((model.n, 3))


@pytest.mark.parametrize("method", list(INTEGRATORS))
@pytest.mark.parametrize("B,variant", [(1e-3, "notes"), (1e-3, "bridson"), (0.0, "notes")])
def test_fused_step_is_bitwise_the_generic_step(B, variant, method):
    model = cloth(12, B=B, variant=variant).model
    assert one_launch_plan(model) is not None
    v0 = start(model)
    dt = 0.5 * stable_dt_estimate(model)
    xa, va, ta = run(model, v0, dt, 150, method, True)
    xb, vb, tb = run(model, v0, dt, 150, method, False)
    assert np.array_equal(xa, xb) and np.array_equal(va, vb) and ta == tb
    assert np.abs(xa - model.X).max() > 1e-3  # it moved: the comparison is not vacuous
    pinned = model.pinned
    assert np.array_equal(xa[pinned], model.X[pinned]) and not va[pinned].any()


@pytest.mark.parametrize("method", list(INTEGRATORS))
def test_any_number_of_blocks_gives_the_same_bits(method):
    """Blocks split the vertices; springs and hinges across a block boundary are computed by both
    blocks, boundary vertices move after the loop. 1 block (one thread), 2, 5 and 9 (more than
    the machine has threads: one thread does several) all give the generic path's state."""
    c = cloth(16, B=1e-3, variant="discrete-shells")
    model = c.model
    v0 = start(model, seed=5)
    dt = 0.5 * stable_dt_estimate(model)
    x_ref, v_ref, _ = run(model, v0, dt, 40, method, False)
    for nb in (1, 2, 5, 9):
        I, F, n_boundary = cloth_plan(model, nb)
        assert (n_boundary > 0) == (nb > 1)
        step = cloth_stepper(model, method, nb)
        st = model.make_state(None, v0)
        step.begin(st)
        for _ in range(40):
            step.step(st, dt)
        s = st.numpy()
        assert np.array_equal(s.x, x_ref) and np.array_equal(s.v, v_ref), nb


@pytest.mark.parametrize("method", list(INTEGRATORS))
def test_many_steps_in_one_launch_give_the_same_bits(method):
    """step(n) runs all n steps in one launch (cloth_kernels.cloth_steps: each block stays on its thread and
    the threads meet at a barrier where a step's loop would end): the same state as n launches of
    one step and as the generic path. 24 x 24 vertices: two blocks on a two-thread runtime."""
    from engine import runtime
    model = cloth(24, B=1e-3).model
    v0 = start(model, seed=13)
    dt = 0.5 * stable_dt_estimate(model)
    one = one_launch_plan(model, method)
    st = model.make_state(None, v0)
    one.begin(st)
    one.step(st, dt, 25)
    x_ref, v_ref, _ = run(model, v0, dt, 25, method, False)
    s = st.numpy()
    assert np.array_equal(s.x, x_ref) and np.array_equal(s.v, v_ref)
    assert cloth_blocks(model.n) == min(2, runtime.current().threads)


def test_many_steps_kernel_with_more_blocks_than_threads():
    """cloth_steps' tasks are taken by whichever thread is free: with more blocks than the runtime
    has threads (some threads do several blocks' tasks) it still gives the generic path's state;
    with no waiting allowed (poll limit 0) it gives up at once and says so."""
    from engine import runtime
    from engine.fields import int_ndarray, vec3_ndarray
    model = cloth(24, B=1e-3).model
    v0 = start(model, seed=19)
    dt = 0.5 * stable_dt_estimate(model)
    I, F, _ = cloth_plan(model, runtime.current().threads + 3)
    w, sync = vec3_ndarray(4 * model.n), int_ndarray(np.zeros(tickets.SYNC_SIZE))
    steps = BoundKernel(C.cloth_steps, (w, I, F, sync, tickets.SPIN_LIMIT), (C.CLOTH_SE, True))
    st = model.make_state(None, v0)
    assert steps(st.x, st.v, dt, 20) == 0
    x_ref, v_ref, _ = run(model, v0, dt, 20, "symplectic-euler", False)
    s = st.numpy()
    assert np.array_equal(s.x, x_ref) and np.array_equal(s.v, v_ref)
    impatient = BoundKernel(C.cloth_steps, (w, I, F, sync, 0), (C.CLOTH_SE, True))
    assert impatient(st.x, st.v, dt, 3) == 1


@pytest.mark.parametrize("scene,method", [("cloth", "symplectic-euler"), ("membrane", "velocity-verlet")])
def test_direct_launch_is_taichis_launch(monkeypatch, scene, method):
    """The bound launch sets the same arguments as Taichi's own kernel call: the same bits (the
    one-launch cloth step, and the two-pass membrane step)."""
    model = cloth(10, B=1e-3).model if scene == "cloth" else _membrane_cloth(10, "baraff-witkin")
    v0 = start(model, seed=7)
    dt = 0.5 * stable_dt_estimate(model)
    xa, va, _ = run(model, v0, dt, 30, method, True)
    monkeypatch.setattr(launch, "DIRECT_LAUNCH", False)
    xb, vb, _ = run(model, v0, dt, 30, method, True)
    assert np.array_equal(xa, xb) and np.array_equal(va, vb)


@pytest.mark.parametrize("how", ["step", "advance"])
def test_new_spring_coefficients_reach_the_fused_step(how):
    """The plan copies c/L; after SpringEnergy.set_coefficients a Stepper plans again, whether it is
    driven by step() or step by step by advance()."""
    c = cloth(10, B=1e-3)
    model = c.model
    v0 = start(model, seed=9)
    dt = 0.25 * stable_dt_estimate(model)
    stepper = Stepper(model, SymplecticEuler(True))
    first = stepper.fast

    def take(st, n):
        if how == "step":
            stepper.step(st, dt, n)
        else:   # symplectic Euler's begin prepares nothing: advance alone, as a caller stepping by hand
            for _ in range(n):
                stepper.advance(st, dt)
    take(model.make_state(None, v0), 5)   # the plan for the first c
    c.springs.set_coefficients(2.0 * c.springs.c_np)
    st = model.make_state(None, v0)
    take(st, 30)
    assert stepper.fast is not first
    xa, va = st.numpy().x, st.numpy().v
    xb, vb, _ = run(model, v0, dt, 30, "symplectic-euler", False)
    assert np.array_equal(xa, xb) and np.array_equal(va, vb)


def test_new_spring_coefficients_reach_an_implicit_steppers_forces():
    """An implicit stepper's one-launch forces copy c/L too: after set_coefficients its next advance
    plans again and steps as a new stepper does, bit for bit."""
    from engine.integrators import BackwardEuler
    c = cloth(10, B=1e-3)
    model = c.model
    v0 = start(model, seed=9)
    stepper = Stepper(model, BackwardEuler(solver="cholesky", tol=1e-10))
    first = stepper.context.forces
    stepper.advance(model.make_state(None, v0), 1e-2)
    c.springs.set_coefficients(2.0 * c.springs.c_np)
    st = model.make_state(None, v0)
    stepper.advance(st, 1e-2)
    assert stepper.context.forces is not first
    ref = model.make_state(None, v0)
    Stepper(model, BackwardEuler(solver="cholesky", tol=1e-10)).advance(ref, 1e-2)
    assert np.array_equal(st.numpy().x, ref.numpy().x) and np.array_equal(st.numpy().v, ref.numpy().v)


def test_repeated_edges_and_an_unordered_incidence():
    """Two springs between the same vertices: when both ends list them in the same order the block
    sweep sums them in that order (fused = generic); when the ends list them in opposite orders
    (edges (1, 2) and (2, 1): each end lists its own first) no single order serves both ends, so
    the planner refuses and the step takes the generic path. So it does when the incidence is not
    in neighbour order at all."""
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2], [2, 0.5, 0]])
    E = [[0, 1], [1, 2], [2, 0], [1, 3], [3, 2], [3, 4], [4, 1], [1, 3]]
    for edges, planned in ((E, True), (E + [[2, 1]], False)):
        model = Model.from_springs(X, np.array(edges), k=50.0, mass=0.1, pinned=[0], gravity=[0, 0, -9.81])
        assert (one_launch_plan(model) is not None) == planned
        v0 = start(model, seed=11, scale=0.3)
        xa, va, _ = run(model, v0, 1e-3, 200, "symplectic-euler", True)
        xb, vb, _ = run(model, v0, 1e-3, 200, "symplectic-euler", False)
        assert np.array_equal(xa, xb) and np.array_equal(va, vb) and np.abs(xa - X).max() > 1e-3

    model = Model.from_springs(X, np.array(E), k=50.0, mass=0.1, pinned=[0])
    sp = model.springs
    off = sp.offsets_np
    for arr in (sp.inc_other_np, sp.inc_edge_np):  # each vertex's incidences in reverse
        for i in range(model.n):
            arr[off[i]:off[i + 1]] = arr[off[i]:off[i + 1]][::-1].copy()
    assert cloth_plan(model, 1) is None


def test_models_without_springs_first_take_the_generic_path():
    c = cloth(6, B=1e-3)
    bending_only = Model(c.model.X, c.model.mass, c.model.pinned, c.model.gravity)
    bending_only.add_energy(c.bending)
    assert one_launch_plan(bending_only) is None
    v0 = 0.01 * np.ones((bending_only.n, 3))
    x, v, _ = run(bending_only, v0, 1e-4, 20, "symplectic-euler", True)  # still steps, on the generic path:
    xg, vg, _ = run(bending_only, v0, 1e-4, 20, "symplectic-euler", False)  # bitwise the generic path's
    assert np.array_equal(x, xg) and np.array_equal(v, vg)
    assert np.abs(x - bending_only.X).max() > 0


def test_the_hinge_angle_is_atan2_to_an_ulp():
    """Both paths take the hinge angle from engine.energies.hinge.fast_atan2: a polynomial for
    |y| < x/8, the C library's atan2 elsewhere. Against numpy's arctan2 (the C library's) it is
    within 1 ulp everywhere, inside the polynomial's range and out of it, and exact at zero."""
    import taichi as ti
    from engine.energies.hinge import fast_atan2
    from engine.fields import float_dtype, scalar_ndarray

    @ti.kernel
    def angles(y: ti.types.ndarray(ndim=1), x: ti.types.ndarray(ndim=1), out: ti.types.ndarray(ndim=1)):
        for i in range(y.shape[0]):
            out[i] = fast_atan2(y[i], x[i])

    fdt = float_dtype()
    rng = np.random.default_rng(17)
    t = np.concatenate([np.linspace(-0.2, 0.2, 4001), rng.uniform(-50, 50, 2000), [0.0, 1e-300, -1e-300]])
    x = np.concatenate([rng.uniform(0.1, 10.0, len(t) - 3), [1.0, 1.0, 1.0]])
    x[::7] *= -1.0  # the other half-plane: the library's branch
    y = (t * x).astype(fdt)
    x = x.astype(fdt)
    out = scalar_ndarray(np.zeros(len(x)))
    angles(scalar_ndarray(y), scalar_ndarray(x), out)
    got, ref = out.to_numpy(), np.arctan2(y, x)
    ulp = np.spacing(np.abs(ref).astype(fdt))
    assert np.all(np.abs(got - ref) <= ulp) and got[-3] == 0.0
    assert np.mean(np.abs(y) < np.abs(x) / 8) > 0.3  # the polynomial's branch is exercised


# -- the two-pass membrane step (engine.integrators.explicit.corner_stepper) -----------------------

def _membrane_cloth(side, model_name, damping=0.0):
    from engine.energies.membrane import MembraneEnergy
    c = cloth(side, B=0.0)
    model = Model(c.model.X, mass=c.model.mass, pinned=np.flatnonzero(c.model.pinned), gravity=c.model.gravity)
    params = (dict(Y=1e3, nu=0.3) if model_name == "stvk" else
              dict(k_stretch=1e3, k_shear=5e2, damping_stretch=damping, damping_shear=damping))
    model.add_energy(MembraneEnergy.from_mesh(c.mesh, model_name, **params))
    return model


@pytest.mark.parametrize("method", list(INTEGRATORS))
@pytest.mark.parametrize("model_name", ["stvk", "baraff-witkin"])
def test_two_pass_membrane_step_is_bitwise_the_generic_step(model_name, method):
    """A membrane model takes the two-pass step (its triangle kernel, then gather + update in one
    loop, both bound launches): the same bits as the generic path (forces kernel, zeroing, gather,
    update through Taichi's own call), launched directly or through Taichi's call."""
    model = _membrane_cloth(12, model_name)
    stepper = Stepper(model, INTEGRATORS[method]())
    assert stepper.path == "two-pass"
    v0 = start(model, seed=4)
    dt = 0.5 * stable_dt_estimate(model)
    xa, va, ta = run(model, v0, dt, 120, method, True)
    xb, vb, tb = run(model, v0, dt, 120, method, False)
    assert np.array_equal(xa, xb) and np.array_equal(va, vb) and ta == tb
    assert np.abs(xa - model.X).max() > 1e-3
    assert np.array_equal(xa[model.pinned], model.X[model.pinned]) and not va[model.pinned].any()


def test_damped_membranes_and_forward_euler_take_the_generic_path():
    """Baraff-Witkin damping is velocity-dependent (the generic path adds -D v); forward Euler has no
    fast step: both are planned generic."""
    from engine.integrators.explicit import ForwardEuler
    assert Stepper(_membrane_cloth(6, "baraff-witkin", damping=1.0), SymplecticEuler()).path == "generic"
    assert Stepper(_membrane_cloth(6, "baraff-witkin"), ForwardEuler()).path == "generic"


@pytest.mark.parametrize("B,variant", [(1e-3, "notes"), (1e-3, "discrete-shells"), (0.0, "notes")])
def test_one_launch_forces_are_bitwise_the_models_forces(B, variant):
    """engine.integrators.explicit.cloth_forces (what an implicit stepper's Newton residual uses for
    springs [+ one hinge energy]) gives Model.forces' bits: the weight added, pinned vertices 0,
    for any number of blocks; an implicit stepper plans it, a membrane's keeps Model.forces."""
    from engine.fields import vec3_ndarray
    from engine.integrators import BackwardEuler
    from engine.integrators.explicit import cloth_forces
    model = cloth(16, B=B, variant=variant).model
    x = model.make_state(model.X + start(model, seed=7)).x
    ref, got = vec3_ndarray(model.n), vec3_ndarray(model.n)
    model.forces(x, ref)
    f_ref = ref.to_numpy()
    assert not f_ref[model.pinned].any() and np.abs(f_ref).max() > 1.0   # not vacuous: pins and real forces
    for nb in (1, 2, 5):
        cloth_forces(model, nb)(x, got)
        assert np.array_equal(got.to_numpy(), f_ref), nb
    stepper = Stepper(model, BackwardEuler(solver="cholesky"))
    assert stepper.context.forces is not model.forces
    stepper.context.forces(x, got)
    assert np.array_equal(got.to_numpy(), f_ref)
    membrane = _membrane_cloth(8, "baraff-witkin")
    assert Stepper(membrane, BackwardEuler(solver="cholesky")).context.forces == membrane.forces
