"""Hard-case stability suite (quick flavours), its checker and report, and the
two core fixes the suite found (step-size control, patch grasps under LOD)."""

import argparse
import dataclasses
import json

import numpy as np
import pytest

from cloth_lod_ros.tools.stress import runner as stress  # the module that reads CASES
from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.integrate.step_control import TimeStepper
from cloth_lod_ros.tools.stress import CASES, Bounds, Case, Variant, run_case
from cloth_lod_ros.tools.stress.cases import Event

CASE = {c.name: c for c in CASES}


# -- every case, LOD on and off ---------------------------------------------------

# fold_in_half: the grasps lay the edge down onto contacts that stick, and the scene's
# converged motion (3 Newton iterations to 1e-4 m) strains 0.24-0.46 too, so the scene's
# path, not the step, is what exceeds the bound.  Of the other contact cases that do not
# hold yet (quick flavours, measured with `cloth-lod stress --quick`; in none do two
# triangles cross at any step), the four tried pass with a tighter time-error tolerance
# alone: table_drape and corner_pull LOD on at `simulation.error_tolerance=1e-5` (1.27x and
# 1.11x at 1e-4), slot_drop LOD off at 1e-5, bar_drop LOD off at 1e-6 (4.1 and 1.8 cm/s
# at 1e-4 and 1e-5).  There the converged motion holds the bounds; the default step control
# does not see the error a landing makes (contact particles count as error-free).  Open in
# issue 31.
KNOWN = {("fold_in_half", False): "the scene's grasp path strains the cloth to 0.46 (energy "
                                  "1.32 J > budget 0.34 J at 1.83 s); its converged motion "
                                  "strains too (issue 31, open)",
         ("fold_in_half", True): "strain 0.27 > 0.15 and energy 1.35x its budget at 1.8 s: "
                                 "the same grasp path (issue 31, open)",
         ("table_drape", True): "a particle leaves the table at 1.39x its landing speed at "
                                "0.28 s (passes at error_tolerance 1e-5; issue 31, open)",
         ("bar_drop", True): "not at rest at 1.2 s: 3.6 cm/s (issue 31, open)",
         ("bar_drop", False): "not at rest at 1.2 s: 8.4 cm/s, the hanging halves still "
                              "swinging (at rest at error_tolerance 1e-6; issue 31, open)",
         ("slot_drop", True): "not at rest at 1.2 s: 4.8 cm/s (issue 31, open)",
         ("slot_drop", False): "not at rest at 1.2 s: 2.1 cm/s (at rest at error_tolerance "
                               "1e-5; issue 31, open)",
         ("grasps_cross", True): "energy 0.98 J > its budget 0.76 J at 1.15 s; a particle "
                                 "leaves an obstacle at 1.57x its landing speed at 0.65 s "
                                 "(issue 31, open)",
         ("corner_pull", True): "a particle leaves an obstacle at 1.44x its landing speed "
                                "at 0.57 s (passes at error_tolerance 1e-5; issue 31, open)"}


class KnownFailure(Exception):
    """A run of :data:`KNOWN` that fails as measured (any other failure of the
    test, such as layers crossing, is a failure)."""


@pytest.mark.parametrize("lod", [True, False], ids=["lod_on", "lod_off"])
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case_stays_finite_bounded_and_conserving(case, lod, request):
    known = (case.name, lod) in KNOWN
    if known:
        # strict: the day the scene's path is fixed, this says so
        request.applymarker(pytest.mark.xfail(reason=KNOWN[case.name, lod], strict=True,
                                              raises=KnownFailure))
    result = run_case(case, lod, quick=True)
    bounds = case.bounds
    if known:
        # The layers hold even where another bound does not yet.
        assert result.crossed_steps == 0 and not any(f.startswith("layers")
                                                     for f in result.failures)
        if not result.passed:
            raise KnownFailure("; ".join(result.failures))
    assert result.passed, result.failures
    # The checker's verdict, restated on the recorded series.
    h = stress.build_scene(case, lod, quick=True).simulation.time_step
    assert result.steps == round(case.quick.duration / h)
    for series in (result.max_strain, result.max_speed, result.energy):
        assert np.all(np.isfinite(series))
    assert result.max_strain.max() <= bounds.max_strain
    assert result.max_speed.max() <= result.speed_limit
    assert result.energy.max() <= bounds.energy_peak * result.budget
    assert result.energy[-1] <= bounds.energy_final * result.budget
    assert result.converged.all()
    if lod and bounds.turnover is not None:
        assert result.max_turnover <= bounds.turnover
    if bounds.min_level is not None:
        assert result.deepest_level >= bounds.min_level
    if not lod:
        assert result.topology_ops.sum() == 0


