"""Full-body adjustment vs plain multi-effector FABRIK: the paper's Table 1 protocol (DESIGN.md §4) on CMU clips.

For captured poses sampled across the shared clips (frame 1, the T-pose, skipped): targets = the captured
wrists and ankles; start = the pose 60 frames earlier in the same clip, translated so its root sits on the
captured root (a different posture at the same place: the comparison is about posture, not travel). Both
methods start there; we compare each result to the captured pose:
  - mean joint angle error (radians): angles between adjacent segments of the body chains (every interior
    joint of the trunk, arms and legs, and each chain's first segment against its parent segment), as in the
    paper's Table 1;
  - mean per-joint position error: over the trunk, arm and leg chain joints.
Plus reach (median/max residual, share met), the "fewest moved joints" check (SC and root displacement on the
poses whose every target is within its limb's reach from the start pose: must be 0), the output's hinge
consistency (each forearm / shin must lie in its upper bone's hinge plane as the returned rotations turn it:
the elbow and knee are pure hinges; and how far the upper bones were twisted to turn the bend planes), and
speed: µs per pose one pose at a time and vectorised over 1,000 frames, as ratios against plain FABRIK in the
same run.

Plain FABRIK (the baseline) is implemented here: tree.py's 'centroid' strategy is not in the repository yet.
It is Aristidou & Lasenby's multi-end-effector FABRIK on the same chains with every joint free (no limits, no
obstacles): the pelvis and hips are fixed (FABRIK cannot move its root), the arms meet at the SC, which goes to
the unweighted centroid of the arms' proposals; same tolerance and iteration cap as our chains.

Run: .ci/with-bpy python bench/fullbody.py [--poses-per-clip 50]   (prints one JSON object)
"""

import argparse
import json
from dataclasses import replace
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fullbody_adjust.solver.adjust import AdjustSettings, adjust_frames, adjust_pose  # noqa: E402
from fullbody_adjust.solver.body import BodyModel, default_limits  # noqa: E402
from fullbody_adjust.solver.geometry import swing_rotation  # noqa: E402
from tests.helpers.bvh import CMU_CLIPS, CMU_GROUPS, read_cmu  # noqa: E402

EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R")
LIMBS = ("arm.L", "arm.R", "leg.L", "leg.R")
BODY_CHAINS = ("trunk", "arm.L", "arm.R", "leg.L", "leg.R")
LAG = 60


def sample_poses(poses_per_clip):
    """(model, captured heads/tails, start heads/tails) stacked over the clips (all share one skeleton)."""
    model, cap_h, cap_t, st_h, st_t, labels = None, [], [], [], [], []
    for name in CMU_CLIPS:
        clip = read_cmu(name)
        m = BodyModel.from_description(clip.names, clip.parents, CMU_GROUPS)
        if model is None:
            model = m
        elif m.names != model.names:
            raise SystemExit(f"{name}: a different skeleton")
        frames = np.linspace(1 + LAG, clip.frame_count - 1, poses_per_clip).astype(int)
        h, t = clip.bones(frames)
        h0, t0 = clip.bones(frames - LAG)
        shift = h[:, model.root] - h0[:, model.root]
        cap_h.append(h)
        cap_t.append(t)
        st_h.append(h0 + shift[:, None])
        st_t.append(t0 + shift[:, None])
        labels += [name] * len(frames)
    return model, np.concatenate(cap_h), np.concatenate(cap_t), np.concatenate(st_h), np.concatenate(st_t), labels


# ----------------------------------------------------------------------------------------------------------
# Plain multi-effector FABRIK (the baseline), vectorised over frames


def _place(anchor, toward, length, fallback):
    d = toward - anchor
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    ok = n > 1e-12 * length[..., None]
    d = np.where(ok, d, fallback)
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    return anchor + d * (length[..., None] / n)


