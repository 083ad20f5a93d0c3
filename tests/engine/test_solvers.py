"""Linear solvers of engine.solvers: PCG (every code path) and sparse Cholesky against a dense
scipy solve of the same filtered system (M/dt^2 + H, pinned rows and columns eliminated)."""
import math

import numpy as np
import pytest
import scipy.linalg as sla

from engine import mesh, solvers
from engine.energies.base import stencil_triplets
from engine.energies.bending import BendingEnergy
from engine.energies.springs import SpringEnergy
from engine.solvers import SolverError, make_solver
from engine.fields import vec3_ndarray
from engine.model import Model


def spring_network(seed=0):
    """A 4x4x2 block of springs (3D), pinned at two vertices, randomly deformed (some springs
    compressed, so the PSD clamp is active)."""
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(2), indexing="ij"), -1).reshape(-1, 3) * 0.1
    n = len(g)
    d = np.linalg.norm(g[:, None] - g[None], axis=-1)
    i, j = np.nonzero(np.triu((d > 0) & (d < 0.15)))
    rng = np.random.default_rng(seed)
    model = Model.from_springs(g, np.stack([i, j], 1), k=rng.uniform(50, 150, len(i)),
                               mass=rng.uniform(0.05, 0.15, n), pinned=[0, 5], gravity=[0, 0, -9.81])
    x = g + 0.02 * rng.standard_normal(g.shape)
    return model, x


class PlainSprings(SpringEnergy):
    """Springs declaring no fast product: PCG must take its generic matrix-free path."""
    products = frozenset()


class PlainBending(BendingEnergy):
    """Bending declaring no rank-one factors."""
    products = frozenset()


class NoStencilSprings(SpringEnergy):
    """Springs without a per-element block layout: Cholesky cannot assemble them."""
    stencil_size = 0


def cloth(N=6, seed=1, springs=SpringEnergy, bending=BendingEnergy):
    """An N x N cloth with area springs and dihedral bending, pinned at two corners, crumpled
    (``springs`` / ``bending``: the energy classes, None to leave one out)."""
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = m3.vertices
    model = Model(X, mass=mesh.lumped_masses(m3, 0.2), pinned=[0, N - 1], gravity=[0, 0, -9.81])
    if springs is not None:
        model.add_energy(springs.from_rest(X, m3.edges, c=500.0 * mesh.edge_measure(m3)))
    if bending is not None:
        model.add_energy(bending.from_mesh(m3, B=0.05))
    rng = np.random.default_rng(seed)
    x = X + 0.03 * rng.standard_normal(X.shape)
    return model, x


def dense_system(model, x_nd, mass_coef, hess_coef=1.0, psd=True):
    """The filtered system on free dofs, from model.dense_hessian."""
    H = model.dense_hessian(x_nd, psd=psd)
    A = mass_coef * np.diag(np.repeat(model.mass, 3)) + hess_coef * H
    free = np.repeat(model.free, 3)
    return A[np.ix_(free, free)], free


SOLVER_VARIANTS = {
    "pcg": lambda tol: make_solver("pcg", tol=tol),                                     # whole-loop kernel
    "pcg-parallel": lambda tol: solvers.PCGSolver(tol, 1000, serial=False),              # 3 launches / iteration
    "pcg-generic": lambda tol: solvers.PCGSolver(tol, 1000, fused=False),                 # per-energy products
    "cholesky": lambda tol: make_solver("cholesky", tol=tol),
    "pardiso": lambda tol: make_solver("pardiso", tol=tol),                               # f32 factor, f64 refinement
    "pardiso-double": lambda tol: solvers.PardisoSolver(tol, precision="double"),
    "direct": lambda tol: make_solver("direct", tol=tol),
}
NO_PARDISO = "MKL PARDISO not installed (pip install -e '.[fast]')"
needs_pardiso = pytest.mark.skipif(not solvers.pardiso_available(), reason=NO_PARDISO)
DIRECT = ["cholesky", pytest.param("pardiso", marks=needs_pardiso)]


def _variants():
    return [pytest.param(v, marks=needs_pardiso) if v.startswith("pardiso") else v for v in SOLVER_VARIANTS]


