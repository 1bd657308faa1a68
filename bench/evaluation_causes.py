"""What each evaluation of a generated Rigify rig is spent on while its controls are placed (rig evaluations per
update), on bench/interactive.py's cases and drag, with Live on or by clicks.

Each placement (control_match.match_controls) is counted: its evaluations, the first of which shows the result
(a click or a Live update has just evaluated the rig, and the matching does not evaluate it first); every further
evaluation is charged to what the one before it left off (the pairs over their tolerance): ``length`` (a scale
pair: a stretchy IK chain's length), ``end`` (an IK end control's pair: the IK's own miss), ``bend`` (an IK
chain's bend plane), ``other`` (an FK or trunk control), joined by ``+`` when several were. Per case: placements,
evaluations per placement, and each cause's extra evaluations per placement. The placements include the one
turning Live on runs (bench/interactive.py divides its count by the updates alone).

Run: .ci/with-bpy python bench/evaluation_causes.py [--repeat 5] [--steps 300]   (one JSON object on stdout)
"""

import collections
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402

import fullbody_adjust  # noqa: E402
from bench import drag_path, interactive  # noqa: E402
from bench.command_line import stdout_to_stderr, whole_number_options  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust.bridge.rig import control_match  # noqa: E402

KINDS = {"scale": "length", "bend": "bend"}


class Causes:
    """Counts of placements, evaluations and extra evaluations by cause since reset()."""

    def __init__(self):
        self.counts = collections.Counter()
        self.evaluations, self.missed, self.tolerance = 0, set(), 0.0
        match, pair_error = control_match.match_controls, control_match._pair_error
        causes = self

        class CountingViewLayer:
            def __init__(self, view_layer):
                self.view_layer = view_layer

            def update(self):
                causes.evaluations += 1
                causes.counts["evaluations"] += 1
                if causes.evaluations > 1:
                    causes.counts["+".join(sorted(causes.missed)) or "unchecked"] += 1
                causes.missed = set()
                self.view_layer.update()

        def counted_match(obj, view_layer, pairs, desired, tolerance, *args, **kwargs):
            causes.evaluations, causes.missed, causes.tolerance = 0, set(), tolerance
            causes.counts["placements"] += 1
            return match(obj, CountingViewLayer(view_layer), pairs, desired, tolerance, *args, **kwargs)

        def checked(pose_bones, pair, desired, lengths):
            error = pair_error(pose_bones, pair, desired, lengths)
            if error > control_match._tolerance(pair, causes.tolerance):
                causes.missed.add(KINDS.get(pair.kind, "end" if pair.follows_control else "other"))
            return error

        control_match.match_controls, control_match._pair_error = counted_match, checked

    def report(self):
        counts = dict(self.counts)
        placements, evaluations = counts.pop("placements", 0), counts.pop("evaluations", 0)
        out = {"placements": placements, "evaluations_per_placement": round(evaluations / max(placements, 1), 2)}
        out["extra_per_placement"] = {cause: round(n / max(placements, 1), 2) for cause, n in sorted(counts.items())}
        self.counts.clear()
        return out


def main():
    args = whole_number_options(__doc__, ("--repeat", 5, "repetitions per case"),
                                ("--steps", 300, "steps of the scripted drag (0: no drag)"))
    interactive.SOLVER, interactive.EVALUATIONS = interactive.SolverClock(), interactive.EvaluationCounter()
    causes = Causes()
    report = {"blender": bpy.app.version_string, "repeat": args.repeat, "steps": args.steps, "cases": {}}
    with stdout_to_stderr():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        fullbody_adjust.register()
        scene = interactive.Scene(interactive.add_rig("generated"))
        for case in interactive.CASES:
            if case == "obstacle":
                scene.add_obstacle()  # places the box with Live on: not counted
                causes.report()
            for name, timer in (("click", interactive.time_adjust_pose), ("live", interactive.time_live)):
                timer(scene, case, args.repeat)
                report["cases"][f"{case} {name}"] = causes.report()
        if args.steps:
            start = scene.goals("near", 0)
            scene.drag = [dict(start, **{"hand.R": point})
                          for point in drag_path.positions(drag_path.waypoints(scene), args.steps)]
            scene.add_obstacle(scene.drag[(5 * (args.steps - 1)) // 6], side="R")
            causes.report()
            interactive.time_live(scene, "drag", args.steps)
            report["cases"]["drag live"] = causes.report()
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
