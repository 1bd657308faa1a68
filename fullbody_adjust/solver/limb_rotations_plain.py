"""limb_rotations._segment_rotations for a few chains in plain Python floats (an Adjust Pose or Live solve turns
the segments of one or two limbs at a time): the numpy path's operations in its order, the trigonometry and the
matrix products numpy's own routines on one value (geometry_plain.py), so each row gets the numpy path's bits
(tests/solver/test_limb_rotations_plain.py). Returns None where plain floats would divide by zero (a segment of
zero length): the numpy path then answers."""

import numpy as np

from . import geometry_plain as g
from . import limits_plain
from .limits import HINGE


def segment_rotations(start, joints, kind, axes):
    """_segment_rotations(start, joints, kind, axes) in plain floats: (b,n-1,3,3), or None."""
    kinds = None if kind is None else kind.tolist()
    rows = axes.tolist() if axes is not None else [None] * len(start)
    try:
        rot = [_chain(s, j, kinds, a) for s, j, a in zip(start.tolist(), joints.tolist(), rows)]
    except ZeroDivisionError:
        return None
    return np.array(rot, dtype=np.float64).reshape(start.shape[0], start.shape[1] - 1, 3, 3)


def _chain(start, joints, kind, axes):
    old = [g.sub(start[i + 1], start[i]) for i in range(len(start) - 1)]
    new = [g.sub(joints[i + 1], joints[i]) for i in range(len(joints) - 1)]
    rot = [g.swing_rotation(o, n) for o, n in zip(old, new)]
    if kind is None:
        return rot
    for i in range(1, len(kind)):
        if kind[i] != HINGE:
            continue
        parent, child = g.divided_by_norm(new[i - 1]), g.divided_by_norm(new[i])
        tau = limits_plain.hinge_twist_angle(parent, child, g.apply_matrix(rot[i - 1], axes[i]))
        rot[i - 1] = g.matmul(g.rotation_about(parent, tau), rot[i - 1])
        if i + 1 >= len(kind) or kind[i + 1] != HINGE:
            rot[i] = g.matmul(g.swing_rotation(g.apply_matrix(rot[i - 1], old[i]), new[i]), rot[i - 1])
    return rot