def test_every_case_has_a_quick_and_a_full_flavour_and_builds():
    assert len({c.name for c in CASES}) == len(CASES) == 18
    for case in CASES:
        assert case.quick.duration <= case.full.duration
        assert case.quick.level <= case.full.level
        for lod in (True, False):
            for quick in (True, False):
                scene = stress.build_scene(case, lod, quick)
                assert scene.lod.enabled is lod


# -- the checker --------------------------------------------------------------------

TINY = Case(name="tiny", description="hang, level 2, 0.1 s", scene="hang_two_corners",
            overrides={}, full=Variant(0.1, 2), quick=Variant(0.1, 2),
            bounds=Bounds(max_strain=0.15), anchors=((0.0, 1.0), (1.0, 1.0)))


def _run(monkeypatch, capsys, cases, argv):
    monkeypatch.setattr(stress, "CASES", tuple(cases))
    parser = argparse.ArgumentParser()
    stress.add_arguments(parser)
    code = stress.run(parser.parse_args(argv))
    return code, capsys.readouterr().out


def test_report_prints_a_row_per_run_and_exits_0(monkeypatch, capsys, tmp_path):
    path = tmp_path / "out" / "stress.json"
    code, out = _run(monkeypatch, capsys, [TINY], ["--quick", "--json", str(path)])
    assert code == 0
    rows = [line for line in out.splitlines() if line.startswith("tiny")]
    assert [r.split()[1] for r in rows] == ["on", "off"]
    assert all(r.split()[2] == "6" and r.rstrip().endswith("pass") for r in rows)
    for column in ("strain", "speed", "E init/max/final", "CG mean/max", "ops total/max/s"):
        assert column in out
    assert "2/2 runs passed" in out
    data = json.loads(path.read_text())
    assert [r["lod"] for r in data["runs"]] == [True, False]
    run = data["runs"][0]
    assert run["passed"] and run["steps"] == 6 and len(run["series"]["energy"]) == 6
    assert run["energy_max"] <= run["energy_budget"]


def test_lod_and_case_selection(monkeypatch, capsys):
    code, out = _run(monkeypatch, capsys, [TINY], ["--quick", "--lod", "off", "--cases", "tiny"])
    assert code == 0
    assert [line.split()[1] for line in out.splitlines() if line.startswith("tiny")] == ["off"]
    code, _ = _run(monkeypatch, capsys, [TINY], ["--cases", "nope"])
    assert code == 2


def test_a_violated_bound_is_reported_as_fail(monkeypatch, capsys):
    impossible = dataclasses.replace(TINY, bounds=Bounds(max_strain=1e-9, speed_factor=1e-9))
    code, out = _run(monkeypatch, capsys, [impossible], ["--quick", "--lod", "on"])
    assert code == 1
    row = next(line for line in out.splitlines() if line.startswith("tiny"))
    assert "FAIL" in row and "strain: max strain" in row and "speed: max speed" in row
    assert "0/1 runs passed" in out


