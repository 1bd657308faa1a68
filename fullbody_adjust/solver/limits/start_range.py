"""A start pose outside the default joint ranges is the rig's own range there: the ranges widen to hold it.

The default human limits (human.HumanLimits) bound the MOTION a solve makes. A character whose start pose lies
outside them (an imported rig whose legs rest past the default hip cone, an arm turned further than the default
shoulder allows, an elbow folded beyond the default hinge range) is not "corrected": each range is widened just
enough to hold the start pose of every frame given, so a limb that has to move is never pulled back toward the
default range by its limits (it may stay where it started, or move back in), and a limb that stays is exactly
as it was. Ranges are one per joint (JointLimits), so over several frames they widen to the widest start.

Cones widen to the start's angle to its parent direction; hinge ranges widen to the start's bend, measured as
the angle between the parent and child directions on the side of the hinge plane the child lies on (at least
the bend a twisted hinge measures, so the start lies within the widened wedge or its bend range).
"""

import math

import numpy as np

from ..maths.geometry import TINY, cross, dot, norm
from .joint_limits import CONE, FREE, HINGE

# Added to a widened bound (radians) so the start is strictly inside it whatever the rounding of a later check.
MARGIN = 1e-9


def widened_ranges(kind, cone, lo, hi, axes, parent_direction, segments):
    """(cone, lo, hi) (m,) widened to hold the start pose: ``kind``, ``cone``, ``lo``, ``hi`` (m,) the ranges,
    ``axes`` (F,m,3) the hinge axes at the start, ``parent_direction`` (F,3) joint 0's parent direction (None:
    joint 0 is free), ``segments`` (F,m,3) the start chain's segments. An array that widens is a new one (the
    given ones are never changed); one that does not is returned as given. A bound is only ever widened (never
    past a half turn), so ranges that were invalid stay invalid."""
    limited = kind != FREE
    if parent_direction is None:
        limited[0] = False
    joints = np.flatnonzero(limited)
    if joints.size == 0:
        return cone, lo, hi
    parents = segments[:, joints - 1]
    if joints[0] == 0:
        parents[:, 0] = parent_direction
    # Unit directions; a zero-length segment (the chains' own error to report, prepared.chains) gives no angle.
    u = parents / np.maximum(norm(parents), TINY)[..., None]
    v = segments[:, joints] / np.maximum(norm(segments[:, joints]), TINY)[..., None]
    c = dot(u, v)
    angle = np.arctan2(norm(v - c[..., None] * u), c)  # (F,k), as limits.cone measures it
    widest = np.minimum(angle.max(axis=0) + MARGIN, math.pi)
    kinds = kind[joints]
    wider = (kinds == CONE) & (widest > cone[joints])
    if np.any(wider):
        cone = cone.copy()
        cone[joints[wider]] = widest[wider]
    hinges = np.flatnonzero(kinds == HINGE)
    if hinges.size:
        # The side a hinge's positive bends lie on is axis x parent; the axis' part along the parent adds nothing.
        positive = dot(v[:, hinges], cross(axes[:, joints[hinges]], u[:, hinges])) >= 0.0
        bend = np.minimum(angle[:, hinges] + MARGIN, math.pi)
        at = joints[hinges]
        over = np.where(positive, bend, -math.inf).max(axis=0)
        under = np.where(positive, math.inf, -bend).min(axis=0)
        if np.any(over > hi[at]):
            hi = hi.copy()
            hi[at] = np.maximum(hi[at], over)
        if np.any(under < lo[at]):
            lo = lo.copy()
            lo[at] = np.minimum(lo[at], under)
    return cone, lo, hi
