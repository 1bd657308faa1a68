"""Fuzz of the full-body adjustment: random problems solved in batches as the product solves them
(solver.adjust_frames; solver.adjust_pose for one pose), on the Rigify human metarig (159 bones).

Problems (tests/helpers/random_bodies.py): random start poses (every bone turned, bone lengths kept), scale (the
body's height) from 1e-3 to 1e3, targets per effector none (a NaN row), at its own joint, within reach, about the
reach's edge, far beyond it, at the root, at the limb's base, coincident with another target; random boxes; random
priorities, sub-base variant, poles and wanted hand/foot orientations. A batch is one problem over --batch frames
that differ by a small jitter (1e-9 to 1e-2 of the height), as a clip's frames do.

Checked on every frame:
  - nan_outputs: frames with a NaN or inf in heads, tails, rotations or displacements, or a NaN residual where the
    effector has a target (must be 0);
  - lengths: the largest relative change of a bone's length (head to tail) and of its head's distance from its
    parent's head (must stay within 1e-9);
  - statuses: how many effectors ended in each status.
Timed: --sample frames of each batch solved alone (adjust_pose, process time; a batch has one time): the slowest
against the median of its batch (goal: none above 10x), the worst batches listed with their seed and kinds to
reproduce them (batch k's generator is numpy's default_rng([seed, k])); each such single solve is also compared to
its row of the batch, bit for bit (mismatches). Counted: the chain iterations each frame spent (the batch's
result.iterations), their median, 99th percentile and largest, and those of each worst batch's slowest frame.
Bad input: --bad problems with a target, start pose, pole or box holding NaN or inf where a number must be: each
must be refused with one SolverInputError line (refused), never solved (solved) nor fail otherwise (failed).

Run: .ci/with-bpy python bench/fuzz.py [--problems 10000] [--batch 20] [--sample 6] [--bad 300] [--seed 0]
(prints one JSON object)
"""

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fullbody_adjust.solver import AdjustSettings, Boxes, SolverInputError, adjust_frames, adjust_pose  # noqa: E402
from fullbody_adjust.solver.vocabulary import VARIANTS  # noqa: E402
from tests.helpers import metarig  # noqa: E402
from tests.helpers import random_bodies  # noqa: E402
from tests.helpers.random_bodies import EFFECTORS  # noqa: E402

LENGTH_TOLERANCE = 1e-9
SLOW = 10.0  # a frame this many times slower than its batch's median is a bad case


def options(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=10000, help="frames solved in all (rounded up to batches)")
    parser.add_argument("--batch", type=int, default=20, help="frames per batch")
    parser.add_argument("--sample", type=int, default=6, help="frames of each batch also solved and timed alone")
    parser.add_argument("--bad", type=int, default=300, help="problems with NaN or inf input")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args(argv)


def solve_options(rng, b):
    """Random priorities, settings, poles and end turns for batch `b` (random_bodies.Batch)."""
    frames = b.targets.shape[0]
    priorities = rng.choice([0.0, 1.0, 2.0, 3.0], len(EFFECTORS))
    settings = AdjustSettings(variant=str(rng.choice(VARIANTS)), feet_first=bool(rng.random() < 0.8))
    poles = end_turns = None
    if rng.random() < 0.25:  # poles for some hands and feet: a point off the limb, near its target
        poles = np.full(b.targets.shape, np.nan)
        some = rng.random(4) < 0.6
        poles[:, :4][:, some] = b.targets[:, :4][:, some] + rng.normal(size=(frames, int(some.sum()), 3)) * b.height
    if rng.random() < 0.25:  # wanted orientations for some hands and feet
        end_turns = np.full(b.targets.shape + (3,), np.nan)
        some = rng.random(4) < 0.6
        turns = random_bodies.rotations(rng, int(some.sum()), np.full(int(some.sum()), np.pi))
        end_turns[:, :4][:, some] = turns[None]
    return priorities, settings, poles, end_turns


def frame_problems(rig, b, extra):
    """adjust_frames' arguments of batch `b` and its `extra` options."""
    priorities, settings, poles, end_turns = extra
    return (rig[0], b.heads, b.tails, b.targets, EFFECTORS, priorities), dict(
        obstacles=b.obstacles, settings=settings, bone_x_axes=b.x_axes, poles=poles, end_turns=end_turns)


def one_frame(args, kwargs, f):
    """adjust_pose's arguments for frame f of a batch."""
    model, heads, tails, targets, effectors, priorities = args
    boxes = kwargs["obstacles"]
    pick = (lambda a: None if a is None else a[f])  # noqa: E731
    one = dict(kwargs, bone_x_axes=pick(kwargs["bone_x_axes"]), poles=pick(kwargs["poles"]),
               end_turns=pick(kwargs["end_turns"]),
               obstacles=None if boxes is None else Boxes(boxes.mins[f], boxes.maxs[f]))
    return (model, heads[f], tails[f], targets[f], effectors, priorities), one


