"""Lesson area-springs: every experiment, its key figures, the long-wavelength theory of
engine/waves.py, and finite-difference checks of the area/volume-spring energy on jittered
meshes.

Not repeated here (tests/engine/test_mesh.py has them): edge measures and lumped masses summing to
the total area/volume/mass on every generator (jittered too), and the bad-mesh errors.
"""
import math

import numpy as np
import pytest

from engine import mesh as M
from engine.errors import ParameterError
from engine.fields import vec3_ndarray
from engine.model import Model
from engine.waves import (ModeProbe, cauchy_born_tensor, christoffel, max_speed, phase_frequency,
                          relaxed_stiffness_2d, young_poisson)
from lessons._framework import validate_config
from engine.theory.schemes import backward_euler_damping_rate as be_damping_rate
from lessons._measure import central_gradient, damped_frequency
from lessons.area_springs import LESSON, AreaSpringsConfig
from lessons.area_springs.scene import bulk_tensor
from tests.helpers import assert_all_passed, assert_unique_ids, run_stage


@pytest.fixture(scope="module")
def stages(default_runs):
    return default_runs(LESSON.id).stages   # every stage at the defaults, shared with the recording tests


# ------------------------------------------------------------------------- the stages

def test_experiment_ids_are_unique_in_the_lesson(stages, be_stages):
    assert_unique_ids(stages)
    assert_unique_ids({i: s for i, (s, _) in be_stages.items()})


def test_stage1_constant_k_scales_as_one_over_h_volume_springs_do_not(stages):
    s = stages[1]
    assert_all_passed(s)
    r2 = s["one-k-ratio-h2"]
    r4 = s["one-k-ratio-h4"]
    assert r2.theory == 2.0 and abs(r2.measured / 2 - 1) < 2e-2
    assert r4.theory == 4.0 and abs(r4.measured / 4 - 1) < 2e-2
    for key in ("volume-scaled-ratio-h2", "volume-scaled-ratio-h4"):
        assert abs(s[key].measured - 1) < 1e-2


def test_stage2_equilateral_p_and_s_speeds(stages):
    s = stages[2]
    assert_all_passed(s)
    cP, cS = math.sqrt(3 / 8), math.sqrt(1 / 8)  # E = rho = 1
    for axis in "xy":
        p = s[f"p-wave-{axis}"]
        assert p.theory == pytest.approx(cP) and abs(p.measured / cP - 1) < 2e-2
    sx = s["s-wave-x"]
    assert sx.theory == pytest.approx(0.35355, abs=1e-5) and abs(sx.measured / cS - 1) < 2e-2
    assert abs(s["p-over-s-sqrt3"].measured / math.sqrt(3) - 1) < 1e-2


def test_stage3_patterns_are_anisotropic_and_predicted(stages):
    s = stages[3]
    assert_all_passed(s)
    expected = {"one-way": (0.6606, 0.7071, 0.4082), "alternating": (0.6455, 0.5774, 0.5774),
                "crossed": (0.5774, 0.6455, 0.6455)}
    for pattern, (vx, vd, va) in expected.items():
        for label, v in (("x", vx), ("diagonal-plus", vd), ("diagonal-minus", va)):
            e = s[f"{pattern}-p-wave-{label}"]
            assert e.theory == pytest.approx(v, abs=1e-4)
            assert abs(e.measured / e.theory - 1) < 2e-2
    assert s["one-way-anisotropic"].measured > 1.7


def test_stage3_jitter_the_affine_sum_is_an_upper_bound(stages):
    s = stages[3]
    bound = s["jitter-affine-sum-upper-bound"]
    assert bound.claim.startswith("jitter 0.25:")
    assert bound.measured < 0.99  # strong jitter: a few per cent softer than the affine sum
    for seed in range(3):
        for axis in "xy":
            e = s[f"jitter-seed{seed}-p-wave-{axis}"]
            assert e.claim.startswith(f"jitter 0.25 (seed {seed}):")
            assert abs(e.measured / e.theory - 1) < 2e-2
    mild = s["mild-jitter-p-wave-x"]
    assert mild.claim.startswith("mild jitter 0.1:")
    assert abs(mild.measured / mild.theory - 1) < 2e-2


def test_stage4_tet_box(stages):
    s = stages[4]
    assert_all_passed(s)
    e = s["box-p-wave-111"]
    assert e.theory == pytest.approx(math.sqrt(10 / 27))
    assert abs(s["box-refinement-keeps-speed"].measured - 1) < 1e-2


