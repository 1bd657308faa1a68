"""Joint limits enforced inside the FABRIK iterations (Aristidou & Lasenby 2011 style).

Joint i of a chain constrains the direction of segment i -> i+1 relative to the parent direction: segment
i-1 -> i, or for joint 0 the chain's fixed `parent_direction`. Two kinds besides FREE:
- CONE: the angle between parent and child direction is at most cone_angle.
- HINGE: the child direction stays in the plane perpendicular to the hinge axis, and its signed bend angle
  about the axis, measured from the parent direction, stays in [hinge_min, hinge_max]. A range that does not
  contain negative angles is a hinge whose bend side never flips (elbows, knees).
The hinge axis is given at the START pose and carried along by the parent segment's swing while solving.
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import SolverInputError
from .geometry import any_perpendicular, apply_matrix, cross, dot, norm, normalize, swing_rotation

FREE, CONE, HINGE = 0, 1, 2

# A direction whose in-plane part is shorter than this is treated as parallel to the hinge axis / antiparallel
# to the parent: its bend angle is undefined, so the previous direction stands in.
_DEGENERATE = 1e-9


@dataclass(frozen=True)
class JointLimits:
    """Limits of a chain of n joints: one entry per joint 0..n-2 (see the module docstring)."""

    kind: np.ndarray
    cone_angle: np.ndarray
    hinge_axis: np.ndarray
    hinge_min: np.ndarray
    hinge_max: np.ndarray

    def __post_init__(self):
        kind = np.array(self.kind, dtype=np.int64).reshape(-1)
        m = kind.shape[0]
        cone = np.array(self.cone_angle, dtype=np.float64).reshape(-1)
        axis = np.array(self.hinge_axis, dtype=np.float64)
        lo = np.array(self.hinge_min, dtype=np.float64).reshape(-1)
        hi = np.array(self.hinge_max, dtype=np.float64).reshape(-1)
        if cone.shape != (m,) or lo.shape != (m,) or hi.shape != (m,):
            raise SolverInputError(f"joint limits: every per-joint array needs {m} entries")
        if axis.shape not in ((m, 3),) and not (axis.ndim == 3 and axis.shape[1:] == (m, 3)):
            raise SolverInputError(f"joint limits: hinge_axis must be ({m},3) or (B,{m},3), got {axis.shape}")
        if np.any((kind < FREE) | (kind > HINGE)):
            raise SolverInputError("joint limits: kind must be FREE=0, CONE=1 or HINGE=2")
        for name, arr in (("cone_angle", cone), ("hinge_axis", axis), ("hinge_min", lo), ("hinge_max", hi)):
            if not np.all(np.isfinite(arr)):
                raise SolverInputError(f"joint limits: {name} has NaN/inf")
        for i in np.nonzero(kind == CONE)[0]:
            if not 0.0 <= cone[i] <= math.pi:
                raise SolverInputError(f"joint {i}: cone angle must be in [0, pi]")
        for i in np.nonzero(kind == HINGE)[0]:
            if not -math.pi <= lo[i] <= hi[i] <= math.pi:
                raise SolverInputError(f"joint {i}: hinge range must satisfy -pi <= min <= max <= pi")
            if np.any(norm(axis[..., i, :]) <= 1e-12):
                raise SolverInputError(f"joint {i}: hinge axis has zero length")
        for arr in (kind, cone, axis, lo, hi):
            arr.setflags(write=False)
        for name, arr in (("kind", kind), ("cone_angle", cone), ("hinge_axis", axis),
                          ("hinge_min", lo), ("hinge_max", hi)):
            object.__setattr__(self, name, arr)

    @classmethod
    def free(cls, n):
        """No limits on a chain of n joints."""
        if n < 2:
            raise SolverInputError("a chain needs at least 2 joints")
        m = n - 1
        return cls(np.zeros(m, np.int64), np.full(m, math.pi), np.tile([0.0, 0.0, 1.0], (m, 1)),
                   np.full(m, -math.pi), np.full(m, math.pi))

    def __len__(self):
        return self.kind.shape[0]

    def _check_index(self, i):
        if not 0 <= i < len(self):
            raise SolverInputError(f"joint {i} out of range: limits cover joints 0..{len(self) - 1}")

    def with_cone(self, i, angle):
        """A copy with joint i limited to a cone of half-angle `angle` radians around the parent direction."""
        self._check_index(i)
        kind, cone = self.kind.copy(), self.cone_angle.copy()
        kind[i], cone[i] = CONE, angle
        return replace(self, kind=kind, cone_angle=cone)

    def with_hinge(self, i, axis, lo, hi):
        """A copy with joint i a hinge about `axis` (3,) or per problem (B,3), at the start pose, bend range
        [lo, hi] radians (positive = right-handed about the axis, from the parent direction)."""
        self._check_index(i)
        axis = np.asarray(axis, dtype=np.float64)
        axes = self.hinge_axis
        if axis.ndim == 2 and axes.ndim == 2:
            axes = np.broadcast_to(axes, (axis.shape[0],) + axes.shape)
        axes = axes.copy()
        axes[..., i, :] = axis
        kind, lo_arr, hi_arr = self.kind.copy(), self.hinge_min.copy(), self.hinge_max.copy()
        kind[i], lo_arr[i], hi_arr[i] = HINGE, lo, hi
        return replace(self, kind=kind, hinge_axis=axes, hinge_min=lo_arr, hinge_max=hi_arr)

    @property
    def any_active(self):
        return bool(np.any(self.kind != FREE))


def hinge_axis_from_bend(parent_dir, child_dir):
    """Hinge axis normalize(cross(parent, child)) of a bent start pose, so that the start pose's bend side is
    the positive one. Raises SolverInputError for a straight (or zero) joint, whose bend side is undefined."""
    u = normalize(parent_dir)
    v = normalize(child_dir)
    c = cross(u, v)
    if np.any(norm(c) <= 1e-9):
        raise SolverInputError("joint is straight: cannot derive a hinge axis from it")
    return normalize(c)


def carry_axis(axis_at_start, start_parent_dir, parent_dir):
    """The hinge axis moved with its parent segment: the minimal swing from the start parent direction to
    the current one, applied to the start axis."""
    return apply_matrix(swing_rotation(start_parent_dir, parent_dir), axis_at_start)


def _with_fallback(v, fallback, bad):
    return np.where(bad[..., None], fallback, v)


def apply_cone(parent, v, angle, fallback):
    """Clamp unit directions v (...,3) into the cone of half-angle `angle` (...) about unit `parent`: a direction
    outside is rotated toward the parent in their common plane to exactly the cone angle. `fallback` (the
    previous direction) gives the rotation plane when v is antiparallel to the parent.
    Returns (limited directions, binding mask)."""
    c = dot(parent, v)
    w = v - c[..., None] * parent
    # atan2 of the perpendicular and parallel parts resolves small angles; cos alone only to ~1e-8 rad.
    over = np.arctan2(norm(w), c) > angle
    bad = ~(norm(w) > _DEGENERATE)
    if np.any(bad):
        fb = fallback - dot(fallback, parent)[..., None] * parent
        w = _with_fallback(w, fb, bad)
        bad = ~(norm(w) > _DEGENERATE)
        w = _with_fallback(w, np.broadcast_to(any_perpendicular(parent), w.shape), bad)
    w = w - dot(w, parent)[..., None] * parent  # twice: w may be tiny, its first pass inexact
    e = w / norm(w)[..., None]
    angle = np.asarray(angle, dtype=np.float64)[..., None]
    limited = np.cos(angle) * parent + np.sin(angle) * e
    return np.where(over[..., None], limited, v), over


def apply_hinge(parent, v, axis, lo, hi, fallback):
    """Put unit directions v (...,3) on the hinge: in the plane perpendicular to `axis` (made perpendicular to
    the unit `parent` first), signed bend angle about the axis clamped to [lo, hi]. A v (nearly) parallel to
    the axis has no bend angle: the previous direction `fallback` stands in, and if that is degenerate too
    the clamped zero bend. Returns (limited directions, binding mask: the direction had to change)."""
    a = axis - dot(axis, parent)[..., None] * parent
    a_bad = ~(norm(a) > _DEGENERATE)
    if np.any(a_bad):
        a = _with_fallback(a, np.broadcast_to(any_perpendicular(parent), a.shape), a_bad)
    a = a - dot(a, parent)[..., None] * parent  # twice: a may be tiny, its first pass inexact
    a = a / norm(a)[..., None]
    side = cross(a, parent)  # the direction of positive bend: a quarter turn about the axis from the parent
    x = dot(v, parent)
    y = dot(v, side)
    bad = ~(np.hypot(x, y) > _DEGENERATE)
    if np.any(bad):
        x = np.where(bad, dot(fallback, parent), x)
        y = np.where(bad, dot(fallback, side), y)
        bad = ~(np.hypot(x, y) > _DEGENERATE)
        x = np.where(bad, 1.0, x)
        y = np.where(bad, 0.0, y)
    theta = np.clip(np.arctan2(y, x), lo, hi)[..., None]
    limited = np.cos(theta) * parent + np.sin(theta) * side
    binding = norm(limited - v) > 1e-12
    return limited, binding
