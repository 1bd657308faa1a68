"""Bone rotations of solved limbs (DESIGN §2.6): each segment's world rotation delta from its start direction to
its solved one, a hinge's twist carried on its parent bone, and the chest's rotation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import apply_matrix, norm, swing_rotation
from .limits import HINGE, hinge_twist_angle

_EYE = np.eye(3)


@dataclass
class LimbSolve:
    """A limb's solved chain on every frame (rigidly carried where not solved)."""

    joints: np.ndarray  # (F,n,3)
    solved: np.ndarray  # (F,) bool
    status: np.ndarray  # (F,) str ('' where not solved)
    reason: np.ndarray  # (F,) str
    rotations: np.ndarray = field(default=None)  # (F,n-1,3,3) each segment's world rotation delta

    def segment_rotations(self, start, limits):
        """World rotation deltas of the chain's segments from the start chain to the solved one, on solved
        frames (computed once per limb; `limits` the limb's LimbLimits or None): see _segment_rotations."""
        if self.rotations is None:
            self.rotations = np.broadcast_to(_EYE, self.joints.shape[:2] + (3, 3))[:, 1:].copy()
            s = self.solved
            if np.any(s):
                self.rotations[s] = _segment_rotations(start[s], self.joints[s], limits, s)
        return self.rotations


def _segment_rotations(start, joints, limits, frames):
    """World rotation deltas (b,n-1,3,3) of chain segments from `start` (b,n,3) to `joints` (b,n,3) on frames
    `frames` (a row selector of the limbs' F frames), DESIGN §2.6: each segment turns by the minimal swing
    from its old direction to its new one (its twist kept), except around a hinge (limits: LimbLimits or None)
    with joint i > 0:
      - the parent segment i-1 also turns about its new direction by the hinge's twist (the angle by which the
        bend plane left the start axis carried by the parent's swing, as the solver carries it), so the
        start hinge axis turned with the bone is the axis the child bends about;
      - the child segment i turns by the minimal swing in its parent's frame: relative to the parent it
        rotates about the hinge axis only, a pure hinge (an elbow or knee does not twist)."""
    old = np.diff(start, axis=1)
    new = np.diff(joints, axis=1)
    rot = swing_rotation(old, new)
    if limits is None:
        return rot
    lim = limits.limits
    axes = lim.hinge_axis
    for i in np.nonzero(lim.kind == HINGE)[0]:
        if i == 0:
            continue
        axis = axes[frames, i] if axes.ndim == 3 else np.broadcast_to(axes[i], (len(start), 3))
        parent = new[:, i - 1] / norm(new[:, i - 1])[:, None]
        child = new[:, i] / norm(new[:, i])[:, None]
        tau = hinge_twist_angle(parent, child, apply_matrix(rot[:, i - 1], axis))
        rot[:, i - 1] = np.einsum("bij,bjk->bik", _rotation_about(parent, tau), rot[:, i - 1])
        if i + 1 >= len(lim) or lim.kind[i + 1] != HINGE:  # a hinge parent itself keeps the solver's frame
            rot[:, i] = np.einsum("bij,bjk->bik", swing_rotation(apply_matrix(rot[:, i - 1], old[:, i]), new[:, i]),
                                  rot[:, i - 1])
    return rot


def _rotation_about(axis, angle):
    """Rotation matrices (b,3,3) about unit axes (b,3) by angles (b,) (Rodrigues)."""
    k = axis
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    kx = np.zeros(k.shape[:1] + (3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    return c * _EYE + s * kx + (1.0 - c) * (k[:, :, None] * k[:, None, :])


def chest_rotation(trunk0, trunk_new):
    """(F,3,3) swing of the last trunk segment: the chest's world rotation delta."""
    return swing_rotation(trunk0[:, -1] - trunk0[:, -2], trunk_new[:, -1] - trunk_new[:, -2])