def test_thrashing_without_hysteresis_is_caught():
    """Near-equal thresholds with no hysteresis (no minimum lifetime, no merge
    energy bound, merges allowed however fast the hinges turn and whatever they
    carry) really thrash: the topology check (not an injected bound) fails.
    (The merge energy bound alone holds this case to 1.0 operations/s per
    particle; with the corners held over patches, removing only the minimum
    lifetime gave 5.4, barely over the bound; with point pins it gave 10.)"""
    case = CASE["near_equal_thresholds"]
    # The checker is what is tested: without any hysteresis, and in vacuum so
    # that the cloth keeps swinging, this case thrashes (measured 7.1/s; 6.1 with
    # the face air drag; the paper's damped step in air, 4.7).
    no_hysteresis = dataclasses.replace(
        case, overrides={**case.overrides, "lod.min_lifetime": 0.0,
                         "lod.max_merge_speed": 100.0,
                         "lod.max_hinge_rate": 1e3, "lod.max_bend_force": 1e3,
                         "air.density": 0.0, "lod.check_interval": 1})
    result = run_case(no_hysteresis, lod=True, quick=True)
    assert not result.passed
    assert [f.split(":")[0] for f in result.failures] == ["topology"]
    assert result.max_turnover > 1.2 * case.bounds.turnover      # measured 7.5


def test_a_linearisation_blow_up_is_caught_without_the_step_size_control(monkeypatch):
    """The 5 m/s impact with the step-size control switched off stretches the
    cloth by ~40 % and multiplies its energy: strain and energy checks fail."""
    monkeypatch.setattr(TimeStepper, "max_substep_depth", 0)
    result = run_case(CASE["drop_on_sphere_fast"], lod=False, quick=True,
                      extra=["simulation.integrator=baraff_witkin"])
    checks = [f.split(":")[0] for f in result.failures]
    assert "strain" in checks and "energy" in checks
    assert result.max_strain.max() > 0.3 and result.energy.max() > 5 * result.budget


def test_a_contact_that_throws_and_a_scene_still_moving_are_reported():
    """The strip lands on the table edge at about 0.6 m/s (at 0.06 s); 0.1 s
    in, every particle is given 2 m/s upwards (an injected kick, as the
    landing kick of issue 31 was): it bounces off the table at over 3x its
    landing speed, and a cloth flying off is not at rest."""
    case = CASE["strip_over_edge"]
    kicked = dataclasses.replace(
        case, quick=Variant(0.45, 4),
        bounds=dataclasses.replace(case.bounds, landing=1.1, rest=0.4),
        events=(Event(0.1, "velocity", ((0.0, 0.0, 2.0),)),))
    result = run_case(kicked, lod=False, quick=True)
    checks = [f.split(":")[0] for f in result.failures]
    assert "landing" in checks and "rest" in checks
    assert result.landing_ratio > 3.0 and result.rest_speed > 0.1
    # Without the kick both hold up to the kick's time.
    calm = dataclasses.replace(kicked, events=(), quick=Variant(0.3, 4),
                               bounds=dataclasses.replace(kicked.bounds, rest=None))
    result = run_case(calm, lod=False, quick=True)
    assert "landing" not in [f.split(":")[0] for f in result.failures]
    assert result.landing_ratio < 1.1


def test_a_grip_that_has_not_caught_up_is_reported():
    """The teleported grasp needs 0.25 s at 2 m/s; demanding it on target after
    0.05 s is a real violation of that (wrong) deadline."""
    too_early = dataclasses.replace(CASE["grasp_teleport"], catch_up=(("left", 0.55),))
    result = run_case(too_early, lod=True, quick=True)
    assert [f.split(":")[0] for f in result.failures] == ["catch_up"]


def _grid(n: int, size: float):
    """A flat ``n x n``-particle square of side ``size`` m: uv ``(n², 2)``, triangles."""
    u, v = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return np.column_stack([u.ravel(), v.ravel()]), tri


