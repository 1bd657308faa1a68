"""Rotation transfer: bone pairing between two rigs and the source's motion carried onto the target's
rest (see solver/retarget/motion.py, step 1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..maths.geometry import norm, swing_rotation
from .fingers import finger_pairs
from .rig import body_frame, chain_joints, hip_centres, rest_points, unit_columns
from ..maths.rotation_channels import quaternions_of, quaternions_to_matrices


@dataclass(frozen=True)
class BonePair:
    """Target bone ``target`` takes the blended rotation change of ``sources`` (indices, weights summing to
    1) applied to its rest turned by ``alignment`` (3,3, world: target rest onto source rest) — or, with no
    sources, rides rigidly on ``rides_on`` (its nearest paired ancestor)."""

    target: int
    sources: tuple
    weights: tuple
    alignment: np.ndarray
    rides_on: int = -1


def pair_bones(source, target):
    """BonePairs for every mapped bone of ``target`` and every finger bone both rigs have (fingers),
    parents first.

    Alignment: limb segments (upper arm, forearm, thigh, shin, and the hand and foot like the segment they
    end) by the rest body frames (facing), then the minimal swing from the target's rest segment direction
    onto the source's, so a T-pose source drives an A-pose target; the rest (pelvis, spine, clavicles, neck,
    head) by the rest body frames only, so the target keeps its own spine curve and shoulder line where rigs
    differ by anatomy (e.g. the CMU clavicle spans from the mid back up to the shoulder, Rigify's lies along
    the shoulder line)."""
    s_heads, s_tails = rest_points(source)
    t_heads, t_tails = rest_points(target)
    s_dirs = _segment_directions(source, s_heads, s_tails)
    t_dirs = _segment_directions(target, t_heads, t_tails)
    body = body_frame(source, s_heads, s_tails) @ body_frame(target, t_heads, t_tails).T
    pairs = {}

    def pair(t, sources, weights=(1.0,), alignment=body):
        pairs[t] = BonePair(t, tuple(sources), tuple(weights), alignment)

    pair(target.groups["root"][0], source.groups["root"])
    for group in ("arm.L", "arm.R", "leg.L", "leg.R"):
        t_bones, s_bones = target.groups[group], source.groups[group]
        limb = 2 if group.startswith("arm") else len(t_bones)  # upper arm and forearm; every leg bone
        for k in range(1, min(len(t_bones), len(s_bones)) + 1):
            t, s = t_bones[-k], s_bones[-k]
            # Facing first, then the minimal swing of the segment (a swing alone would lose a turn about it).
            pair(t, (s,), alignment=swing_rotation(body @ t_dirs[t], s_dirs[s]) @ body if k <= limb else body)
    for group in ("trunk", "head"):
        t_bones = list(target.groups.get(group, ()))
        s_bones = list(source.groups.get(group, ()))
        if group == "head" and t_bones and s_bones:
            pair(t_bones[-1], (s_bones[-1],))  # head bone <-> head bone; the necks in between
            t_bones, s_bones = t_bones[:-1], s_bones[:-1]
        n, m = len(t_bones), len(s_bones)
        for k, t in enumerate(t_bones if m else ()):
            # Bone centre k+1/2 of n <-> the same fraction of the source chain (equal counts: bone k <-> k).
            x = min(max((k + 0.5) * m / n - 0.5, 0.0), m - 1.0)
            lo = int(np.floor(x))
            hi = min(lo + 1, m - 1)
            pair(t, (s_bones[lo], s_bones[hi]) if hi != lo and x > lo else (s_bones[lo],),
                 (1.0 - (x - lo), x - lo) if hi != lo and x > lo else (1.0,))
    for side in ("L", "R"):
        for end, chain in ((f"hand.{side}", f"arm.{side}"), (f"foot.{side}", f"leg.{side}")):
            if end not in target.groups or end not in source.groups:
                continue  # no hand bone on one side: the other's hand rides on its forearm
            last = pairs.get(target.groups[chain][-1])
            pair(target.groups[end][0], source.groups[end], alignment=last.alignment if last else body)
    # Fingers both rigs have (fingers), aligned as their hand is.
    hands = {side: pairs[target.groups[f"hand.{side}"][0]].alignment for side in ("L", "R")
             if f"hand.{side}" in target.groups and f"hand.{side}" in source.groups}
    for t, s, alignment in finger_pairs(source, target, s_dirs, t_dirs, hands):
        if t not in pairs:
            pair(t, (s,), alignment=alignment)

    # Mapped bones left without a source ride on their nearest paired ancestor.
    for t in sorted({b for bones in target.groups.values() for b in bones}):
        if t in pairs:
            continue
        p = target.parents[t]
        while p >= 0 and p not in pairs:
            p = target.parents[p]
        if p >= 0:
            pairs[t] = BonePair(t, (), (), body, rides_on=p)
    return [pairs[t] for t in sorted(pairs)]


def _segment_directions(rig, heads, tails):
    """World rest direction (J,3) of each bone's chain segment (head -> next chain joint), else head -> tail."""
    dirs = tails - heads
    for group in ("trunk", "arm.L", "arm.R", "leg.L", "leg.R", "head"):
        if group not in rig.groups:
            continue
        joints = chain_joints(rig, group, heads, tails)
        bones = rig.groups[group][:-1] if group == "head" else rig.groups[group]
        for k, b in enumerate(bones):
            seg = joints[k + 1] - joints[k]
            if norm(seg) > 1e-9 * max(norm(dirs[b]), 1e-300):
                dirs[b] = seg
    return dirs


