"""Reproduce the paper's §6.1 comparisons (Figs. 7, 8, 9) through the product's own solver, and time it against a
well-written plain FABRIK; print ONE JSON object.

Run: `.ci/with-bpy python bench/paper_experiments.py [--cases 200]` (pure numpy; no Blender needed; a few
minutes on a loaded machine).

Figs. 7 and 8 are solved by solver.adjust.adjust_frames, what Adjust Pose, Adjust Frames and the command line
run, on a small body model defined here (scene units; tolerance 1e-5, the product's ChainSettings):
    pelvis (the root) below the trunk base (0,0,0); trunk 0 -> SC (0,0,0.9) in three 0.3 segments; arm A
    (arm.L) and arm B (arm.R) from the SC along +x and -x, each a clavicle, upper arm and forearm of 0.25 and a
    hand; a neck of three 0.25 segments along +y from the SC and a head (the third "arm" of Fig. 8); legs of
    two 0.4 segments, knees a little bent, and feet whose ankles are held where they are (planted, priority
    4, so the pelvis translates only as far as the feet allow, and the trunk does the work as in the paper's
    chains).
Each figure is solved for the three sub-base variants (solver/vocabulary.py): 'priority' (paper variant 2, the
product's default), 'weighted' (variant 1, eq. 4) and 'fabrik' (plain FABRIK's unweighted centroid), each
with the joints free as in the paper's chains (use_limits=False) and with the default human joint limits, and
for the plain multi-effector FABRIK of bench/plain_fabrik.py (free joints, fixed pelvis).
(a) Fig. 7 - two targets, each reachable alone, not both: hand A (priority 3) at (0.6, 0.4, 1.2), hand B
    (priority 1) at (-0.9, -0.5, 0.2). Reported: residual of the high- and low-priority task, status, chain
    iterations the solve spent, SC and pelvis displacement.
(b) Fig. 8 - three targets, two beyond reach: hand A (priority 3) at (0.35, 0.1, 0.95), reachable; hand B
    (priority 2) at (-2.5, 0, 0.9) and the head (priority 1) at (2.0, 0.5, 1.0). Same figures; the paper
    measured 426 (FABRIK) vs 71 (priority) iterations until the high-priority target was met. The product
    places the sub-bases first and then solves each chain, so its count is the chain iterations of the whole
    solve (met or not), not FABRIK sweeps of the tree. Also --random-cases random cases of the same kind
    (hand A's target 0.2-0.6 from the SC, the other two 1.8-2.5 from the trunk base, seed 8), all solved in
    one vectorised call per method: how often the high-priority target is met and the iterations spent.
(c) Fig. 9 - a five-joint arm (four 0.25 segments along +x from the origin) reaching (0.2, 0, 0.7) past two
    boxes [0.3,0.5]x[-0.15,0.15]x[0.12,0.3] and [0.45,0.65]x[-0.15,0.15]x[0.45,0.65], solved by
    solve_chain_batch (the chain solve adjust_frames runs for every chain) without and with the boxes (margin
    0.01): joints inside and segments crossing a box, residual and status.
(d) Speed - --cases random Fig. 8 cases, ours (adjust_frames, default variant) against plain FABRIK
    (bench/plain_fabrik.py: numpy, vectorised over frames like ours, the same tolerance, iteration cap and
    converged-frame masking). Same limits: ours with use_limits=False (the baseline has none); ours with the
    default limits is timed too. µs per case one case per call (--single-cases of them) and all cases in one
    call; best of 3 runs each, ratios from this run.
"""

import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from command_line import whole_number_options  # noqa: E402
from fullbody_adjust.solver import Boxes, penetrations  # noqa: E402
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch  # noqa: E402
from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames  # noqa: E402
from fullbody_adjust.solver.body.model import BodyModel  # noqa: E402
from fullbody_adjust.solver.vocabulary import VARIANTS  # noqa: E402
from plain_fabrik import plain_fabrik  # noqa: E402
from timing import best_time  # noqa: E402

SC = np.array([0.0, 0.0, 0.9])
EFFECTORS = ("hand.L", "hand.R", "head", "foot.L", "foot.R")
FEET_PRIORITY = 4.0
TOL = AdjustSettings().chain.tolerance


