"""Bone rotations of solved limbs: each segment's world rotation delta from its start direction to
its solved one, a hinge's twist carried on its parent bone, and the chest's rotation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec
from ..maths.geometry import all_set, any_perpendicular, any_set, apply_matrix, norm, stack_rows, swing_rotation
from ..limits.joint_limits import HINGE, hinge_twist

_EYE = np.eye(3)

# How far a hand or foot may turn away from where its forearm or shin carries it (its start pose relative to
# that bone) when it takes a wanted orientation: a wrist bends about 80 degrees, an ankle about 50, so the
# larger of the two bounds both without leaving the range of a hand in most poses.
END_SWING = np.radians(80.0)


@dataclass
class LimbSolve:
    """A limb's solved chain on every frame (rigidly carried where not solved)."""

    joints: np.ndarray  # (F,n,3)
    solved: np.ndarray  # (F,) bool
    status: np.ndarray  # (F,) str ('' where not solved)
    reason: np.ndarray  # (F,) str
    rotations: np.ndarray = field(default=None)  # (F,n-1,3,3) each segment's world rotation delta

    def placed_frames(self):
        """The solved frames as an index of the frame axis: every frame (a slice), some (their indices) or None."""
        if all_set(self.solved):
            return slice(None)
        return np.nonzero(self.solved)[0] if any_set(self.solved) else None

    def segment_rotations(self, start, limits):
        """World rotation deltas of the chain's segments from the start chain `start` (F,n,3) to the solved one,
        on solved frames (`limits` the limb's LimbLimits or None); computed once per limb, unless
        set_segment_rotations already did it for its stacked group."""
        if self.rotations is None:
            set_segment_rotations([self], [start], [limits])
        return self.rotations


def set_segment_rotations(solves, starts, limits):
    """Fill the `rotations` of LimbSolves `solves` (identity where not solved), their start chains `starts`
    (F,n,3) and LimbLimits (or None) `limits` each, with one _segment_rotations call on all their solved frames
    stacked in order. The limbs share a chain length and per-joint limit kinds (a stacked chain solve's group):
    every row is computed on its own, so a stacked row equals the limb's alone, and numpy's per-call cost is
    paid once for all of them."""
    frames = [np.nonzero(ls.solved)[0] for ls in solves]
    for ls in solves:
        ls.rotations = np.empty((ls.joints.shape[0], ls.joints.shape[1] - 1, 3, 3))
        ls.rotations[...] = _EYE
    if not any(f.size for f in frames):
        return
    rot = _stacked_rotations([s[f] for s, f in zip(starts, frames)], [ls.joints[f] for ls, f in zip(solves, frames)],
                             limits, frames)
    at = 0
    for ls, f in zip(solves, frames):
        ls.rotations[f] = rot[at:at + f.size]
        at += f.size


def chain_rotations(start, joints, limits, frames):
    """World rotation deltas (b,n-1,3,3) of chains `joints` (b,n,3) on frames `frames` (b,) from their start
    chains `start` (b,n,3), as set_segment_rotations writes them (`limits` the limb's LimbLimits or None)."""
    return _stacked_rotations([start], [joints], [limits], [frames])


def _stacked_rotations(starts, joints, limits, frames):
    """_segment_rotations of limbs' chains `starts` -> `joints` (b_i,n,3) each, on their frames `frames` (b_i,) with
    their LimbLimits (or None) `limits` (the same per-joint kinds), stacked in order."""
    kind = axes = None
    if limits[0] is not None:
        kind = limits[0].limits.kind
        if any_set(kind[1:] == HINGE):
            axes = stack_rows([_frame_axes(ll.limits.hinge_axis, f) for ll, f in zip(limits, frames)])
    return _segment_rotations(stack_rows(starts), stack_rows(joints), kind, axes)


def _frame_axes(axes, frames):
    """Hinge axes (b,m,3) on `frames` (b,) from per-frame (F,m,3) or shared (m,3) ones."""
    return axes[frames] if axes.ndim == 3 else np.broadcast_to(axes, (len(frames),) + axes.shape)