def membrane(model_name="baraff-witkin", N=6, seed=2):
    """An N x N sheet with a membrane energy alone ("element-blocks": the PCG's fused paths take its
    per-triangle blocks), pinned at two corners, crumpled."""
    from engine.energies.membrane import MembraneEnergy
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = m3.vertices
    model = Model(X, mass=mesh.lumped_masses(m3, 0.2), pinned=[0, N - 1], gravity=[0, 0, -9.81])
    params = dict(k_stretch=300.0, k_shear=150.0) if model_name == "baraff-witkin" else dict(Y=300.0, nu=0.3)
    model.add_energy(MembraneEnergy.from_mesh(m3, model_name, **params))
    x = X + 0.03 * np.random.default_rng(seed).standard_normal(X.shape)
    return model, x


SCENES = {"springs": spring_network, "cloth": cloth, "bending": lambda: cloth(springs=None),
          "cloth-plain": lambda: cloth(springs=PlainSprings, bending=PlainBending),
          "membrane": membrane, "membrane-stvk": lambda: membrane("stvk")}


@pytest.mark.parametrize("variant", _variants())
@pytest.mark.parametrize("scene", list(SCENES))
def test_solvers_agree_with_dense_reference(scene, variant):
    model, x = SCENES[scene]()
    x_nd = vec3_ndarray(model.n, x)
    rng = np.random.default_rng(7)
    b = rng.standard_normal((model.n, 3))
    dt = 1e-2
    a, c = 1.0 / dt ** 2, 1.3  # c != 1: a Rayleigh-like Hessian weight
    A, free = dense_system(model, x_nd, a, c)
    y_ref = sla.solve(A, b.reshape(-1)[free], assume_a="pos")
    tol = 1e-10
    solver = SOLVER_VARIANTS[variant](tol)
    y = vec3_ndarray(model.n)
    info = solver.solve(model, x_nd, vec3_ndarray(model.n, b), y, a, c)
    yy = y.to_numpy().reshape(-1)
    # the reported residual is the true one, below tol, and matches the dense residual
    res_dense = np.linalg.norm(A @ yy[free] - b.reshape(-1)[free]) / np.linalg.norm(b.reshape(-1)[free])
    assert info.converged and info.residual <= tol, info
    assert res_dense <= tol
    assert res_dense == pytest.approx(info.residual, rel=1e-3, abs=1e-15)
    # forward error within cond(A) x residual
    cond = np.linalg.cond(A)
    err = np.linalg.norm(yy[free] - y_ref) / np.linalg.norm(y_ref)
    assert err <= cond * max(info.residual, 1e-15) * 1.01, (err, cond, info.residual)
    # pinned unknowns are exactly zero (filtered / eliminated)
    assert np.all(yy[~free] == 0.0)
    if variant.startswith("pcg"):
        assert 1 <= info.iterations < 200
    elif solver.name == "pardiso" and solver.precision == "mixed":
        # an f32 factorisation alone cannot reach 1e-10: at least one f64 refinement step was taken
        assert 2 <= info.iterations <= 1 + solver.refinements and solver.escalations == 0, info
    else:
        assert info.iterations == 1 and info.residual < 1e-13


@pytest.mark.parametrize("name", ["pcg"] + DIRECT)
def test_exact_hessian_option(name):
    """psd=False uses the exact (indefinite) Hessian; with a large mass term the system is still SPD."""
    model, x = spring_network(3)
    x_nd = vec3_ndarray(model.n, x)
    b = np.random.default_rng(0).standard_normal((model.n, 3))
    a = 1e4
    A, free = dense_system(model, x_nd, a, psd=False)
    A_psd, _ = dense_system(model, x_nd, a, psd=True)
    assert np.abs(A - A_psd).max() > 1.0  # some spring is compressed: the two Hessians differ
    y = vec3_ndarray(model.n)
    info = make_solver(name, tol=1e-11).solve(model, x_nd, vec3_ndarray(model.n, b), y, a, psd=False)
    y_ref = np.linalg.solve(A, b.reshape(-1)[free])
    assert info.converged
    assert np.abs(y.to_numpy().reshape(-1)[free] - y_ref).max() <= 1e-9 * np.abs(y_ref).max()