def check_frames(model, b, result):
    """(frames with NaN output (F,) bool, largest relative length change (F,)) of batch `b`'s result."""
    active = np.isfinite(b.targets[..., 0])
    finite = (np.isfinite(result.heads).all(axis=(1, 2)) & np.isfinite(result.tails).all(axis=(1, 2))
              & np.isfinite(result.rotations).all(axis=(1, 2, 3)) & np.isfinite(result.sc_displacement)
              & np.isfinite(result.root_displacement) & ~(np.isnan(result.residuals) & active).any(axis=1))
    length0 = np.linalg.norm(b.tails - b.heads, axis=2)
    length = np.linalg.norm(result.tails - result.heads, axis=2)
    change = np.abs(length - length0) / length0
    child = np.nonzero(model.parents >= 0)[0]
    parent = model.parents[child]
    offset0 = np.linalg.norm(b.heads[:, child] - b.heads[:, parent], axis=2)
    offset = np.linalg.norm(result.heads[:, child] - result.heads[:, parent], axis=2)
    # A head on its parent's head has no length to keep relative to: measured against the body's height.
    offset_change = np.abs(offset - offset0) / np.maximum(offset0, b.height)
    worst = np.maximum(np.nan_to_num(change, nan=np.inf).max(axis=1),
                       np.nan_to_num(offset_change, nan=np.inf).max(axis=1))
    return ~finite, worst


def same_bits(single, batch, f):
    for field in ("heads", "tails", "rotations", "residuals", "sc_displacement", "root_displacement"):
        a = np.ascontiguousarray(getattr(single, field), dtype=np.float64)
        b = np.ascontiguousarray(getattr(batch, field)[f], dtype=np.float64)
        if not np.array_equal(a.view(np.int64), b.view(np.int64)):
            return False
    return (single.status == batch.status[f]).all() and (single.reasons == batch.reasons[f]).all()


def bad_inputs(rng, rig, count):
    """Problems with NaN or inf where a number must be: ({refused, solved, failed} counts, the most common messages,
    the first problems solved)."""
    model = rig[0]
    out, messages, solved = Counter(), Counter(), []
    for k in range(count):
        b = random_bodies.batch(rng, rig, 1, boxes=int(rng.choice([0, 2])))
        args, kwargs = frame_problems(rig, b, solve_options(rng, b))
        model, heads, tails, targets, effectors, priorities = args
        heads, tails, targets = heads.copy(), tails.copy(), targets.copy()
        bad = rng.choice([np.nan, np.inf, -np.inf])
        what = ["target", "head", "tail", "pole", "end_turn", "x_axis", "box"][k % 7]
        e, j = rng.integers(len(EFFECTORS)), rng.integers(heads.shape[1])
        if what == "target":  # part of a row (an all-NaN row is "no target", not an error)
            targets[0, e] = np.where(np.isfinite(targets[0, e]), targets[0, e], heads[0, model.root])
            targets[0, e, rng.integers(3)] = bad
        elif what == "head":
            heads[0, j, rng.integers(3)] = bad
        elif what == "tail":
            tails[0, j, rng.integers(3)] = bad
        elif what == "pole":
            poles = np.zeros(targets.shape)
            poles[0, e, rng.integers(3)] = bad
            kwargs["poles"] = poles
        elif what == "end_turn":
            turns = np.broadcast_to(np.eye(3), targets.shape + (3,)).copy()
            turns[0, e, rng.integers(3), rng.integers(3)] = bad
            kwargs["end_turns"] = turns
        elif what == "x_axis":
            x = b.x_axes.copy()
            x[0, j, rng.integers(3)] = bad
            kwargs["bone_x_axes"] = x
        try:
            if what == "box":
                mins = rng.normal(size=(1, 2, 3))
                mins[0, 0, rng.integers(3)] = bad
                kwargs["obstacles"] = Boxes(mins, mins + 1.0)
            result = adjust_frames(model, heads, tails, targets, effectors, priorities, **kwargs)
        except SolverInputError as error:
            one_line = "\n" not in str(error) and str(error).strip() != ""
            out["refused" if one_line else "refused_not_one_line"] += 1
            messages[f"{what}: {error}"] += 1
        except Exception as error:  # noqa: BLE001  (what the fuzz looks for)
            out["failed"] += 1
            messages[f"{what}: {type(error).__name__}: {error}"] += 1
        else:
            nan, _ = check_frames(model, b, result)
            out["solved_with_nan" if nan.any() else "solved"] += 1
            solved.append({"what": what, "value": str(bad), "effector": EFFECTORS[e], "bone": int(j)})
    return dict(out), dict(messages.most_common(12)), solved[:5]