def _blend_rotations(rotations, weights):
    """Normalised weighted sum of quaternions (nlerp) of (F,k,3,3) rotations -> (F,3,3)."""
    if len(weights) == 1:
        return rotations[:, 0]
    q = quaternions_of(rotations)
    q = np.where((np.sum(q * q[:, :1], axis=-1) < 0.0)[..., None], -q, q)
    blended = np.einsum("fkq,k->fq", q, np.asarray(weights))
    return quaternions_to_matrices(blended)


def carried_bones(source, target):
    """Target bones outside the bone map that take the source's motion (fingers both rigs have), sorted."""
    mapped = {b for bones in target.groups.values() for b in bones}
    return tuple(sorted(p.target for p in pair_bones(source, target) if p.target not in mapped))


def _pelvis_turn(source, source_pose):
    """(F,3,3) the pelvis's turn since rest in the source's armature space, from its hip joints: the change of
    the frame of the hips' line and the pelvis bone's axis most across it (of a rigid pelvis, its own rotation
    change). Some game rigs swing the hips by moving the thighs' heads (KayKit's run: location keys on
    upperleg.l/r turn the hips' line 30 degrees each way while the pelvis bone only pitches): the pelvis turns as
    its joints do. None where the hip joints coincide."""
    left, right = source.groups["leg.L"][0], source.groups["leg.R"][0]
    pelvis = source.groups["root"][0]
    rest = unit_columns(source.rest[pelvis, :3, :3])
    line = source.rest[left, :3, 3] - source.rest[right, :3, 3]
    size = float(norm(line))
    if not size > 1e-9 * max(float(norm(source.rest[left, :3, 3])), 1e-300):
        return None
    k = int(np.argmin(np.abs(rest.T @ (line / size))))  # the bone axis most across the hips' line

    def frames(lines, axes):
        lateral = lines / norm(lines)[..., None]
        up = axes - np.sum(axes * lateral, axis=-1, keepdims=True) * lateral
        up = up / norm(up)[..., None]
        return np.stack([lateral, up, np.cross(lateral, up)], axis=-1)

    pose = np.asarray(source_pose, dtype=np.float64)
    lines = pose[:, left, :3, 3] - pose[:, right, :3, 3]
    if not np.all(norm(lines) > 1e-9 * size):
        return None
    now = frames(lines, unit_columns(pose[:, pelvis, :3, :3])[..., k])
    before = frames(line, rest[:, k])
    return now @ before.T