def plain_fabrik(model, heads, tails, targets, tolerance=1e-5, max_iterations=200):
    """Joint positions {chain: (F,n,3)} after plain FABRIK; arms hang from the SC through the rigid SC -> arm
    base link (a segment like any other here); legs are independent chains from fixed hips."""
    chains = {n: model.limbs[n].joints(heads, tails).copy() for n in BODY_CHAINS}
    links = {a: chains[a][:, 0] - chains["trunk"][:, -1] for a in ("arm.L", "arm.R")}
    link_len = {a: np.linalg.norm(v, axis=-1) for a, v in links.items()}
    lengths = {n: np.linalg.norm(np.diff(c, axis=1), axis=-1) for n, c in chains.items()}
    tgt = {limb: targets[:, k] for k, limb in enumerate(LIMBS)}
    base_trunk = chains["trunk"][:, 0].copy()
    hips = {leg: chains[leg][:, 0].copy() for leg in ("leg.L", "leg.R")}
    f = heads.shape[0]
    iterations = np.zeros(f, dtype=int)
    active = np.ones(f, dtype=bool)

    def residual():
        return np.max(np.stack([np.linalg.norm(chains[l][:, -1] - tgt[l], axis=-1) for l in LIMBS]), axis=0)

    active &= residual() > tolerance
    while np.any(active):
        rows = np.nonzero(active)[0]
        c = {n: chains[n][rows].copy() for n in chains}
        prev = {n: v.copy() for n, v in c.items()}
        # Forward: effectors to targets, back toward the bases; the SC = centroid of the arms' proposals.
        proposals = []
        for a in ("arm.L", "arm.R"):
            p = c[a]
            p[:, -1] = tgt[a][rows]
            for i in range(p.shape[1] - 2, -1, -1):
                p[:, i] = _place(p[:, i + 1], p[:, i], lengths[a][rows, i], prev[a][:, i] - prev[a][:, i + 1])
            proposals.append(_place(p[:, 0], c["trunk"][:, -1], link_len[a][rows], -links[a][rows]))
        tr = c["trunk"]
        tr[:, -1] = np.mean(proposals, axis=0)
        for i in range(tr.shape[1] - 2, -1, -1):
            tr[:, i] = _place(tr[:, i + 1], tr[:, i], lengths["trunk"][rows, i], prev["trunk"][:, i] - prev["trunk"][:, i + 1])
        # Backward: root pinned, out to the SC, then each arm from the SC.
        tr[:, 0] = base_trunk[rows]
        for i in range(tr.shape[1] - 1):
            tr[:, i + 1] = _place(tr[:, i], tr[:, i + 1], lengths["trunk"][rows, i], prev["trunk"][:, i + 1] - prev["trunk"][:, i])
        for a in ("arm.L", "arm.R"):
            p = c[a]
            p[:, 0] = _place(tr[:, -1], p[:, 0], link_len[a][rows], links[a][rows])
            for i in range(p.shape[1] - 1):
                p[:, i + 1] = _place(p[:, i], p[:, i + 1], lengths[a][rows, i], prev[a][:, i + 1] - prev[a][:, i])
        # Legs: single chains from the fixed hips.
        for leg in ("leg.L", "leg.R"):
            p = c[leg]
            p[:, -1] = tgt[leg][rows]
            for i in range(p.shape[1] - 2, -1, -1):
                p[:, i] = _place(p[:, i + 1], p[:, i], lengths[leg][rows, i], prev[leg][:, i] - prev[leg][:, i + 1])
            p[:, 0] = hips[leg][rows]
            for i in range(p.shape[1] - 1):
                p[:, i + 1] = _place(p[:, i], p[:, i + 1], lengths[leg][rows, i], prev[leg][:, i + 1] - prev[leg][:, i])
        for n in chains:
            chains[n][rows] = c[n]
        iterations[rows] += 1
        res = residual()[rows]
        moved = np.max(np.stack([np.linalg.norm(c[l][:, -1] - prev[l][:, -1], axis=-1) for l in LIMBS]), axis=0)
        done = (res <= tolerance) | (moved < tolerance * 1e-3) | (iterations[rows] >= max_iterations)
        active[rows[done]] = False
    return chains, iterations


# ----------------------------------------------------------------------------------------------------------
# Measures


def body_chains(model, heads, tails):
    return {n: model.limbs[n].joints(heads, tails) for n in BODY_CHAINS}


def joint_angles(model, chains, heads, tails):
    """(F, A) angles between adjacent segments: interior joints of every chain, and each chain's first
    segment against its parent segment (trunk and legs: the root bone; arms: the trunk's last segment)."""
    root_dir = tails[:, model.root] - heads[:, model.root]
    pairs = []
    for n in BODY_CHAINS:
        segs = np.diff(chains[n], axis=1)
        parent = np.diff(chains["trunk"], axis=1)[:, -1] if n.startswith("arm") else root_dir
        pairs.append((parent, segs[:, 0]))
        pairs += [(segs[:, i - 1], segs[:, i]) for i in range(1, segs.shape[1])]
    a = np.stack([p for p, _ in pairs], axis=1)
    b = np.stack([q for _, q in pairs], axis=1)
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cos, -1.0, 1.0))