def _spread(x):
    return {"median": float(np.median(x)), "p99": float(np.percentile(x, 99)), "max": int(x.max()),
            "mean": round(float(x.mean()), 2)}


def run(problems, batch, sample, bad, seed, time_singles=True):
    """The fuzz report (a dict) of `problems` frames in batches of `batch`, `sample` per batch timed alone."""
    rig = metarig.load()
    model = rig[0]
    rng = np.random.default_rng(seed)
    batches = -(-problems // batch)
    statuses, kinds_seen = Counter(), Counter()
    nan_frames = mismatches = errors = 0
    worst_length = 0.0
    ratios, slow, error_cases, nan_cases, frame_iterations = [], [], [], [], []
    batch_seconds = single_seconds = 0.0
    singles = 0
    for k in range(batches):
        brng = np.random.default_rng([seed, k])
        b = random_bodies.batch(brng, rig, batch)
        extra = solve_options(brng, b)
        kinds_seen.update(b.kinds)
        args, kwargs = frame_problems(rig, b, extra)
        t0 = time.process_time()
        try:
            result = adjust_frames(*args, **kwargs)
        except Exception as error:  # noqa: BLE001  (valid input: any error is a finding)
            errors += 1
            error_cases.append({"batch": k, "kinds": b.kinds, "error": f"{type(error).__name__}: {error}"})
            continue
        batch_seconds += time.process_time() - t0
        nan, worst = check_frames(model, b, result)
        nan_frames += int(nan.sum())
        if nan.any():
            nan_cases.append({"batch": k, "frames": np.nonzero(nan)[0].tolist()[:5], "kinds": b.kinds})
        worst_length = max(worst_length, float(worst.max()))
        statuses.update(result.status.ravel().tolist())
        frame_iterations.append(result.iterations)
        if not time_singles or sample <= 0:
            continue
        times, frames = [], sorted(brng.choice(batch, min(sample, batch), replace=False).tolist())
        for f in frames:
            one_args, one_kwargs = one_frame(args, kwargs, f)
            t0 = time.process_time()
            single = adjust_pose(*one_args, **one_kwargs)
            times.append(time.process_time() - t0)
            mismatches += not same_bits(single, result, f)
        singles += len(times)
        single_seconds += sum(times)
        ratio = max(times) / float(np.median(times))
        ratios.append(ratio)
        slow.append({"batch": k, "ratio": round(ratio, 2), "slowest_ms": round(1e3 * max(times), 2),
                     "median_ms": round(1e3 * float(np.median(times)), 2),
                     "slowest_iterations": int(result.iterations[frames[int(np.argmax(times))]]),
                     "median_iterations": float(np.median(result.iterations[frames])), "kinds": b.kinds,
                     "boxes": 0 if b.obstacles is None else len(b.obstacles), "height": b.height,
                     "jitter": b.jitter})
    slow.sort(key=lambda case: -case["ratio"])
    refused, messages, accepted = bad_inputs(np.random.default_rng([seed, batches]), rig, bad)
    return {
        "rig": f"Rigify human metarig, {len(model.names)} bones",
        "seed": seed, "problems": batches * batch, "batches": batches, "frames_per_batch": batch,
        "errors": errors, "error_cases": error_cases[:5],
        "nan_outputs": nan_frames, "nan_cases": nan_cases[:5],
        "max_relative_length_change": worst_length, "lengths_within": worst_length <= LENGTH_TOLERANCE,
        "statuses": dict(statuses), "target_kinds": dict(kinds_seen),
        "iterations_per_frame": _spread(np.concatenate(frame_iterations) if frame_iterations else np.zeros(1)),
        "bad_inputs": refused, "bad_input_messages": messages, "bad_inputs_solved": accepted,
        "timing": {
            "batch_ms_per_frame": round(1e3 * batch_seconds / max(1, batches * batch), 3),
            "singles_timed": singles,
            "single_ms_per_frame": round(1e3 * single_seconds / max(1, singles), 3),
            "slowest_to_median_of_batch": {"max": round(max(ratios, default=0.0), 2),
                                           "p99": round(float(np.percentile(ratios, 99)) if ratios else 0.0, 2),
                                           "median": round(float(np.median(ratios)) if ratios else 0.0, 2)},
            "batches_over_10x": sum(r > SLOW for r in ratios),
            "worst_batches": slow[:5],
        },
        "single_vs_batch_mismatches": mismatches,
    }


def main():
    args = options()
    t0 = time.time()
    report = run(args.problems, args.batch, args.sample, args.bad, args.seed)
    report["wall_seconds"] = round(time.time() - t0, 1)
    print(json.dumps(report, indent=1, default=str))


if __name__ == "__main__":
    main()