def small_body():
    """(model, heads (J,3), tails (J,3)) of the body described in the module docstring."""
    bones = []  # (name, parent, head, tail)

    def add(name, parent, head, tail):
        bones.append((name, parent, np.array(head, float), np.array(tail, float)))

    add("pelvis", None, (0, 0, -0.1), (0, 0, 0))
    add("spine1", "pelvis", (0, 0, 0), (0, 0, 0.3))
    add("spine2", "spine1", (0, 0, 0.3), (0, 0, 0.6))
    add("spine3", "spine2", (0, 0, 0.6), SC)
    groups = {"root": ["pelvis"], "trunk": ["spine1", "spine2", "spine3"]}
    for side, direction, names in (("L", (1, 0, 0), ("clavicle", "upper_arm", "forearm", "hand")),
                                   ("R", (-1, 0, 0), ("clavicle", "upper_arm", "forearm", "hand")),
                                   (None, (0, 1, 0), ("neck1", "neck2", "neck3", "head"))):
        parent = "spine3"
        for k, base in enumerate(names):
            name = f"{base}.{side}" if side else base
            add(name, parent, SC + 0.25 * k * np.array(direction), SC + 0.25 * (k + 1) * np.array(direction))
            parent = name
        if side:
            groups[f"arm.{side}"] = [f"{n}.{side}" for n in names[:3]]
            groups[f"hand.{side}"] = [f"hand.{side}"]
        else:
            groups["head"] = list(names)
    for side, x in (("L", 0.1), ("R", -0.1)):
        add(f"thigh.{side}", "pelvis", (x, 0, -0.1), (x, 0.05, -0.497))
        add(f"shin.{side}", f"thigh.{side}", (x, 0.05, -0.497), (x, 0, -0.894))
        add(f"foot.{side}", f"shin.{side}", (x, 0, -0.894), (x, -0.15, -0.894))
        groups[f"leg.{side}"] = [f"thigh.{side}", f"shin.{side}"]
        groups[f"foot.{side}"] = [f"foot.{side}"]
    names = [b[0] for b in bones]
    parents = [-1 if b[1] is None else names.index(b[1]) for b in bones]
    model = BodyModel.from_description(names, parents, groups)
    return model, np.array([b[2] for b in bones]), np.array([b[3] for b in bones])


def _targets(model, heads, hands_and_head):
    """(F,5,3) targets: hand.L, hand.R, head from `hands_and_head` (F,3,3) (a NaN row: none), ankles planted."""
    ankles = heads[[model.groups["foot.L"][0], model.groups["foot.R"][0]]]
    f = hands_and_head.shape[0]
    return np.concatenate([hands_and_head, np.broadcast_to(ankles, (f, 2, 3))], axis=1)


def _methods():
    """{name: AdjustSettings} for every variant, joints free and with the default limits."""
    out = {}
    for variant in VARIANTS:
        out[f"{variant}_free"] = AdjustSettings(variant=variant, use_limits=False)
        out[f"{variant}_limits"] = AdjustSettings(variant=variant)
    return out


def _solve_all(model, heads, tails, targets, priorities):
    """{method: (residuals (F,3) of hand.L hand.R head, status (F,3), iterations (F,), sc/root shift (F,))}."""
    f = targets.shape[0]
    h, t = np.broadcast_to(heads, (f,) + heads.shape), np.broadcast_to(tails, (f,) + tails.shape)
    out = {}
    for name, settings in _methods().items():
        r = adjust_frames(model, h, t, targets, EFFECTORS, priorities, settings=settings)
        out[name] = (r.residuals[:, :3], r.status[:, :3], r.iterations, r.sc_displacement, r.root_displacement)
    chains, iterations = plain_fabrik(model, h, t, targets[:, :3], EFFECTORS[:3], TOL,
                                      AdjustSettings().chain.max_iterations)
    ends = np.stack([chains[n][:, -1] for n in ("arm.L", "arm.R", "head")], axis=1)
    res = np.where(np.isnan(targets[:, :3]).any(axis=2), np.nan, np.linalg.norm(ends - targets[:, :3], axis=2))
    status = np.where(res <= TOL, "reached", "not met")
    sc = np.linalg.norm(chains["trunk"][:, -1] - SC, axis=1)
    out["plain_fabrik"] = (res, status, iterations, sc, np.zeros(f))
    return out


def _figure(model, heads, tails, hands_and_head, priorities):
    out = {}
    for name, (res, status, iterations, sc, root) in _solve_all(
            model, heads, tails, _targets(model, heads, hands_and_head[None]), priorities).items():
        out[name] = {"high_priority_residual": float(res[0, 0]), "other_residuals": res[0, 1:][
                     np.isfinite(res[0, 1:])].tolist(), "status": status[0].tolist(),
                     "iterations": int(iterations[0]), "sc_displacement": float(sc[0]),
                     "pelvis_displacement": float(root[0])}
    return out


def fig7(model, heads, tails):
    targets = np.array([[0.6, 0.4, 1.2], [-0.9, -0.5, 0.2], [np.nan] * 3])
    return _figure(model, heads, tails, targets, [3.0, 1.0, 0.0, FEET_PRIORITY, FEET_PRIORITY])


FIG8_PRIORITIES = [3.0, 2.0, 1.0, FEET_PRIORITY, FEET_PRIORITY]