def naturalness(model, chains, heads, tails, cap_chains, cap_h, cap_t):
    ang = np.abs(joint_angles(model, chains, heads, tails) - joint_angles(model, cap_chains, cap_h, cap_t))
    pos = np.concatenate([np.linalg.norm(chains[n] - cap_chains[n], axis=-1) for n in BODY_CHAINS], axis=1)
    return float(ang.mean()), float(pos.mean())


def hinge_consistency(model, heads, tails, result):
    """Over the arms and legs of every pose: the largest distance of the lower bone's direction from the plane
    perpendicular to the start hinge axis turned by the upper bone's returned rotation (0 = a pure hinge), and
    the largest twist of the upper bone about its own direction beyond its minimal swing (radians)."""
    limits = default_limits(model, heads, tails)
    off, twist = 0.0, 0.0
    for name in LIMBS:
        limb = model.limbs[name]
        i = len(limb.bones) - 1
        upper = limb.bones[i - 1]
        old = model.limbs[name].joints(heads, tails)
        new = model.limbs[name].joints(result.heads, result.tails)
        d0, p = old[:, i] - old[:, i - 1], new[:, i] - new[:, i - 1]
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        v = new[:, i + 1] - new[:, i]
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        axis = limits[name].limits.hinge_axis[:, i]
        axis = axis - np.sum(axis * d0, axis=1, keepdims=True) * d0 / np.sum(d0 * d0, axis=1, keepdims=True)
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        turned = np.einsum("fab,fb->fa", result.rotations[:, upper], axis)
        off = max(off, float(np.max(np.abs(np.sum(turned * v, axis=1)))))
        swung = np.einsum("fab,fb->fa", swing_rotation(d0, p), axis)
        tau = np.arctan2(np.sum(np.cross(swung, turned) * p, axis=1), np.sum(swung * turned, axis=1))
        twist = max(twist, float(np.max(np.abs(tau))))
    return off, twist


def reach_summary(residuals, tol):
    r = residuals[np.isfinite(residuals)]
    return {"median": float(np.median(r)), "p99": float(np.percentile(r, 99)), "max": float(r.max()),
            "share_met": float(np.mean(r <= tol))}


