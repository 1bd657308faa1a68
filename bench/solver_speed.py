"""Speed of one Adjust Pose solve on the Rigify full human metarig (159 bones), feet planted, hands moved.

Cases (tests/helpers/metarig.py): 'near' (both hands within their arms' reach), 'far' (the left hand's target
beyond any reach), 'obstacle' (a box where the left forearm would go). For each case, in the same run:
  - single_pose_us: median µs of solver.adjust.adjust_pose (one pose, what Adjust Pose and Live call) from a
    start pose prepared before (solver/fullbody/prepared.py: what every Live update after the first one costs);
  - single_pose_cold_us: the same by a copy of the model made before each call, which has kept nothing (the
    first Adjust Pose click on a rig), and ratio_prepared_to_cold = single_pose_us / that;
  - single_pose_new_start_us: from a start pose seen for the first time whose limbs but the right arm are as in
    the start before (a click after a click that moved the right hand: only that limb is prepared again);
  - batch_one_frame_us: median µs of solver.adjust.adjust_frames with F = 1 (the batch path);
  - ratio_single_to_batch: single_pose_us / batch_one_frame_us;
  - batch_per_frame_us: µs per frame of adjust_frames over --frames frames of the case (targets jittered),
    and ratio_single_to_batch_frame = single_pose_us / batch_per_frame_us (the price of one frame alone);
  - max_difference: largest |single - batch row| over heads, tails, rotations and residuals, for the case's
    pose and every jittered frame solved alone.
Timings are process CPU time (time.process_time), medians of --repeats runs (the batch of many frames: a third
as many, at least 5) taken in turn with the figure they are compared to, so other processes on a shared machine disturb them less; compare figures only within one run.

With --reference REV (a git revision of this repository, e.g. main), the same figures of that revision's solver
are taken in the same run, each reference call alternated with the call it is compared to, and reported under
"reference" with the ratios new / reference ("ratio_to_reference": medians; "min_ratio_to_reference": the
fastest runs').

Run: .ci/with-bpy python bench/solver_speed.py [--repeats 30] [--frames 32] [--reference REV]
(prints one JSON object)
"""

import argparse
import importlib
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import fullbody_adjust.solver.fullbody.adjust as current  # noqa: E402
from tests.helpers import metarig  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
_MINIMA = {}


def median_us(repeats, *fns):
    """Median µs of each function, run in turn (a, b, a, b, ...) so a change of machine load hits them alike (each
    one's fastest run is kept in _MINIMA)."""
    for fn in fns:
        fn()  # warm-up
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, out in zip(fns, times):
            t0 = time.process_time()
            fn()
            out.append(time.process_time() - t0)
    for fn, t in zip(fns, times):
        _MINIMA[fn] = 1e6 * float(np.min(t))
    return [1e6 * float(np.median(t)) for t in times]