@pytest.mark.parametrize("seed", range(6))
def test_the_layer_check_finds_no_crossing_in_a_flat_sheet_in_any_plane(seed):
    """A flat sheet has no two layers, in whatever plane it lies: the rounded
    coordinates of a turned plane (or of cloth lying on a floor) put its
    particles 1e-17 m off the plane at random, and exact sign tests on those
    found 'crossings' between triangles that do not overlap (3-8 per 16 x 16
    sheet, seeds 2-4)."""
    from scipy.spatial.transform import Rotation
    from cloth_lod_ros.tools.stress.intersect import intersecting_pairs
    uv, tri = _grid(17, 0.8)
    turn = Rotation.random(random_state=seed).as_matrix()
    x = np.column_stack([uv, np.zeros(len(uv))]) @ turn.T + [0.3, -0.2, 0.45]
    assert len(intersecting_pairs(x, tri)) == 0
    # The same sheet with a second one through it, 1e-9 m deep at one corner:
    # a crossing, however shallow, is still one.
    uv2, tri2 = _grid(2, 0.05)
    y = np.column_stack([np.zeros(len(uv2)), uv2]) + [0.41, 0.42, -0.05 + 1e-9]
    y = y @ turn.T + [0.3, -0.2, 0.45]
    pairs = intersecting_pairs(np.concatenate([x, y]), np.concatenate([tri, tri2 + len(x)]))
    assert len(pairs) and np.all(pairs[:, 1] >= len(tri))


# -- core fixes the suite found ---------------------------------------------------

def _scene(level=3, lod=None, grasps=(), pins=(), gravity=(0, 0, -9.81), obstacles=(),
           origin=(0.0, 0.0, 1.0), integrator="sdirk2", self_collision=False):
    return scene_from_dict({
        "name": "stress_test",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level,
                  "origin": list(origin)},
        "material": {"air_drag": 0.0},
        "air": {"density": 0.0},        # no air: the impacts stay as fast as stated
        "pins": [dict(p) for p in pins], "grasps": [dict(g) for g in grasps],
        "obstacles": [dict(o) for o in obstacles],
        "simulation": {"time_step": 1 / 60, "duration": 1.0, "gravity": list(gravity),
                       "integrator": integrator},
        "solver": {"tolerance": 1e-6},
        "lod": lod or {"enabled": False},
        # These tests are about the step and the grasps: the cloth alone, as
        # before self-collision was on by default.
        "self_collision": {"enabled": self_collision},
    })


def _yank(sim):
    """Hang 20 steps, then move pin "a" 0.33 m in one step (20 m/s)."""
    for _ in range(20):
        assert sim.step().substeps == 1              # ordinary motion: one solve
    target = sim.positions[sim.pin("a").vertex] + [0.0, -0.1, 0.3]
    sim.set_pin_target("a", target)
    return target, sim.step()


def test_a_step_whose_stretch_jumps_is_split_and_pins_still_land_exactly(monkeypatch):
    """A pin yanked 0.33 m in one step over-stretches its neighbours in one
    linearised step; the step is redone in parts, the pin ends exactly on its
    target, the clock exactly one step on, and (with the paper's step, which
    is where the control matters most) the stretch is about half."""
    pins = [{"name": "a", "uv": [0.0, 1.0]}, {"name": "b", "uv": [1.0, 1.0]}]
    for integrator in ("sdirk2", "baraff_witkin"):
        sim = ClothSim(_scene(pins=pins, integrator=integrator))
        target, stats = _yank(sim)
        assert stats.substeps > 1
        assert np.array_equal(sim.positions[sim.pin("a").vertex], target)
        assert sim.time == stats.time and stats.time == pytest.approx(21 / 60, abs=1e-12)
    monkeypatch.setattr(TimeStepper, "max_substep_depth", 0)
    uncontrolled = ClothSim(_scene(pins=pins, integrator="baraff_witkin"))
    _, single = _yank(uncontrolled)
    assert single.substeps == 1
    assert stats.max_strain < 0.6 * single.max_strain      # measured 0.31 vs 0.65


@pytest.mark.parametrize("control,integrator", [
    (True, "sdirk2"),
    pytest.param(True, "baraff_witkin", marks=pytest.mark.xfail(
        strict=True, raises=AssertionError, reason=(
            "since the squared-Hessian bending the paper's one linearised step, under "
            "the control, keeps a step that gains 8 % (3.35 J from 3.09 J: the stretch "
            "overshoots at the impact; strain 0.074); the control checks stretch growth, "
            "not energy (issue 31, open)"))),
    (False, "baraff_witkin")],
    ids=["control", "control_paper", "no_control_paper"])
