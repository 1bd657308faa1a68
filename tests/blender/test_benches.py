"""The benches that drive Blender end to end run through the bpy module, print their one JSON report and exit 0: a
bench whose calls went stale fails here rather than when somebody next measures. Few repetitions each; no time is
checked, only what the benches report of the poses they measured."""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def run_bench(tmp_path, name, *args):
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    done = subprocess.run([sys.executable, str(REPO / "bench" / name), *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


def test_interactive_bench_measures_every_rig_and_case(tmp_path):
    steps = 24
    report = run_bench(tmp_path, "interactive.py", "--repeat", "3", "--steps", str(steps))  # a median, not one update
    assert set(report["rigs"]) == {"basic", "full", "generated"}
    for kind, rig in report["rigs"].items():
        assert set(rig["cases"]) == {"near", "far", "obstacle"}
        for case, measures in rig["cases"].items():
            for name in ("adjust_pose_ms", "live_update_ms", "live_floor_ms", "blender_ik_ms"):
                assert measures[name]["median"] > 0.0, (kind, case, name, measures[name])
            # The floor replays the poses Live showed without solving: below the real update by the solve's time.
            assert measures["live_floor_ms"]["median"] < measures["live_update_ms"]["median"], (kind, case)
            for name in ("adjust_pose_ms", "live_update_ms"):  # only a control rig is evaluated to place controls
                evaluations = measures[name].get("rig_evaluations_per_update")  # at least the one that shows it
                assert (evaluations >= 1) if kind == "generated" else (evaluations is None), (kind, case, name)
            for name in ("adjust_pose_ms", "live_update_ms"):  # wrists from the evaluated pose, in arm lengths
                if case == "far":
                    assert measures[name]["hand_residual"] > 0.1, (kind, name)  # 2.5 arm lengths away
                else:
                    assert measures[name]["hand_residual"] < 1e-4, (kind, case, name)
        drag = rig["drag"]  # the scripted drag: every update timed, Live's and the floor's and Blender's IK's
        for name in ("live_update_ms", "live_floor_ms", "blender_ik_ms"):
            figures = drag[name]
            assert figures["steps"] == steps, (kind, name, figures)
            assert 0.0 < figures["p50"] <= figures["p95"] <= figures["p99"] <= figures["worst"], (kind, name, figures)
        assert drag["live_floor_ms"]["p50"] < drag["live_update_ms"]["p50"], kind
        evaluations = drag["live_update_ms"].get("rig_evaluations_per_update")
        assert (evaluations >= 1) if kind == "generated" else (evaluations is None), (kind, evaluations)
        # The hand on its target where the path is within reach, far off at 2.5 arm lengths; Blender's IK acts.
        residual = drag["live_update_ms"]["hand_residual"]
        assert max(residual[at] for at in ("start", "back", "end")) < 1e-4 < 0.1 < residual["far"], (kind, residual)
        assert drag["blender_ik_ms"]["hand_residual"]["start"] < 1e-3, (kind, drag["blender_ik_ms"])


def test_ik_limits_bench_reads_the_limits_it_set(tmp_path):
    report = run_bench(tmp_path, "ik_limits.py", "--repeat", "1")
    assert report["bones"] == 159
    for name in ("adjust_plain", "read_plain", "adjust_set", "read_set", "defaults"):
        assert report[name]["median_ms"] > 0.0