def test_stage5_static_stretch(stages):
    s = stages[5]
    assert_all_passed(s)
    nu = s["equilateral-poisson-ratio"]
    E = s["equilateral-young-modulus"]
    assert abs(nu.measured * 3 - 1) < 2e-2 and abs(E.measured * 3 - 1) < 2e-2
    alt = s["alternating-poisson-ratio"]
    assert alt.theory == pytest.approx(0.2) and abs(alt.measured / 0.2 - 1) < 2e-2


def test_stage5_records_the_stretched_strips(tmp_path):
    from lessons.app.recorder import Recorder
    from lessons.app.recorder_read import summarize
    rec = Recorder(tmp_path / "a.rrd", "test")
    assert_all_passed(run_stage(LESSON, 5, rec=rec, strip_cells=40))
    rec.close()
    info = summarize(tmp_path / "a.rrd")
    for entity in ("/stage5/equilateral_strip/mesh", "/stage5/equilateral_strip/springs"):
        assert entity in info
    assert "Mesh3D:vertex_colors" in info["/stage5/equilateral_strip/mesh"]["components"]


def test_stage2_records_each_wave_in_its_own_view_coloured_by_its_displacement(tmp_path):
    """P and S waves along x and y each draw a mesh (no springs) of tens of frames over the S waves'
    time, coloured by the component the wave carries on the fixed scale A = strain / k."""
    from lessons.app.recorder import Recorder
    from lessons.app.recorder_read import summarize
    rec = Recorder(tmp_path / "a.rrd", "test")
    assert_all_passed(run_stage(LESSON, 2, rec=rec))
    rec.close()
    info = summarize(tmp_path / "a.rrd")
    cfg = AreaSpringsConfig()
    A = cfg.strain * cfg.wavelength / (2 * math.pi)
    runs = {r.name: r for r in rec.stages[-1].runs}
    carried = {"P_along_x": "u_x", "S_along_x": "u_y", "P_along_y": "u_y", "S_along_y": "u_x"}
    for name, component in carried.items():
        run = runs[name]
        assert run.camera == "top" and run.energy is None and run.label.startswith(f"{name[0]} wave along {name[-1]}")
        assert list(run.scales) == [f"{component} (m)"] and run.scales[f"{component} (m)"] == pytest.approx(A)
        assert run.span == pytest.approx(runs["S_along_x"].span)
        mesh = info[f"/stage2/{name}/mesh"]
        assert "Mesh3D:vertex_colors" in mesh["components"] and len(set(mesh["frames"])) >= 10
        assert f"/stage2/{name}/springs" not in info
    # the P waves end sooner on the shared timeline
    assert max(info["/stage2/P_along_x/mesh"]["frames"]) < 0.7 * max(info["/stage2/S_along_x/mesh"]["frames"])


def test_displacement_component_names_the_axis_or_the_wave_direction():
    from lessons._waves import displacement_component
    a, name = displacement_component([1.0, 0.0], [0.0, -1.0])  # S along x
    assert name == "u_y (m)" and np.allclose(a, [0, 1, 0])
    a, name = displacement_component([1, 1, 1] / np.sqrt(3), [-1, -1, -1] / np.sqrt(3))  # P along (1,1,1)
    assert name == "u_n (m)" and np.allclose(a, np.ones(3) / np.sqrt(3))
    a, name = displacement_component([1.0, 0.0, 0.0], [0.95, 0.22, 0.22])  # quasi-P along x
    assert name == "u_x (m)" and np.allclose(a, [1, 0, 0])
    a, name = displacement_component([1.0, 0.0, 0.0], [0.2, 0.7, 0.7])  # quasi-S along x
    assert name == "u_t (m)" and a[0] == 0 and np.allclose(a, [0, 1, 1] / np.sqrt(2))


def test_config_rejects_a_stretch_longer_than_a_spacing():
    with pytest.raises(ParameterError, match="--strain"):
        LESSON.validate(AreaSpringsConfig(strain=0.01, strip_cells=200))
    with pytest.raises(ParameterError, match="--jitter"):
        validate_config(AreaSpringsConfig(jitter=0.3))


# ---------------------------------------------------------------- long-wavelength theory

def test_cauchy_born_of_the_equilateral_lattice_is_isotropic_with_lambda_equal_mu():
    m = M.equilateral_lattice(9, 8, 0.5)
    C = cauchy_born_tensor(m.vertices, m.edges, 2.0 * m.edge_measure, m.total_measure)
    d = np.eye(2)
    iso = (2.0 / 8) * (np.einsum("ij,kl->ijkl", d, d) + np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d))
    assert np.abs(C - iso).max() < 1e-12
    for angle in np.linspace(0, np.pi, 7):
        speeds = christoffel(C, [math.cos(angle), math.sin(angle)], 0.5)[0]
        assert speeds == pytest.approx([math.sqrt(2 / 8 / 0.5), math.sqrt(6 / 8 / 0.5)], rel=1e-12)
    E_eff, nu = young_poisson(C, 0)
    assert E_eff == pytest.approx(2.0 / 3, rel=1e-12) and nu == pytest.approx(1 / 3, rel=1e-12)