def test_a_fast_impact_stays_physical_with_the_step_size_control(control, integrator,
                                                                 monkeypatch):
    """5 m/s onto a sphere at level 5.  Without the control one linearised step
    of the paper's method stretches the cloth by ~40 % and multiplies its
    energy ~9x (measured; one Newton iteration of SDIRK2 does much the same);
    with it the strain stays at a few per cent and the energy, which
    inelastic contact can only remove, grows by < 1 %."""
    if not control:
        monkeypatch.setattr(TimeStepper, "max_substep_depth", 0)
    ball = {"type": "sphere", "centre": [0.5, 0.5, 0.0], "radius": 0.25}
    sim = ClothSim(_scene(level=5, obstacles=[ball], origin=(0.0, 0.0, 0.3),
                          integrator=integrator))
    sim.state.velocities[:] = [0.0, 0.0, -5.0]
    initial = sum(sim.energy().values())
    stats = [sim.step() for _ in range(12)]
    strain = max(s.max_strain for s in stats)
    energy = max(s.total_energy for s in stats)
    if control:
        assert max(s.substeps for s in stats) > 1
        assert strain < 0.1 and energy < 1.01 * initial
    else:
        assert all(s.substeps == 1 for s in stats)
        assert strain > 0.3 and energy > 5 * initial


def test_a_fast_impact_keeps_the_layers_apart_with_self_collision():
    """The impact above with self-collision on (the default, auto): the free
    corners whip round the sphere at 11-13 m/s and fold over; no two
    triangles may cross at any step, and the strain stays that of the
    impact without folds (< 0.1)."""
    from cloth_lod_ros.tools.stress.intersect import intersecting_pairs
    ball = {"type": "sphere", "centre": [0.5, 0.5, 0.0], "radius": 0.25}
    sim = ClothSim(_scene(level=5, obstacles=[ball], origin=(0.0, 0.0, 0.3),
                          self_collision=True))
    sim.state.velocities[:] = [0.0, 0.0, -5.0]
    for _ in range(6):
        s = sim.step()
        assert not len(intersecting_pairs(sim.positions, sim.triangles))
        assert s.max_strain < 0.1


def test_patch_grasp_under_lod_holds_the_particles_splits_make_inside_it():
    """A patch grasp closed on a coarse adaptive mesh holds the particles that
    later splits create inside the patch, so it stays rigid when it turns."""
    lod = {"enabled": True, "initial_level": 1, "min_lifetime": 0.0}
    sim = ClothSim(_scene(level=5, lod=lod, gravity=(0, 0, 0),
                          grasps=[{"name": "hand", "uv": [0.5, 1.0], "width": 0.3,
                                   "close_time": 0.0}]))
    sim.step()
    g = sim.grasp("hand")
    before_nodes = len(g.nodes)
    for _ in range(4):
        corners = sim.rest_uv[sim.triangles]                       # (t, 3, 2)
        near = (np.linalg.norm(corners - [0.5, 1.0], axis=2) < 0.2).any(axis=1)
        for tri in sim.triangle_ids[near]:
            sim.refine(int(tri))
    inside = np.linalg.norm(sim.rest_uv - [0.5, 1.0], axis=1) <= 0.15 + 1e-12
    assert inside.sum() > before_nodes
    assert set(sim.vertex_ids[inside]) <= set(g.nodes.tolist())
    held = np.searchsorted(sim.vertex_ids, g.nodes)
    before = sim.positions[held].copy()
    centre = g.position.copy()
    sim.set_grasp_target("hand", centre, orientation=[0.0, 0.0, np.sin(np.pi / 4),
                                                      np.cos(np.pi / 4)])
    for _ in range(30):
        sim.step()
    held = np.searchsorted(sim.vertex_ids, g.nodes)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(sim.positions[held], centre + (before - centre) @ rot.T,
                               atol=1e-9)


def test_set_applies_to_every_case_and_a_bad_value_is_refused(monkeypatch, capsys):
    assert stress.build_scene(TINY, True, True, ["solver.method=direct"]).solver.method == "direct"
    code, out = _run(monkeypatch, capsys, [TINY], ["--quick", "--lod", "off",
                                                    "--set", "solver.method=multigrid"])
    assert code == 0 and "1/1 runs passed" in out