def timed(fn, repeat=1):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--poses-per-clip", type=int, default=50, help="captured poses per clip (5 clips)")
    ap.add_argument("--single-poses", type=int, default=60, help="poses timed one at a time")
    ap.add_argument("--batch-frames", type=int, default=1000, help="frames in the vectorised timing")
    args = ap.parse_args()

    model, cap_h, cap_t, st_h, st_t, labels = sample_poses(args.poses_per_clip)
    n = cap_h.shape[0]
    ends = [model.limbs[l].end_bone for l in LIMBS]
    targets = cap_h[:, ends]
    settings = AdjustSettings()
    tol = settings.chain.tolerance
    cap_chains = body_chains(model, cap_h, cap_t)

    ours = adjust_frames(model, st_h, st_t, targets, EFFECTORS, settings=settings)
    ours_chains = body_chains(model, ours.heads, ours.tails)
    plain_chains, plain_iter = plain_fabrik(model, st_h, st_t, targets, tol, settings.chain.max_iterations)
    plain_res = np.stack([np.linalg.norm(plain_chains[l][:, -1] - targets[:, k], axis=-1)
                          for k, l in enumerate(LIMBS)], axis=1)
    # Plain FABRIK moves joints only; the root bone stays, so its angles use the start's root direction.
    ang_o, pos_o = naturalness(model, ours_chains, ours.heads, ours.tails, cap_chains, cap_h, cap_t)
    ang_p, pos_p = naturalness(model, plain_chains, st_h, st_t, cap_chains, cap_h, cap_t)
    ang_s, pos_s = naturalness(model, body_chains(model, st_h, st_t), st_h, st_t, cap_chains, cap_h, cap_t)

    # Fewest moved joints: poses whose every target is within its limb's reach from the start pose.
    within = np.ones(n, dtype=bool)
    for k, l in enumerate(LIMBS):
        j = model.limbs[l].joints(st_h, st_t)
        reach = np.linalg.norm(np.diff(j, axis=1), axis=-1).sum(axis=1)
        within &= np.linalg.norm(targets[:, k] - j[:, 0], axis=-1) <= reach

    # Rule (i) read by length alone: where every limb then reaches its target alone, the SC and root must stay
    # exactly; where a limb within its length is held short by its limits, ours moves the trunk to help.
    strict = adjust_frames(model, st_h, st_t, targets, EFFECTORS,
                           settings=replace(settings, help_held_limbs=False))
    alone = within & np.all(strict.status == "reached", axis=1)
    helped = within & ~alone

    off_plane, max_twist = hinge_consistency(model, st_h, st_t, ours)

    # Speed: one pose at a time, then 1,000 frames in one call, each against plain FABRIK in this run.
    k = min(args.single_poses, n)
    t_ours_1 = timed(lambda: [adjust_pose(model, st_h[i], st_t[i], targets[i], EFFECTORS) for i in range(k)]) / k
    t_plain_1 = timed(lambda: [plain_fabrik(model, st_h[i:i + 1], st_t[i:i + 1], targets[i:i + 1]) for i in range(k)],
                      repeat=2) / k
    idx = np.arange(args.batch_frames) % n
    bh, bt, btg = st_h[idx], st_t[idx], targets[idx]
    t_ours_b = timed(lambda: adjust_frames(model, bh, bt, btg, EFFECTORS)) / args.batch_frames
    t_plain_b = timed(lambda: plain_fabrik(model, bh, bt, btg), repeat=2) / args.batch_frames

    out = {
        "protocol": "paper Table 1 (DESIGN.md §4): targets = captured wrists+ankles; start = pose %d frames earlier,"
                    " root moved onto the captured root; errors vs the captured pose" % LAG,
        "clips": list(CMU_CLIPS),
        "poses": int(n),
        "baseline": "plain multi-effector FABRIK (bench/fullbody.py; unweighted centroid at the SC, all joints free,"
                    " pelvis and hips fixed)",
        "mean_joint_angle_error_rad": {"ours": ang_o, "plain_fabrik": ang_p, "start_pose": ang_s},
        "mean_joint_position_error": {"ours": pos_o, "plain_fabrik": pos_p, "start_pose": pos_s},
        "reach_error": {"ours": reach_summary(ours.residuals, tol), "plain_fabrik": reach_summary(plain_res, tol)},
        "status_counts_ours": {s: int(c) for s, c in zip(*np.unique(ours.status, return_counts=True))},
        "fewest_moved_joints": {
            "poses_with_every_target_within_reach": int(within.sum()),
            "of_those_reached_by_the_limbs_alone": int(alone.sum()),
            "max_sc_displacement": float(ours.sc_displacement[alone].max()) if alone.any() else None,
            "max_root_displacement": float(ours.root_displacement[alone].max()) if alone.any() else None,
            "max_sc_and_root_displacement_with_rule_i_by_length_alone": float(
                np.max(strict.sc_displacement[within] + strict.root_displacement[within])) if within.any() else None,
            "of_those_with_a_limb_held_by_its_limits": {
                "poses": int(helped.sum()),
                "tasks_met_with_rule_i_by_length_alone": int(np.sum(strict.status[helped] == "reached")),
                "tasks_met_with_trunk_help": int(np.sum(ours.status[helped] == "reached")),
                "tasks": int(helped.sum() * len(EFFECTORS))},
            "share_of_other_poses_moving_sc": float(np.mean(ours.sc_displacement[~within] > 0))
            if (~within).any() else None,
        },
        "hinge_output": {"max_lower_bone_off_upper_bone_hinge_plane": off_plane,
                         "max_upper_bone_twist_rad": max_twist},
        "iterations_mean": {"ours": float(ours.iterations.mean()), "plain_fabrik": float(plain_iter.mean())},
        "speed": {
            "us_per_pose_single": {"ours": t_ours_1 * 1e6, "plain_fabrik": t_plain_1 * 1e6,
                                   "ratio_ours_over_plain": t_ours_1 / t_plain_1},
            "us_per_pose_vectorised_%d" % args.batch_frames: {
                "ours": t_ours_b * 1e6, "plain_fabrik": t_plain_b * 1e6, "ratio_ours_over_plain": t_ours_b / t_plain_b},
            "single_over_vectorised_ours": t_ours_1 / t_ours_b,
        },
        "numpy": np.__version__,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