def random_fig8_targets(count, seed=8):
    """(count,3,3) hand A's target 0.2-0.6 from the SC, hand B's and the head's 1.8-2.5 from the trunk base."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(count, 3, 3))
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    dist = np.stack([rng.uniform(0.2, 0.6, count), rng.uniform(1.8, 2.5, count), rng.uniform(1.8, 2.5, count)], 1)
    base = np.array([SC, [0.0, 0, 0], [0.0, 0, 0]])
    return base + u * dist[..., None]


def fig8(model, heads, tails, random_cases):
    headline = _figure(model, heads, tails, np.array([[0.35, 0.1, 0.95], [-2.5, 0.0, 0.9], [2.0, 0.5, 1.0]]),
                       FIG8_PRIORITIES)
    hands_and_head = random_fig8_targets(random_cases)
    summary = {}
    for name, (res, _status, iterations, _sc, _root) in _solve_all(
            model, heads, tails, _targets(model, heads, hands_and_head), FIG8_PRIORITIES).items():
        met = res[:, 0] <= TOL
        summary[name] = {"high_priority_met": int(met.sum()),
                         "median_high_priority_residual": float(np.median(res[:, 0])),
                         "median_iterations": float(np.median(iterations)),
                         "median_iterations_when_met": float(np.median(iterations[met])) if met.any() else None}
    return {"headline": headline, "random_cases": {"cases": random_cases, **summary},
            "paper_iterations_until_met": {"fabrik": 426, "priority": 71}}


def fig9():
    start = np.array([[0.0, 0, 0], [0.25, 0, 0], [0.5, 0, 0], [0.75, 0, 0], [1.0, 0, 0]])
    target = np.array([0.2, 0.0, 0.7])
    boxes = Boxes(np.array([[0.3, -0.15, 0.12], [0.45, -0.15, 0.45]]), np.array([[0.5, 0.15, 0.3], [0.65, 0.15, 0.65]]))
    segments = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    out = {}
    for name, kwargs in (("without_obstacles", {}), ("ours", {"obstacles": boxes})):
        r = solve_chain_batch(start[None], target[None], **kwargs)[0]
        inside, crossing = penetrations(r.positions, segments, boxes)
        out[name] = {"joints_inside": int(inside), "segments_crossing": int(crossing), "residual": r.residual,
                     "status": r.status, "iterations": r.iterations}
    return out


def speed(model, heads, tails, cases, single_cases):
    targets = _targets(model, heads, random_fig8_targets(cases, seed=4))
    h, t = np.broadcast_to(heads, (cases,) + heads.shape), np.broadcast_to(tails, (cases,) + tails.shape)
    free = AdjustSettings(use_limits=False)
    cap = free.chain.max_iterations

    def ours(settings, rows):
        return adjust_frames(model, h[rows], t[rows], targets[rows], EFFECTORS, FIG8_PRIORITIES, settings=settings)

    def baseline(rows):
        return plain_fabrik(model, h[rows], t[rows], targets[rows, :3], EFFECTORS[:3], TOL, cap)

    every = slice(None)
    singles = [slice(i, i + 1) for i in range(min(single_cases, cases))]
    batch = {"ours_free": best_time(lambda: ours(free, every)) / cases,
             "ours_limits": best_time(lambda: ours(AdjustSettings(), every)) / cases,
             "plain_fabrik": best_time(lambda: baseline(every)) / cases}
    one = {"ours_free": best_time(lambda: [ours(free, s) for s in singles]) / len(singles),
           "ours_limits": best_time(lambda: [ours(AdjustSettings(), s) for s in singles]) / len(singles),
           "plain_fabrik": best_time(lambda: [baseline(s) for s in singles]) / len(singles)}
    r = ours(free, every)
    _chains, base_iterations = baseline(every)
    return {
        "cases": cases, "single_cases": len(singles),
        "us_per_case_vectorised": {k: v * 1e6 for k, v in batch.items()},
        "us_per_case_one_per_call": {k: v * 1e6 for k, v in one.items()},
        "ratio_ours_free_over_plain_fabrik": {"vectorised": batch["ours_free"] / batch["plain_fabrik"],
                                              "one_per_call": one["ours_free"] / one["plain_fabrik"]},
        "ratio_ours_limits_over_plain_fabrik": {"vectorised": batch["ours_limits"] / batch["plain_fabrik"],
                                                "one_per_call": one["ours_limits"] / one["plain_fabrik"]},
        "mean_iterations": {"ours_free": float(r.iterations.mean()), "plain_fabrik": float(base_iterations.mean())},
        "high_priority_met": {"ours_free": int(np.sum(r.residuals[:, 0] <= TOL))},
    }


def main():
    args = whole_number_options(__doc__, ("--random-cases", 60, "random Fig. 8 cases"),
                                ("--cases", 200, "random cases in the speed comparison"),
                                ("--single-cases", 20, "of those, timed one per call"))
    t0 = time.perf_counter()
    model, heads, tails = small_body()
    report = {
        "setup": "synthetic scenes defined in the docstring of bench/paper_experiments.py; tolerance %g" % TOL,
        "solver": "solver.adjust.adjust_frames (the product's solve); variants x {free joints, default limits}; "
                  "plain_fabrik = bench/plain_fabrik.py",
        "python": platform.python_version(), "numpy": np.__version__,
        "fig7_two_targets": fig7(model, heads, tails),
        "fig8_three_targets": fig8(model, heads, tails, args.random_cases),
        "fig9_obstacles": fig9(),
        "speed_fig8_cases": speed(model, heads, tails, args.cases, args.single_cases),
    }
    report["bench_seconds"] = time.perf_counter() - t0
    print(json.dumps(report, indent=1, default=lambda o: o.tolist() if isinstance(o, np.ndarray) else str(o)))


if __name__ == "__main__":
    main()