def test_cauchy_born_of_the_kuhn_tet_box():
    m = M.tet_box(6, 6, 6, size=0.5)
    C = bulk_tensor(m, m.edge_measure, 0.1)  # E = 1
    assert C[0, 0, 0, 0] == pytest.approx(13 / 54, rel=1e-12)
    assert C[0, 0, 0, 1] == pytest.approx(5 / 108, rel=1e-12)
    speeds, pol = christoffel(C, [1, 1, 1], 1.0)
    assert speeds[-1] == pytest.approx(math.sqrt(10 / 27), rel=1e-12)
    assert abs(abs(pol[:, -1] @ np.ones(3)) / math.sqrt(3) - 1) < 1e-12  # purely longitudinal
    assert max_speed(C, 1.0) == pytest.approx(math.sqrt(10 / 27), rel=1e-3)
    # area scaling: the whole-mesh sum equals the bulk tensor; one k for all springs scales as 1/h^2
    assert np.abs(cauchy_born_tensor(m.vertices, m.edges, m.edge_measure, m.total_measure) - C).max() < 1e-12
    m2 = M.tet_box(6, 6, 6, size=0.25)
    ratio = bulk_tensor(m2, m2.rest_lengths, 0.05)[0, 0, 0, 0] / bulk_tensor(m, m.rest_lengths, 0.1)[0, 0, 0, 0]
    assert ratio == pytest.approx(4.0, rel=1e-12)


def test_relaxed_stiffness_regular_grid_has_nothing_to_relax_jitter_softens():
    from engine.energies.springs import SpringEnergy
    for mesh, softer in ((M.right_triangle_grid(14, 14, 13.0, 13.0, "one-way"), False),
                         (M.jitter(M.right_triangle_grid(14, 14, 13.0, 13.0, "one-way"), 0.25, 4), True)):
        c = mesh.edge_measure
        X3 = M.embed_3d(mesh).vertices
        sp = SpringEnergy.from_rest(X3, mesh.edges, c=c)
        blocks = sp.hessian_blocks_numpy(vec3_ndarray(len(X3), X3), psd=False)
        window = np.linalg.norm(mesh.vertices[mesh.triangles].mean(axis=1) - 6.5, axis=1) <= 4.0
        C_rel, C_aff = relaxed_stiffness_2d(mesh, blocks, c, window)
        if not softer:
            C = cauchy_born_tensor(mesh.vertices, mesh.edges, c, mesh.total_measure)
            assert np.abs(C_rel - C).max() < 1e-12 and np.abs(C_aff - C).max() < 1e-12
        else:
            from engine.waves import voigt_2d
            gap = np.linalg.eigvalsh(voigt_2d(C_aff) - voigt_2d(C_rel))
            assert gap.min() > -1e-12 and gap.max() > 1e-3  # relaxation only lowers the energy


def test_mode_probe_and_phase_frequency():
    m = M.equilateral_lattice(6, 6, 1.0)
    X = M.embed_3d(m).vertices
    mass = M.lumped_masses(m, 1.0)
    probe = ModeProbe(X, mass, [1, 1], [1, -1], 0.3, (2.0, 2.0, 0.0), np.ones(len(X), bool))
    assert probe.amplitude(X + probe.displacement(1e-3)) == pytest.approx(1e-3, rel=1e-12)
    t = np.linspace(0, 2.0, 60)
    assert phase_frequency(t, 0.7 * np.cos(1.3 * t)) == pytest.approx(1.3, rel=1e-10)


# ------------------------------------------------------- derivatives of the mesh energies

def _fd_gradient_error(X, edges, c, x):
    model = Model.from_springs(X, edges, c=c)
    sp = model.springs
    f = vec3_ndarray(len(x))
    sp.add_forces(vec3_ndarray(len(x), x), f)
    f = f.to_numpy().reshape(-1)
    g = central_gradient(lambda y: sp.energy(vec3_ndarray(len(y), y)), x, 1e-6).reshape(-1)
    return np.linalg.norm(g + f) / np.linalg.norm(g)


@pytest.mark.parametrize("which", ["jittered sheet", "jittered tet box"])
def test_area_spring_energy_gradient_by_central_differences(which):
    rng = np.random.default_rng(11)
    if which == "jittered sheet":
        mesh = M.embed_3d(M.jitter(M.right_triangle_grid(6, 5, 1.0, 0.8, "alternating"), 0.25, 2))
    else:
        mesh = M.jitter(M.tet_box(4, 4, 4, size=0.6), 0.25, 3)
    X = mesh.vertices
    c = 3.0 * M.edge_measure(mesh)
    x = X + 0.05 * rng.standard_normal(X.shape)  # stretched and compressed springs, out of plane too
    assert _fd_gradient_error(X, mesh.edges, c, x) < 1e-6