def reference_solver(rev, into):
    """The solver package of git revision `rev` as its own package (fullbody_adjust_ref, unpacked under `into`):
    (its adjust module, its BodyModel, its Boxes)."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "fullbody_adjust"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", into], input=archive, check=True)
    Path(into, "fullbody_adjust").rename(Path(into, "fullbody_adjust_ref"))
    sys.path.insert(0, into)
    # Where the modules are: by concept (solver/fullbody/, body/, obstacles/), or the flat solver/ of revisions
    # before that layout (e.g. 26b640e, the one-solver issue's baseline).
    layouts = (("fullbody.adjust", "body.model", "obstacles.boxes"), ("adjust", "body", "obstacles"))
    flat = not Path(into, "fullbody_adjust_ref", "solver", "fullbody").is_dir()
    adjust, body, boxes = (importlib.import_module(f"fullbody_adjust_ref.solver.{name}") for name in layouts[flat])
    return adjust, body.BodyModel, boxes.Boxes


def options():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30, help="timed runs per figure")
    parser.add_argument("--frames", type=int, default=32, help="frames in the batch timing")
    parser.add_argument("--reference", default=None, help="a git revision whose solver is timed alongside")
    return parser.parse_args()


def max_difference(a, b):
    worst = 0.0
    for field in ("heads", "tails", "rotations", "residuals"):
        x, y = getattr(a, field), getattr(b, field)
        both = ~(np.isnan(x) & np.isnan(y))
        worst = max(worst, float(np.max(np.abs(x - y)[both], initial=0.0)))
    return worst


def timed_functions(solver, model, heads, tails, x_axes, targets, frames_targets, kwargs):
    """(single, batch_one, cold, new_start, batch_many) of one solver (an adjust module) on one case."""
    adjust_frames, adjust_pose = solver.adjust_frames, solver.adjust_pose
    n = len(frames_targets)

    def single(t=targets, solving=model):
        return adjust_pose(solving, heads, tails, t, metarig.EFFECTORS, metarig.PRIORITIES,
                           bone_x_axes=x_axes, **kwargs)

    def cold():
        return single(solving=replace(model))

    wrist, starts = model.limbs["arm.R"].end_bone, [0]

    def new_start():
        # A start seen for the first time whose other limbs are as in the one before (a click after a click
        # that moved the right hand; the left arm's box makes its solve's cost depend on the tiniest change of
        # its own start): prepared again, the unchanged limbs' limits and checks kept.
        starts[0] += 1
        h = heads.copy()
        h[wrist] += 1e-7 * starts[0]
        return adjust_pose(model, h, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x_axes,
                           **kwargs)

    def batch_one():
        return adjust_frames(model, heads[None], tails[None], targets[None], metarig.EFFECTORS,
                             metarig.PRIORITIES, bone_x_axes=x_axes[None], **kwargs)

    def batch_many():
        return adjust_frames(model, np.repeat(heads[None], n, 0), np.repeat(tails[None], n, 0), frames_targets,
                             metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=np.repeat(x_axes[None], n, 0),
                             **kwargs)

    return single, batch_one, cold, new_start, batch_many


def main():
    args = options()
    model, heads, tails, x_axes = metarig.load()
    rng = np.random.default_rng(7)
    out = {"rig": f"Rigify human metarig, {len(model.names)} bones", "cases": {}}
    reference = None
    if args.reference:
        tmp = tempfile.TemporaryDirectory()
        ref_adjust, ref_body, ref_boxes = reference_solver(args.reference, tmp.name)
        with np.load(metarig.DATA) as data:
            ref_model = ref_body.from_description([str(n) for n in data["names"]], data["parents"].tolist(),
                                                  json.loads(str(data["groups"])))
        out["reference"] = {"revision": args.reference, "cases": {}}
    for kind in metarig.CASES:
        targets, boxes = metarig.case(model, heads, tails, kind)
        jitter = rng.normal(scale=0.02, size=(args.frames, len(metarig.EFFECTORS), 3))
        jitter[0] = 0.0
        frames_targets = targets[None] + jitter  # the head's NaN row stays NaN (no target)
        n = args.frames
        fns = timed_functions(current, model, heads, tails, x_axes, targets, frames_targets, dict(obstacles=boxes))
        single, batch_one, cold, new_start, batch_many = fns
        if args.reference:
            ref_kwargs = dict(obstacles=None if boxes is None else ref_boxes(boxes.mins, boxes.maxs, boxes.axes))
            reference = timed_functions(ref_adjust, ref_model, heads, tails, x_axes, targets, frames_targets,
                                        ref_kwargs)
            pairs = [f for pair in zip(fns[:4], reference[:4]) for f in pair]
            times = median_us(args.repeats, *pairs)
            single_us, batch1_us, cold_us, new_us = times[0::2]
            ref_times = times[1::2]
            many_pair = median_us(max(5, args.repeats // 3), batch_many, reference[4])
            many_us, ref_many = many_pair[0] / n, many_pair[1] / n
            names = ("single_pose_us", "batch_one_frame_us", "single_pose_cold_us", "single_pose_new_start_us",
                     "batch_per_frame_us")
            mins = [_MINIMA[f] for f in fns[:4]] + [_MINIMA[batch_many] / n]
            ref_mins = [_MINIMA[f] for f in reference[:4]] + [_MINIMA[reference[4]] / n]
            new_all = [single_us, batch1_us, cold_us, new_us, many_us]
            ref_all = ref_times + [ref_many]
            out["reference"]["cases"][kind] = {
                name: {"new": round(a, 1), "reference": round(b, 1), "ratio_to_reference": round(a / b, 3),
                       "min_ratio_to_reference": round(m / mr, 3)}
                for name, a, b, m, mr in zip(names, new_all, ref_all, mins, ref_mins)}
        else:
            single_us, batch1_us, cold_us, new_us = median_us(args.repeats, single, batch_one, cold, new_start)
            many_us = median_us(max(5, args.repeats // 3), batch_many)[0] / n
        many = batch_many()
        diff = max_difference(single(), batch_one()[0])
        for f in range(n):
            diff = max(diff, max_difference(single(frames_targets[f]), many[f]))
        result = single()
        out["cases"][kind] = {
            "single_pose_us": round(single_us, 1),
            "single_pose_cold_us": round(cold_us, 1),
            "ratio_prepared_to_cold": round(single_us / cold_us, 3),
            "single_pose_new_start_us": round(new_us, 1),
            "batch_one_frame_us": round(batch1_us, 1),
            "ratio_single_to_batch": round(single_us / batch1_us, 3),
            "batch_per_frame_us": round(many_us, 1),
            "ratio_single_to_batch_frame": round(single_us / many_us, 3),
            "max_difference": diff,
            "status": result.status.tolist(),
            "max_residual": float(np.nanmax(result.residuals)),
            "chain_iterations": result.iterations,
        }
    out["max_difference"] = max(c["max_difference"] for c in out["cases"].values())
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