def test_apply_system_matches_dense_product():
    model, x = cloth(5)
    x_nd = vec3_ndarray(model.n, x)
    p = np.random.default_rng(2).standard_normal((model.n, 3))
    p[model.pinned] = 0.0
    q = vec3_ndarray(model.n)
    solvers.apply_system(model, x_nd, vec3_ndarray(model.n, p), q, 50.0, 2.0)
    A, free = dense_system(model, x_nd, 50.0, 2.0)
    qq = q.to_numpy().reshape(-1)
    assert np.abs(qq[free] - A @ p.reshape(-1)[free]).max() <= 1e-12 * np.abs(qq).max()
    assert np.all(qq[~free] == 0.0)


def test_nonconvergent_pcg_is_reported():
    model, x = cloth()
    x_nd = vec3_ndarray(model.n, x)
    b = vec3_ndarray(model.n, np.ones((model.n, 3)))
    solver = make_solver("pcg", tol=1e-10, max_iter=2)
    info = solver.solve(model, x_nd, b, vec3_ndarray(model.n), 1e2)
    assert not info.converged and info.iterations == 2 and info.residual > 1e-10
    with pytest.raises(SolverError) as exc:
        info.check()
    msg = str(exc.value)
    assert "\n" not in msg
    for word in ("pcg", "tol 1.0e-10", f"{info.residual:.3e}", "2 iterations"):
        assert word in msg, msg


@pytest.mark.parametrize("name", DIRECT + [pytest.param("pardiso-double", marks=needs_pardiso)])
def test_direct_solver_reports_indefinite_matrix(name):
    """No mass term and the exact Hessian of a crumpled network: not positive definite, reported by
    each direct solver, PARDISO in both precisions (f32-then-f64 and f64 only): its factorisation is
    the classic one, which reports a non-positive pivot (the two-level one does not: see
    test_two_level_pardiso_misses_a_negative_pivot_that_the_classic_one_reports)."""
    model, x = spring_network(3)
    x_nd = vec3_ndarray(model.n, x)
    b = vec3_ndarray(model.n, np.ones((model.n, 3)))
    solver = solvers.PardisoSolver(1e-8, precision="double") if name == "pardiso-double" else make_solver(name)
    info = solver.solve(model, x_nd, b, vec3_ndarray(model.n), 0.0, psd=False)
    assert not info.converged and "factorization failed" in info.message, info
    assert "not positive definite" in info.message, info
    with pytest.raises(SolverError, match=solver.name):
        info.check()