def test_a_too_short_wavelength_fails_honestly():
    """Eight cells per wavelength is far from the long-wavelength limit: the lattice is
    dispersive, and the claims must then fail rather than be hidden."""
    s = run_stage(LESSON, 4, box_wavelength=8)
    e = s["box-p-wave-111"]
    assert not e.passed and e.measured < e.theory
    assert "lattice dispersion" in e.reason  # and the failure says why


# ------------------------------------------------------------ stepping options (--integrator)

BE_PCG = "backward-euler (pcg, tol 1e-08)"
WHERE = {1: "refinement", 2: "equilateral", 3: "patterns", 4: "tet-box"}  # id prefix of each stage's BE checks
DAMPING = "backward Euler damps each wave by 1/sqrt(1 + (W dt)^2) per step: fitted / scheme's decay rate"
PHASE = "backward Euler's phase lag 1 - arctan(W dt)/(W dt) at the chosen dt"


@pytest.fixture(scope="module")
def be_stages():
    """Every wave stage under --integrator backward-euler, on smaller configurations where they
    exist (stage 1 with 7-cell coarse boxes, stage 3 with one strong-jitter mesh, stage 4 with
    16-cell waves and --solver cholesky, which the 3D boxes replace by pcg)."""
    out = {}
    for i, stepping, kw in ((1, {}, dict(box_cells=7)), (2, {}, {}), (3, {}, dict(jitter_seeds=1)),
                            (4, dict(solver="cholesky"), dict(box_wavelength=16))):
        used = []
        s = run_stage(LESSON, i, stepping=dict(integrator="backward-euler", **stepping), used=used, **kw)
        out[i] = s, used
    return out


@pytest.mark.parametrize("stage, runs", [(1, 6), (2, 4), (3, 16), (4, 4)])
def test_backward_euler_wave_stages_pass_as_scene_runs(be_stages, stage, runs):
    s, used = be_stages[stage]
    assert_all_passed(s)
    assert len(used) == runs and all(u.split(": ", 1)[1] == BE_PCG for u in used)  # scene runs, none [fixed]
    damping = s[f"{WHERE[stage]}-backward-euler-damping"]
    assert damping.claim.startswith(DAMPING) and abs(damping.measured - 1) < 3e-2
    phase = s[f"{WHERE[stage]}-backward-euler-phase-lag"]
    assert phase.claim.startswith(PHASE)
    assert 7e-4 < phase.measured <= 1e-3  # w dt = 0.05: 1 - arctan(0.05)/0.05 = 8.3e-4


def test_backward_euler_keeps_the_continuum_speeds_and_ratios(be_stages):
    s1 = be_stages[1][0]
    assert abs(s1["one-k-ratio-h4"].measured / 4 - 1) < 2e-2
    assert abs(s1["volume-scaled-ratio-h4"].measured - 1) < 1e-2
    s2 = be_stages[2][0]
    assert abs(s2["p-wave-x"].measured / math.sqrt(3 / 8) - 1) < 2e-2
    assert abs(s2["s-wave-x"].measured / math.sqrt(1 / 8) - 1) < 2e-2


@pytest.mark.parametrize("stage, kw", [(2, {}), (4, dict(box_wavelength=16))])
def test_symplectic_euler_override_passes_the_wave_stages(stage, kw):
    used = []
    s = run_stage(LESSON, stage, stepping=dict(integrator="symplectic-euler"), used=used, **kw)
    assert_all_passed(s)
    assert used and all(u.split(": ", 1)[1] == "symplectic-euler" for u in used)
    assert not any(e.claim.startswith(DAMPING) or i.endswith("backward-euler-damping") for i, e in s.items())


def test_damped_frequency_recovers_backward_eulers_own_decay():
    """Backward Euler from rest on an oscillator of frequency W: a_n = a_0 cos(th)^n cos(n th),
    th = arctan(W dt), exactly; the fit returns w = th/dt and the decay -ln(cos th)/dt."""
    W, dt = 0.7, 0.08
    th = math.atan(W * dt)
    n = np.arange(40)
    w, gamma = damped_frequency(n * dt, 2.5 * np.cos(th) ** n * np.cos(n * th))
    assert w == pytest.approx(th / dt, rel=1e-10)
    assert gamma == pytest.approx(be_damping_rate(w, dt), rel=1e-8)
    assert be_damping_rate(w, dt) == pytest.approx(math.log(1 + (W * dt) ** 2) / (2 * dt), rel=1e-12)
