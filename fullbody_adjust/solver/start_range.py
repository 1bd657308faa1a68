"""A start pose outside the default joint ranges is the rig's own range there: the ranges widen to hold it.

The default human limits (body.HumanLimits) bound the MOTION a solve makes. A character whose start pose lies
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

from .geometry import any_perpendicular, cross, dot, norm, normalize
from .limits import CONE, FREE, HINGE

# Added to a widened bound (radians) so the start is strictly inside it whatever the rounding of a later check.
MARGIN = 1e-9


def widened_ranges(kind, cone, lo, hi, axes, parent_direction, segments):
    """(cone, lo, hi) (m,) widened to hold the start pose: ``kind``, ``cone``, ``lo``, ``hi`` (m,) the ranges,
    ``axes`` (F,m,3) the hinge axes at the start, ``parent_direction`` (F,3) joint 0's parent direction (None:
    joint 0 is free), ``segments`` (F,m,3) the start chain's segments. New arrays; the given ones unchanged.
    A bound is only ever widened (never past a half turn), so ranges that were invalid stay invalid."""
    cone, lo, hi = cone.copy(), lo.copy(), hi.copy()
    for i in np.nonzero(kind != FREE)[0]:
        parent = parent_direction if i == 0 else segments[:, i - 1]
        if parent is None:
            continue
        u = normalize(parent)
        v = normalize(segments[:, i])
        c = dot(u, v)
        angle = np.arctan2(norm(v - c[:, None] * u), c)  # as limits.apply_cone measures it
        if kind[i] == CONE:
            cone[i] = max(cone[i], min(float(angle.max()) + MARGIN, math.pi))
        elif kind[i] == HINGE:
            a = axes[:, i] - dot(axes[:, i], u)[:, None] * u
            a = normalize(a, fallback=any_perpendicular(u))
            positive = dot(v, cross(a, u)) >= 0.0
            if np.any(positive):
                hi[i] = max(hi[i], min(float(angle[positive].max()) + MARGIN, math.pi))
            if np.any(~positive):
                lo[i] = min(lo[i], max(-float(angle[~positive].max()) - MARGIN, -math.pi))
    return cone, lo, hi