@needs_pardiso
def test_two_level_pardiso_misses_a_negative_pivot_that_the_classic_one_reports():
    """One of the two reasons the engine keeps PARDISO's classic factorisation (iparm(24) = 0, see
    engine/solvers/pardiso.py) though the two-level one (iparm(24) = 10) is faster in f64: on a positive
    definite chain both solve to round-off, in f64 and f32; with one negative diagonal entry the
    classic one returns error -4 (factorize -> False) in both precisions, while the two-level one in
    f64 reports success (the engine's solver, classic, reports it: test_direct_solver_reports_indefinite_matrix)."""
    import scipy.sparse
    from engine.solvers.pardiso import Pardiso
    n = 600
    A = scipy.sparse.diags([np.full(n - 1, -1.0), np.full(n, 4.0), np.full(n - 1, -1.0)], [-1, 0, 1]).tolil()
    b = np.random.default_rng(2).standard_normal(n)
    for indefinite in (False, True):
        if indefinite:
            A[n // 2, n // 2] = -50.0
        full = A.tocsr()
        U = scipy.sparse.triu(full).tocsr()
        U.sort_indices()
        for single in (False, True):
            for algorithm in (0, 10):
                S = Pardiso(U.indptr, U.indices, 2, single=single)
                if algorithm:
                    S._lib.set_iparm(24, algorithm)   # before the analysis (the first factorisation)
                ok = S.factorize(U.data)
                if not indefinite:
                    y = S.solve(b)
                    res = np.linalg.norm(full @ y - b) / np.linalg.norm(b)
                    assert ok and res < (1e-5 if single else 1e-13), (single, algorithm, res)
                elif algorithm == 0:
                    assert not ok, ("classic", single)
                elif not single:
                    assert ok, "the two-level f64 factorisation now reports the indefinite matrix"


@needs_pardiso
def test_csr_pattern_holds_the_upper_triangle_and_is_reproducible():
    """The fixed CSR pattern (engine.solvers.assembly (P1)) holds every nonzero of the upper triangle of
    the dense filtered matrix (rows sorted, no duplicates); its values are that matrix exactly
    (to round-off); assembling twice gives bitwise the same values; pardiso's solution of a
    pinned, bent cloth matches the dense solve."""
    import scipy.sparse
    model, x = cloth(6)
    x_nd = vec3_ndarray(model.n, x)
    a = 2.5e3
    solver = make_solver("pardiso", tol=1e-12)
    entry = solver._setup(model)
    pattern = entry["pattern"]
    v1 = solver.assemble_values(model, entry, x_nd, a, True, None).copy()
    v2 = solver.assemble_values(model, entry, x_nd, a, True, None).copy()
    assert np.array_equal(v1, v2)
    N = 3 * model.n
    U = scipy.sparse.csr_matrix((v1, pattern.indices, pattern.indptr), shape=(N, N)).toarray()
    assert np.all(np.diff(pattern.indices[pattern.indptr[0]:pattern.indptr[1]]) > 0)
    for r in range(N):
        cols = pattern.indices[pattern.indptr[r]:pattern.indptr[r + 1]]
        assert np.all(np.diff(cols) > 0) and cols[0] == r      # sorted, diagonal first
    A = a * np.diag(np.repeat(model.mass, 3)) + model.dense_hessian(x_nd, psd=True)
    free = np.repeat(model.free, 3)
    A[~free, :] = 0.0
    A[:, ~free] = 0.0
    A[~free, ~free] = 1.0
    assert np.abs(U - np.triu(A)).max() <= 1e-12 * np.abs(A).max()
    assert np.all(np.tril(U, -1) == 0.0)


@needs_pardiso
@pytest.mark.parametrize("psd", [True, False])
def test_rank_one_factors_assemble_the_stored_blocks(psd):
    """PARDISO's CSR values assembled with bending as its Gauss-Newton factors (the rank-one path,
    96 bytes per hinge) equal those assembled from the stored 16 blocks per hinge (1152 bytes) to
    round-off; with the exact Hessian (psd False) the stored blocks are used, bit for bit."""
    model, x = cloth(6)
    x_nd = vec3_ndarray(model.n, x)
    solver = make_solver("pardiso", tol=1e-12)
    entry = solver._setup(model)
    fast = solver.assemble_values(model, entry, x_nd, 2.5e3, psd, None).copy()
    from engine.solvers import assembly, operator
    values = entry["matrix"].data
    assembly.init_rows(values, entry["pattern"].indptr_nd, model.mass_nd, model.inv_mass_nd, 2.5e3)
    for scale, e, blocks in operator.element_terms(model, x_nd, psd, None):   # no factor buffers: stored blocks
        assert not isinstance(blocks, operator.RankOneFactors)
        assembly.assemble_rows(entry["pattern"], values, e, blocks, scale)
    if psd:
        assert not np.array_equal(fast, values) and np.abs(fast - values).max() <= 1e-14 * np.abs(values).max()
    else:
        assert np.array_equal(fast, values)


@needs_pardiso
@pytest.mark.parametrize("psd", [True, False])
def test_one_pass_assembly_is_bitwise_the_three_passes(psd, monkeypatch):
    """A cloth's springs + hinges are assembled into PARDISO's CSR values in one launch
    (assembly.pair_assembler: per block row, the mass diagonal, then the springs', then the
    hinges' contributions): the same bits as init_rows followed by one assemble_rows per energy;
    with an extra term (Rayleigh beta: each energy twice) the per-term passes are taken."""
    from engine.solvers import assembly, operator
    model, x = cloth(7)
    x_nd = vec3_ndarray(model.n, x)
    solver = make_solver("pardiso", tol=1e-12)
    entry = solver._setup(model)
    pattern, values = entry["pattern"], entry["matrix"].data
    pairs = []
    pair = assembly.pair_assembler
    monkeypatch.setattr(assembly, "pair_assembler", lambda *a: pairs.append(a) or pair(*a))
    for extra, fused in ((None, True), ((0.3, vec3_ndarray(model.n, model.X)), False)):
        pairs.clear()
        one = solver.assemble_values(model, entry, x_nd, 2.5e3, psd, extra).copy()
        assert bool(pairs) == fused
        values[:] = np.nan
        assembly.init_rows(values, pattern.indptr_nd, model.mass_nd, model.inv_mass_nd, 2.5e3)
        for scale, e, blocks in operator.element_terms(model, x_nd, psd, extra, {}):
            assembly.assemble_rows(pattern, values, e, blocks, scale)
        assert np.array_equal(one, values) and np.abs(values).max() > 0


def test_cholesky_refactorizes_with_cached_pattern():
    """The pattern is analysed once per model; new values are factorised on every solve."""
    model, x = cloth(5)
    solver = make_solver("cholesky", tol=1e-12)
    b = np.random.default_rng(4).standard_normal((model.n, 3))
    entries = []
    for k, scale in enumerate([0.0, 0.05, 0.1]):
        xk = model.X + scale * np.random.default_rng(k).standard_normal(x.shape)
        x_nd = vec3_ndarray(model.n, xk)
        y = vec3_ndarray(model.n)
        info = solver.solve(model, x_nd, vec3_ndarray(model.n, b), y, 1e3)
        A, free = dense_system(model, x_nd, 1e3)
        assert info.converged
        assert np.abs(y.to_numpy().reshape(-1)[free] - np.linalg.solve(A, b.reshape(-1)[free])).max() < 1e-10
        entries.append(solver._entry(model))
    entry = entries[0]
    assert all(e is entry for e in entries)  # one set-up (pattern, analysis) for the model
    assert entry["analyzed"] and entry["capacity"] == solvers.triplet_capacity(model)


def test_triplet_capacity_is_exact_formula():
    model, _ = cloth(5)
    springs, bending = model.energies
    assert solvers.triplet_capacity(model) == 3 * model.n + 21 * springs.m + 78 * bending.n_hinges
    # (T1) 6k + 9k(k-1)/2 is the lower triangle of one k-vertex element's 3k x 3k Hessian
    for k in range(1, 7):
        assert stencil_triplets(k) == np.tril(np.ones((3 * k, 3 * k))).sum()
    with pytest.raises(NotImplementedError, match="no per-element block layout"):
        solvers.triplet_capacity(cloth(4, springs=NoStencilSprings)[0])


def test_code_paths_follow_the_declared_products():
    """The PCG fast path is taken for energies declaring "pair-gather" + "rank-one" and not for
    the same energies declaring nothing.  Cholesky needs only the stencil: with "rank-one" declared
    it assembles the bending blocks from the Gauss-Newton factors (w w^T), without from the stored
    blocks (max(W'',0) g g^T): the same system to round-off, so the same solution to 1e-12."""
    solver = solvers.PCGSolver(1e-10)
    x_of = {}
    ys = {}
    for name, kw in (("declared", {}), ("plain", dict(springs=PlainSprings, bending=PlainBending))):
        model, x = cloth(5, **kw)
        x_nd = vec3_ndarray(model.n, x)
        blocks = {}
        solvers.operator.hessian_plan(model, x_nd, True, None, blocks)
        fused = solver._fused_setup(model, solver._work(model), x_nd, True, blocks)
        assert (fused is not None) == (name == "declared")
        b = vec3_ndarray(model.n, np.random.default_rng(3).standard_normal((model.n, 3)))
        y = vec3_ndarray(model.n)
        assert make_solver("cholesky", tol=1e-12).solve(model, x_nd, b, y, 1e3).converged
        ys[name] = y.to_numpy()
        x_of[name] = x
    assert np.array_equal(x_of["declared"], x_of["plain"])
    assert not np.array_equal(ys["declared"], ys["plain"])   # two assemblies: not bit for bit
    assert np.abs(ys["declared"] - ys["plain"]).max() <= 1e-12 * np.abs(ys["plain"]).max()
    model, x = cloth(4, springs=NoStencilSprings)
    with pytest.raises(NotImplementedError, match="use solver='pcg'"):
        make_solver("cholesky").solve(model, vec3_ndarray(model.n, x), vec3_ndarray(model.n, x),
                                      vec3_ndarray(model.n), 1e3)


def test_zero_rhs_and_unknown_solver():
    model, x = spring_network()
    y = vec3_ndarray(model.n, np.ones((model.n, 3)))
    info = make_solver("pcg").solve(model, vec3_ndarray(model.n, x), vec3_ndarray(model.n), y, 1.0)
    assert info.converged and info.iterations == 0 and np.all(y.to_numpy() == 0.0)
    with pytest.raises(ValueError, match="pcg, cholesky, pardiso, direct"):
        make_solver("lu")
    assert math.isfinite(info.residual)


@pytest.mark.parametrize("name", ["pcg"] + DIRECT)
def test_extra_hessian_term(name):
    """A = a M + c H(x) + s H(x2) (backward Euler's stiffness damping beta/dt H(x_n) during Newton)."""
    model, x = cloth(5)
    x2 = model.X + 0.02 * np.random.default_rng(9).standard_normal(x.shape)
    x_nd, x2_nd = vec3_ndarray(model.n, x), vec3_ndarray(model.n, x2)
    b = np.random.default_rng(1).standard_normal((model.n, 3))
    a, c, s = 400.0, 1.0, 0.7
    A, free = dense_system(model, x_nd, a, c)
    A = A + s * model.dense_hessian(x2_nd, psd=True)[np.ix_(free, free)]
    y = vec3_ndarray(model.n)
    info = make_solver(name, tol=1e-11).solve(model, x_nd, vec3_ndarray(model.n, b), y, a, c, extra=(s, x2_nd))
    y_ref = np.linalg.solve(A, b.reshape(-1)[free])
    assert info.converged
    assert np.abs(y.to_numpy().reshape(-1)[free] - y_ref).max() <= 1e-8 * np.abs(y_ref).max()


def test_a_membrane_takes_the_fused_pcg_paths():
    """A membrane ("element-blocks") alone is planned on the PCG's fused paths (its blocks gathered per
    vertex inside the direction-product kernel, or inside the whole-loop kernel); membrane + springs is
    not (one element-blocks energy alone, or with at most one pair-gather and one rank-one energy)."""
    solver = solvers.PCGSolver(1e-10)
    model, x = membrane()
    x_nd = vec3_ndarray(model.n, x)
    blocks = {}
    solvers.operator.hessian_plan(model, x_nd, True, None, blocks)
    fused = solver._fused_setup(model, solver._work(model), x_nd, True, blocks)
    assert fused is not None and fused[2]["n"] == model.energies[0].n_elements and fused[2]["k"] == 3
    assert solver._fused_setup(model, solver._work(model), x_nd, False, blocks) is None   # exact Hessian: generic
    two, _ = membrane()
    two.add_energy(two.energies[0])
    blocks = {}
    solvers.operator.hessian_plan(two, x_nd, True, None, blocks)
    assert solver._fused_setup(two, solver._work(two), x_nd, True, blocks) is None


@pytest.mark.parametrize("scene", ["cloth", "membrane", "springs"])
def test_whole_loop_pcg_is_the_fused_parallel_path_bit_for_bit(scene):
    """The whole-loop kernel (serial below 512 vertices) adds each element's product (rank-one factors,
    membrane blocks) to its corners' sums as it is made, and each spring pair's term once to both ends;
    the fused parallel path gathers them per vertex over the slot and pair incidences. Both sum in the same order
    (elements, and neighbours, ascending per vertex), so on a mesh small enough that Taichi runs the
    parallel loops and their reductions on one thread (under 512 vertices) the two solves are the
    same bit for bit, iterations included."""
    model, x = SCENES[scene]()
    assert model.n < 512
    x_nd = vec3_ndarray(model.n, x)
    b = vec3_ndarray(model.n, np.random.default_rng(5).standard_normal((model.n, 3)))
    out = []
    for serial in (True, False):
        y = vec3_ndarray(model.n)
        info = solvers.PCGSolver(1e-10, 1000, serial=serial).solve(model, x_nd, b, y, 1e4, 1.3)
        assert info.converged and info.iterations > 10, info
        out.append((info.iterations, info.residual, y.to_numpy()))
    assert out[0][0] == out[1][0] and out[0][1] == out[1][1]
    assert np.array_equal(out[0][2], out[1][2])


@pytest.mark.parametrize("scene", ["cloth", "membrane"])
def test_two_block_whole_loop_pcg_is_the_same_on_one_thread_or_two(scene):
    """From WHOLE_SPLIT_FROM vertices the whole-loop kernel works on the mesh's two halves, their phases
    shared by the threads (engine.tickets): each block makes the element products and spring terms of
    its own vertices (those reaching across the halves included) and the scalars are sums of the
    halves' partial sums. So its solve is the same bit for bit whether two threads or one run it, run
    after run; it meets the tolerance on the dense system, and it is the fused parallel path's solve to
    round-off, in as many iterations."""
    from engine.constants import WHOLE_SPLIT_FROM
    N = 24
    model, x = cloth(N) if scene == "cloth" else membrane(N=N)
    assert model.n >= WHOLE_SPLIT_FROM
    x_nd = vec3_ndarray(model.n, x)
    b = vec3_ndarray(model.n, np.random.default_rng(5).standard_normal((model.n, 3)))
    tol = 1e-10
    out = {}
    for name, kw in (("two", {}), ("again", {}), ("one thread", {"whole_threads": 1}), ("fused", {"serial": False})):
        y = vec3_ndarray(model.n)
        solver = solvers.PCGSolver(tol, 5000, **kw)
        info = solver.solve(model, x_nd, b, y, 1e4, 1.3)
        assert info.converged and info.iterations > 50 and solver.gave_up == 0, (name, info)
        out[name] = (info.iterations, info.residual, y.to_numpy())
    for name in ("again", "one thread"):
        assert out[name][:2] == out["two"][:2] and np.array_equal(out[name][2], out["two"][2]), name
    assert out["fused"][0] == out["two"][0]
    y2, yf = out["two"][2], out["fused"][2]
    assert np.abs(y2 - yf).max() <= 1e-9 * np.abs(yf).max()
    A, free = dense_system(model, x_nd, 1e4, 1.3)
    bf = b.to_numpy().reshape(-1)[free]
    assert np.linalg.norm(A @ y2.reshape(-1)[free] - bf) <= 1.001 * tol * np.linalg.norm(bf)


@pytest.mark.parametrize("case", ["max_iter", "zero curvature"])
def test_two_block_whole_loop_pcg_stops_like_the_fused_path(case):
    """The two-half whole-loop kernel's other ways out, as the fused parallel path takes them and the same
    on one thread or two: at the iteration limit (every task stops at the same phase; that many
    iterations, not converged), and on a direction with p.Ap <= 0 (mass_coef 0 and a right-hand side on
    a free vertex that no element touches: its preconditioner block is 0, so the first direction is 0)."""
    N = 24
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = np.vstack([m3.vertices, [[3.0, 3.0, 3.0]]])   # the last vertex: in no element
    model = Model(X, mass=np.append(mesh.lumped_masses(m3, 0.2), 0.01), pinned=[0, N - 1],
                  gravity=[0, 0, -9.81])
    model.add_energy(SpringEnergy.from_rest(X, m3.edges, c=500.0 * mesh.edge_measure(m3)))
    x = X + 0.03 * np.random.default_rng(1).standard_normal(X.shape)
    x_nd = vec3_ndarray(model.n, x)
    rhs = np.random.default_rng(5).standard_normal((model.n, 3))
    max_iter, a = 7, 1e4
    if case == "zero curvature":
        rhs[:-1] = 0.0
        max_iter, a = 5000, 0.0
    b = vec3_ndarray(model.n, rhs)
    out = {}
    for name, kw in (("two", {}), ("one thread", {"whole_threads": 1}), ("fused", {"serial": False})):
        y = vec3_ndarray(model.n)
        info = solvers.PCGSolver(1e-10, max_iter, **kw).solve(model, x_nd, b, y, a, 1.3)
        out[name] = info
        assert not info.converged, (name, info)
        if case == "max_iter":
            assert info.iterations == max_iter and info.residual > 1e-10, (name, info)
        else:
            assert "not positive definite" in info.message and info.iterations == 0, (name, info)
    assert out["one thread"].iterations == out["two"].iterations == out["fused"].iterations
    assert out["one thread"].residual == out["two"].residual


def _graded_chain(decades: float, n: int = 40, seed: int = 3):
    """A chain of n unit masses (node 0 pinned) whose springs' stiffnesses span ``decades`` decades
    (log-uniform), slightly deformed, and a random right-hand side: cond(a M + H) ~ 10^decades."""
    X = np.stack([np.linspace(0, 1, n), np.zeros(n), np.zeros(n)], 1)
    rng = np.random.default_rng(seed)
    k = 10.0 ** rng.uniform(0, decades, n - 1)
    model = Model.from_springs(X, np.stack([np.arange(n - 1), np.arange(1, n)], 1), k=k, mass=np.ones(n),
                               pinned=[0], gravity=[0, 0, -9.81])
    x_nd = vec3_ndarray(n, X + 0.01 * rng.standard_normal(X.shape))
    return model, x_nd, vec3_ndarray(n, rng.standard_normal((n, 3)))


@needs_pardiso
@pytest.mark.parametrize("decades, escalates", [(4, False), (8, True)])
def test_mixed_precision_pardiso_refines_or_escalates(decades, escalates):
    """PARDISO's mixed precision: an f32 factorisation refined in f64 reaches the tolerance on the
    f64 system when cond(A) is well below 1/eps_f32 ~ 1.7e7 (cond 6e5: several refinement steps, no
    f64 factorisation); above it (cond 7e9) f32 refinement cannot converge, the same matrix is
    factorised in f64 (one escalation) and the result is the f64 solver's."""
    model, x_nd, b = _graded_chain(decades)
    A, free = dense_system(model, x_nd, 1.0)
    cond = np.linalg.cond(A)
    assert (cond > 1e9) if escalates else (1e5 < cond < 1e7), cond
    tol = 1e-6 if escalates else 1e-10
    out = {}
    for precision in ("mixed", "double"):
        solver = solvers.PardisoSolver(tol, precision=precision)
        y = vec3_ndarray(model.n)
        info = solver.solve(model, x_nd, b, y, 1.0)
        yy = y.to_numpy().reshape(-1)
        res_dense = np.linalg.norm(A @ yy[free] - b.to_numpy().reshape(-1)[free]) / np.linalg.norm(
            b.to_numpy().reshape(-1)[free])
        # a residual is evaluated to ~ eps ||A|| ||y|| / ||b|| (round-off of the product): equal to that
        bf = b.to_numpy().reshape(-1)[free]
        floor = 8 * np.finfo(float).eps * np.linalg.norm(A, 2) * np.linalg.norm(yy[free]) / np.linalg.norm(bf)
        assert info.converged and res_dense <= tol and abs(res_dense - info.residual) <= floor, (info, floor)
        out[precision] = (info, solver.escalations, yy)
    info, escalations, yy = out["mixed"]
    assert escalations == (1 if escalates else 0)
    if escalates:   # the f64 factorisation of the same matrix, then its own solve: the double solver's answer
        assert np.array_equal(yy, out["double"][2])
    else:
        assert info.iterations >= 3        # f32 alone is ~eps_f32 cond ~ 0.06 off: refinement did the work
        err = np.linalg.norm(yy[free] - out["double"][2][free]) / np.linalg.norm(out["double"][2][free])
        assert err <= cond * 2 * tol


@needs_pardiso
def test_pardiso_precision_is_checked():
    with pytest.raises(ValueError, match="precision must be one of mixed, double, got 'half'"):
        solvers.PardisoSolver(1e-8, precision="half")


@needs_pardiso
@pytest.mark.parametrize("mkl", [True, False])
def test_symmetric_upper_residual_is_the_full_matrix_and_sees_values_written_in_place(mkl):
    """engine.solvers.pardiso.SymmetricUpper (PARDISO's residual check) computes b - A y for the full
    symmetric A from its upper triangle, with an unsymmetric-looking upper part (a lower-triangle-only or
    transposed product would differ), the diagonal counted once, and the values written into U.data
    after the product was set up (the engine assembles in place every step) are the ones used; the
    scipy fallback (no MKL inspector-executor) gives the same."""
    import scipy.sparse
    from engine.solvers.pardiso import SymmetricUpper
    rng = np.random.default_rng(5)
    n = 30
    full = rng.standard_normal((n, n)) * (rng.random((n, n)) < 0.2)
    full = full + full.T + np.diag(rng.uniform(5, 10, n))
    U = scipy.sparse.csr_matrix(np.triu(full))
    U.sort_indices()
    product = SymmetricUpper(U)
    if not mkl:
        product._handle = None
    else:
        assert product.uses_mkl
    y, b = rng.standard_normal(n), rng.standard_normal(n)
    assert np.max(np.abs(product.residual(b, y) - (b - full @ y))) <= 1e-13 * np.abs(full).sum()
    U.data *= -2.5   # in place, as the assembly writes
    assert np.max(np.abs(product.residual(b, y) - (b + 2.5 * full @ y))) <= 1e-13 * np.abs(full).sum()
