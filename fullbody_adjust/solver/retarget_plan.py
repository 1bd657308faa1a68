"""Planning a retarget: the start pose and the effector targets of every frame (see solver/retarget.py,
step 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .adjust import sub_base_point
from .contacts import RetargetSettings, detect_object_contacts, detect_plants, hold
from .errors import SolverInputError
from .geometry import norm
from .retarget_rig import (EFFECTORS, FEET, EFFECTOR_CHAIN, Rig, ankle_above_sole, chain_joints, hip_centres,
                           leg_length, rest_points, sole_heights)
from .retarget_transfer import transfer_pose, translate_body


def moving_average(values, half_width):
    """Mean over ±half_width frames (the ends repeated) of values (F,…)."""
    values = np.asarray(values, dtype=np.float64)
    if half_width <= 0 or len(values) < 2:
        return values.copy()
    w = int(half_width)
    padded = np.concatenate([np.repeat(values[:1], w, axis=0), values, np.repeat(values[-1:], w, axis=0)])
    total = np.cumsum(np.concatenate([np.zeros((1,) + values.shape[1:]), padded]), axis=0)
    return (total[2 * w + 1:] - total[:-2 * w - 1]) / (2 * w + 1)


def body_shift(bases, targets, reach, priorities, margin, settle_margin, half_width):
    """World shifts (F,3) of the whole body that bring each target (F,E,3) within its limb's ``reach`` (E,)
    less ``margin`` from the limb's base (F,E,3): the smallest shift on each frame (nearest point of the
    intersection of the reach balls, the paper's two-sphere construction; where they do not meet, the
    higher ``priorities`` first), smoothed over ±half_width frames, then the smallest further shift that
    puts every target within its reach less ``settle_margin`` again. Zero where every target is in reach.
    Continuous from frame to frame, as the nearest point of a convex set is."""
    centres = targets - bases  # a shift d serves target k when |centres_k - d| <= radius_k
    frames = len(targets)
    active = np.ones(centres.shape[:2], dtype=bool)
    zero = np.zeros((frames, 3))

    def nearest(start, fraction):
        radii = np.broadcast_to((1.0 - fraction) * np.asarray(reach, dtype=np.float64), active.shape)
        point, _ = sub_base_point(start, centres, radii, active, priorities, "priority")
        return point

    first = nearest(zero, margin)
    return nearest(moving_average(first, half_width), settle_margin)


@dataclass
class RetargetPlan:
    """What the solve needs and what the caller reports, for F frames.

    start_pose (F,Jt,4,4): the transferred pose (target armature space); heads/tails (F,Jt,3) of it in
    armature space; targets (F,4,3) for EFFECTORS in armature space, world_targets the same in world space;
    contacts (F,4) bool: frames held at a contact (planted foot, object contact); leg_ratio target/source;
    ground: world z of the ground (the source's lowest foot joints)."""

    start_pose: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    targets: np.ndarray
    world_targets: np.ndarray
    contacts: np.ndarray
    contact_intervals: dict
    leg_ratio: float
    ground: float
    effectors: tuple = EFFECTORS


def plan_retarget(source, source_pose, target, target_basis, settings=RetargetSettings(), boxes=None):
    """The start pose and effector targets that carry ``source_pose`` (F,Js,4,4, source armature space)
    over to ``target`` (its unmapped bones at ``target_basis`` (Jt,4,4)). ``boxes``: (mins, maxs) (K,3)
    each, world boxes of a contact object (None: the ground is the contact). See the module docstring."""
    if not isinstance(source, Rig) or not isinstance(target, Rig):
        raise SolverInputError("source and target must be Rigs")
    source_pose = np.asarray(source_pose, dtype=np.float64)
    if source_pose.ndim != 4 or source_pose.shape[1:] != (len(source), 4, 4) or len(source_pose) == 0:
        raise SolverInputError(f"source pose must have shape (F,{len(source)},4,4), got {source_pose.shape}")
    if not np.all(np.isfinite(source_pose)):
        raise SolverInputError("source pose has NaN/inf")
    target_basis = np.asarray(target_basis, dtype=np.float64)
    if target_basis.shape != (len(target), 4, 4):
        raise SolverInputError(f"target basis must have shape ({len(target)},4,4), got {target_basis.shape}")
    leg_s, leg_t = leg_length(source), leg_length(target)
    if not (leg_s > 0.0 and leg_t > 0.0):
        raise SolverInputError("a rig's legs have zero length")
    ratio = leg_t / leg_s

    s_heads, s_tails = source.world_points(source_pose)
    ground = float(np.percentile(sole_heights(source, s_heads, s_tails), 2))
    # Scale about the ground below each rig's rest hips: the source's motion, re-anchored on the target.
    anchor_s = hip_centres(source, rest_points(source)[0])
    anchor_t = hip_centres(target, rest_points(target)[0])
    anchor_s[2] = anchor_t[2] = ground

    def scaled(points):
        return anchor_t + ratio * (points - anchor_s)

    start = transfer_pose(source, source_pose, target, target_basis, scaled(hip_centres(source, s_heads)))

    free = {e: scaled(s_heads[:, source.groups[e][0]]) for e in EFFECTORS}
    exact_source = {e: s_heads[:, source.groups[e][0]] for e in EFFECTORS}
    blend = settings.frames(settings.blend_duration) if settings.blend_duration else 0
    t_heads, t_tails = target.world_points(start)
    soles = ankle_above_sole(target, t_heads, t_tails)  # the transferred feet's own ankle heights
    frames = len(source_pose)
    contacts = np.zeros((frames, len(EFFECTORS)), dtype=bool)
    found = {}
    world_targets = np.empty((frames, len(EFFECTORS), 3))
    for k, e in enumerate(EFFECTORS):
        if boxes is None:
            runs = detect_plants(exact_source[e], 2, settings.fps, leg_s, settings) if e in FEET else []
        else:
            runs = detect_object_contacts(exact_source[e], boxes[0], boxes[1], settings.fps, leg_s, settings)
        holds = []
        for a, b in runs:
            if boxes is None:
                point = free[e][a:b].mean(axis=0)
                if settings.exact:  # the target's sole on the ground
                    point[2] = ground + soles[a:b, FEET.index(e)].mean()
            else:
                point = (exact_source[e] if settings.exact else free[e])[a:b].mean(axis=0)
            holds.append((a, b, point))
            contacts[a:b, k] = True
        found[e] = runs
        world_targets[:, k] = hold(free[e], holds, blend)
    # Every target within its limb's reach (see reach_margin): shift the whole body, smoothly, where needed.
    bases, reach = [], []
    rest_heads, rest_tails = rest_points(target)
    for e in EFFECTORS:
        chain = EFFECTOR_CHAIN[e]
        bases.append(target.to_world(start[:, target.groups[chain][-2], :3, 3]))  # shoulder, hip joint
        last_two = chain_joints(target, chain, rest_heads, rest_tails)[-3:]  # upper arm + forearm, thigh + shin
        reach.append(float(norm(np.diff(last_two, axis=0)).sum()))
    feet_first = [2.0 if e.startswith("hand") else 3.0 for e in EFFECTORS]
    shift = body_shift(np.stack(bases, axis=1), world_targets, reach, feet_first, settings.reach_margin,
                       settings.settle_margin, blend)
    translate_body(target, start, shift)
    heads = start[..., :3, 3]
    tails = heads + start[..., :3, 1] * target.lengths[:, None]
    return RetargetPlan(start_pose=start, heads=heads, tails=tails, targets=target.to_armature(world_targets),
                        world_targets=world_targets, contacts=contacts, contact_intervals=found, leg_ratio=ratio,
                        ground=ground)
