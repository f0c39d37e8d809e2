"""``cloth-lod bench --contact``: contact scenes against their converged motion (issue 31).

The outside truth: a scene whose own settings are those of its converged
reference (uniform mesh, ``sdirk2`` at a fixed step, the reference's Newton
settings) with ``h_ref = H / 1`` is the same computation as its reference, so
the suite must find no distance between them at any sample time, while the
run at ``2 h_ref`` (a different computation) differs.  No timing assertions.
"""

from __future__ import annotations

import json
import math

import pytest
import yaml

from cloth_lod_ros.tools.bench import contact
from cloth_lod_ros.tools.bench.performance import write_report
from cloth_lod_ros.tools.reference import ConvergedReference


@pytest.fixture(scope="module")
def same_as_reference(tmp_path_factory):
    """``grasp_lift`` (contact with the table, two grasps) with the reference's
    settings at H/1, as a scene file; the suite run on it twice (the second from
    the reference cache)."""
    tmp = tmp_path_factory.mktemp("contact")
    scene = yaml.safe_load((contact.Path(contact.__file__).parents[3] / "config" / "scenes"
                            / "grasp_lift.yaml").read_text())
    ref = ConvergedReference(contact.QUICK["level"], scene["simulation"]["time_step"], 1)
    for item in ref.overrides():
        key, value = item.split("=", 1)
        section, name = key.split(".")
        scene.setdefault(section, {})[name] = yaml.safe_load(value)
    path = tmp / "grasp_lift_as_reference.yaml"
    path.write_text(yaml.safe_dump(scene))
    cache = tmp / "cache"
    runs = [contact.run_contact(tmp / f"out{i}", repeats=1, quick=True, progress=lambda *a: None,
                                scenes=(str(path),), divisor=1, cache=cache) for i in range(2)]
    return tmp, runs, cache


def test_the_reference_itself_is_at_zero_distance_and_its_double_step_is_not(same_as_reference):
    _, (first, _), _ = same_as_reference
    (row,) = first["rows"]
    assert row["times"] == list(contact.QUICK["times"])
    assert row["rms_frac"] == [0.0] * len(row["times"])
    assert row["max_frac"] == [0.0] * len(row["times"])
    # The run at 2 h_ref is another computation: its difference is the reference's
    # stated own error, positive and finite, and the Richardson estimate is a third.
    assert all(0.0 < d < 1.0 for d in row["reference_diff_rms_frac"])
    assert row["reference_richardson_rms_frac"] == pytest.approx(
        [d / 3 for d in row["reference_diff_rms_frac"]])
    assert row["cpu_per_sim_s_median"] > 0 and math.isfinite(row["cpu_per_sim_s_median"])
    assert row["reference_time_step"] == pytest.approx(row["frame_period_s"])
    # The sensitivity run really started elsewhere (by 1 nm), and over the quick
    # 0.5 s of a lift nothing amplifies that to a measurable fraction of the side.
    assert row["sensitivity_perturbation_m"] == contact.PERTURB
    assert all(0.0 < d < 1e-4 for d in row["sensitivity_rms_frac"])


def test_references_come_from_the_cache_the_second_time_with_the_same_numbers(same_as_reference):
    _, (first, second), cache = same_as_reference
    assert len(list(cache.glob("*.json"))) == 3   # the reference, its 2 h_ref and moved runs
    a, b = first["rows"][0], second["rows"][0]
    assert not a["reference_cached"] and b["reference_cached"]
    for key in ("rms_frac", "max_frac", "reference_diff_rms_frac", "reference_diff_max_frac",
                "sensitivity_rms_frac"):
        assert a[key] == b[key]


def test_cache_key_follows_the_run_and_the_simulator_sources():
    spec = dict(scene="grasp_lift", overrides=["cloth.level=3"], points=[[0.0, 0.0]],
                times=[0.25], duration=0.5)
    key = contact._cache_key(spec, "text", "fp")
    assert contact._cache_key(dict(spec, overrides=["cloth.level=4"]), "text", "fp") != key
    assert contact._cache_key(spec, "text", "other sources") != key
    assert contact._cache_key(spec, "other scene file", "fp") != key
    assert contact._cache_key(dict(spec, cpu=1, result="x"), "text", "fp") == key
    assert contact._cache_key(dict(spec, perturb=dict(size=1e-9, seed=1)), "text", "fp") != key


def test_report_shows_the_contact_table_with_its_command(same_as_reference):
    tmp, (first, _), _ = same_as_reference
    out = tmp / "out0"
    data = json.loads((out / "contact.json").read_text())
    data["command"] = f"cloth-lod bench --contact --quick --repeats 1 --out {out}"
    (out / "contact.json").write_text(json.dumps(data))
    page = write_report(tmp / "performance.md", out)
    assert "## Contact scenes against their converged motion" in page
    assert f"Command: `{data['command']}`" in page
    assert "| grasp_lift | 3 | 0 % (0 %) | 0 % (0 %) |" in page