def transfer_pose(source, source_pose, target, target_basis, hips):
    """Target pose (F,Jt,4,4, armature space) carrying the source's motion (source_pose (F,Js,4,4), source
    armature space): mapped bones take the aligned world rotation change of their source bones, unmapped
    bones keep ``target_basis`` (Jt,4,4), and the root translates so the hip centre is at ``hips`` (F,3,
    world). (The hips, not the root bone's head: where a rig puts its root bone relative to the legs varies,
    e.g. at the hip joints or a hand's width above them.)"""
    source_pose = np.asarray(source_pose, dtype=np.float64)
    frames = source_pose.shape[0]
    pairs = pair_bones(source, target)
    used = sorted({s for pair in pairs for s in pair.sources})
    s_rest = source.rotation @ unit_columns(source.rest[used, :3, :3])
    # The world rotation change since rest of each used source bone, seen in the target's armature space.
    # (Contiguous operands: numpy multiplies strided stacks of small matrices several times slower.)
    changes = target.rotation.T @ source.rotation @ unit_columns(
        np.ascontiguousarray(source_pose[:, used][..., :3, :3])) @ np.ascontiguousarray(np.swapaxes(s_rest, -1, -2))
    change_of = {s: k for k, s in enumerate(used)}
    pelvis = source.groups["root"][0]
    if pelvis in change_of:
        turn = _pelvis_turn(source, source_pose)
        if turn is not None:
            changes[:, change_of[pelvis]] = target.rotation.T @ source.rotation @ turn @ source.rotation.T
    t_rest = target.rotation @ unit_columns(target.rest[:, :3, :3])
    armature_rot = {}  # target bone -> (F,3,3) rotation in the target's armature space
    for pair in pairs:
        t = pair.target
        if pair.sources:
            change = _blend_rotations(changes[:, [change_of[s] for s in pair.sources]], pair.weights)
            armature_rot[t] = change @ (pair.alignment @ t_rest[t])
        else:  # rigid on the paired ancestor: keep the rest relation to it
            armature_rot[t] = armature_rot[pair.rides_on] @ (t_rest[pair.rides_on].T @ t_rest[t])

    # Unmapped bones keep their (static) basis; a mapped bone keeps its own scale, not its rotation.
    basis = np.array(target_basis, dtype=np.float64)
    basis[target.connected, :3, 3] = 0.0
    local = target.relative @ basis  # (Jt,4,4)
    own_scale = np.sqrt(np.sum(basis[:, :3, :3] ** 2, axis=-2))  # (Jt,3)
    local_rot, local_head = np.ascontiguousarray(local[:, :3, :3]), np.ascontiguousarray(local[:, :3, 3])
    # Bone-major: each bone's frames contiguous (faster than strided slices), copied into place once.
    rotations = np.empty((len(target), frames, 3, 3))
    heads = np.empty((len(target), frames, 3))
    for j, p in enumerate(target.parents):
        if j in armature_rot:
            np.multiply(armature_rot[j], own_scale[j], out=rotations[j])
        elif p < 0:
            rotations[j] = local_rot[j]
        else:
            np.matmul(rotations[p], local_rot[j], out=rotations[j])
        if p < 0:
            heads[j] = local_head[j]
        else:
            np.add(rotations[p] @ local_head[j], heads[p], out=heads[j])
    pose = np.empty((frames, len(target), 4, 4))
    pose[..., :3, :3] = rotations.transpose(1, 0, 2, 3)
    pose[..., :3, 3] = heads.transpose(1, 0, 2)
    pose[..., 3, :3] = 0.0
    pose[..., 3, 3] = 1.0
    # Put the hip centre where it belongs.
    hips_now = target.to_world(hip_centres(target, pose[..., :3, 3]))
    translate_body(target, pose, np.asarray(hips, dtype=np.float64) - hips_now)
    return pose


def translate_body(rig, pose, world_shift):
    """Move the root and every bone below it by ``world_shift`` (F,3) in place (pose: armature space)."""
    root = rig.groups["root"][0]
    shift = world_shift @ rig.matrix_world[:3, :3] / rig.scale ** 2  # world -> armature vectors (M⁻¹ = Mᵀ/s²)
    below = np.zeros(len(rig), dtype=bool)
    for j, p in enumerate(rig.parents):
        below[j] = j == root or (p >= 0 and below[p])
    heads = pose[..., :3, 3]  # a view: moved in place
    heads[:, below] += shift[:, None, :]