def _segment_rotations(start, joints, kind, axes):
    """World rotation deltas (b,n-1,3,3) of chain segments from `start` (b,n,3) to `joints` (b,n,3):
    each segment turns by the minimal swing from its old direction to its new one (its twist kept),
    except around a hinge (`kind` the per-joint limit kinds or None, `axes` (b,n-1,3) the start-pose hinge
    axes) with joint i > 0:
      - the parent segment i-1 also turns about its new direction by the hinge's twist (the angle by which the
        bend plane left the start axis carried by the parent's swing, as the solver carries it), so the
        start hinge axis turned with the bone is the axis the child bends about;
      - the child segment i turns by the minimal swing in its parent's frame: relative to the parent it
        rotates about the hinge axis only, a pure hinge (an elbow or knee does not twist)."""
    kinds = None if kind is None else kind.tolist()
    rows = lanes.run(_rotations, (start, joints, axes), kinds)
    return rows.reshape(start.shape[0], start.shape[1] - 1, 3, 3)


def _rotations(start, joints, axes, kind):
    """_segment_rotations written once (maths/lanes.py): each segment's rotation, in turn."""
    old = [vec.sub(start[i + 1], start[i]) for i in range(len(start) - 1)]
    new = [vec.sub(joints[i + 1], joints[i]) for i in range(len(joints) - 1)]
    rot = [vec.swing_rotation(o, n) for o, n in zip(old, new)]
    for i in range(1, 0 if kind is None else len(kind)):
        if kind[i] != HINGE:
            continue
        parent, child = vec.divided(new[i - 1], vec.norm(new[i - 1])), vec.divided(new[i], vec.norm(new[i]))
        tau = hinge_twist(parent, child, vec.apply_matrix(rot[i - 1], axes[i]))
        rot[i - 1] = vec.matmul(vec.rotation_about(parent, tau), rot[i - 1])
        if i + 1 >= len(kind) or kind[i + 1] != HINGE:  # a hinge parent itself keeps the solver's frame
            rot[i] = vec.matmul(vec.swing_rotation(vec.apply_matrix(rot[i - 1], old[i]), new[i]), rot[i - 1])
    return rot


def end_rotation(wanted, carried, direction, max_swing=END_SWING):
    """World rotation deltas (b,3,3) of hand or foot bones: `wanted` (b,3,3), unless that points the bone
    (start direction `direction` (b,3)) more than `max_swing` away from where its parent's delta `carried`
    (b,3,3) takes it; then the wanted one swung back to that cone's edge (its twist about the bone kept)."""
    want = apply_matrix(wanted, direction)
    ride = apply_matrix(carried, direction)
    cos = np.einsum("bi,bi->b", want, ride) / (norm(want) * norm(ride))
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    over = angle > max_swing
    if not any_set(over):
        return wanted
    out = wanted.copy()
    # Slerp from the carried direction toward the wanted one by the allowed fraction; a wanted direction right
    # opposite the carried one gives no way to go, so one is picked (any, fixed: the result stays finite).
    a, toward = ride[over] / norm(ride[over])[:, None], want[over] / norm(want[over])[:, None]
    opposite = angle[over] > np.pi - 1e-6
    b = np.where(opposite[:, None], -a + 1e-3 * any_perpendicular(a), toward)
    b = b / norm(b)[:, None]
    full = np.arccos(np.clip(np.einsum("bi,bi->b", a, b), -1.0, 1.0))
    t = max_swing / full
    edge = (np.sin((1.0 - t) * full)[:, None] * a + np.sin(t * full)[:, None] * b) / np.sin(full)[:, None]
    out[over] = np.einsum("bij,bjk->bik", swing_rotation(toward, edge), wanted[over])
    return out


def chest_rotation(trunk0, trunk_new):
    """(F,3,3) swing of the last trunk segment: the chest's world rotation delta."""
    old, new = trunk0[:, -1] - trunk0[:, -2], trunk_new[:, -1] - trunk_new[:, -2]
    return lanes.run(vec.swing_rotation, (old, new))
