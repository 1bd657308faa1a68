"""Joint limits enforced inside the FABRIK iterations (Aristidou & Lasenby 2011 style).

Joint i of a chain constrains the direction of segment i -> i+1 relative to the parent direction: segment
i-1 -> i, or for joint 0 the chain's fixed `parent_direction`. Two kinds besides FREE:
- CONE: the angle between parent and child direction is at most cone_angle.
- HINGE: the child direction stays in the plane perpendicular to the hinge axis, and its signed bend angle
  about the axis, measured from the parent direction, stays in [hinge_min, hinge_max]. A range that does not
  contain negative angles is a hinge whose bend side never flips (elbows, knees).
The hinge axis is given at the START pose (or at the parent direction `hinge_reference`, if given) and carried
along by the parent segment's minimal swing while solving (carry_axis); the solver uses its part perpendicular
to the parent direction (any perpendicular if the axis lies along the parent, where the hinge is meaningless).

Hinge twist. A swing carries the axis but cannot turn the bend plane about the parent segment, yet a real
shoulder or hip turns the upper arm or thigh about its own length (humeral/femoral rotation): without that,
a hinged limb reaches only the targets its parent's swing can face. `hinge_twist` (radians, in [0, pi/2))
lets the bend plane turn about the parent direction by up to +-hinge_twist from the carried axis. The set of
allowed child directions is then two wedges around the parent: positive bends at azimuths within
+-hinge_twist of the carried bend side, negative bends (if the range has any) opposite; hinge returns
the nearest allowed direction. As |twist| < pi/2 the two wedges never meet: the bend side never flips.
A caller that writes bone rotations turns the parent bone by the same twist (hinge_twist), so the
child's rotation relative to its parent stays a pure hinge.
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec
from ..errors import SolverInputError
from ..maths.geometry import all_set, any_set, norm

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
    # (n-1,) radians in [0, pi/2): how far the bend plane may turn about the parent direction (module
    # docstring). None = 0 everywhere: the plane turns only with the parent's swing.
    hinge_twist: np.ndarray = None
    # (n-1,3) or (B,n-1,3): the parent direction at which hinge_axis is given, where the carry starts from.
    # None = the chain's start pose. Lets a caller keep the axis in the frame it writes bone rotations in
    # when the chain starts from another pose (a limb carried along by its parent, a warm start).
    hinge_reference: np.ndarray = None

    def __post_init__(self):
        kind = np.array(self.kind, dtype=np.int64).reshape(-1)
        m = kind.shape[0]
        cone = np.array(self.cone_angle, dtype=np.float64).reshape(-1)
        axis = np.array(self.hinge_axis, dtype=np.float64)
        lo = np.array(self.hinge_min, dtype=np.float64).reshape(-1)
        hi = np.array(self.hinge_max, dtype=np.float64).reshape(-1)
        twist = np.zeros(m) if self.hinge_twist is None else np.array(self.hinge_twist, dtype=np.float64)
        twist = twist.reshape(-1)
        ref = None if self.hinge_reference is None else np.array(self.hinge_reference, dtype=np.float64)
        if cone.shape != (m,) or lo.shape != (m,) or hi.shape != (m,) or twist.shape != (m,):
            raise SolverInputError(f"joint limits: every per-joint array needs {m} entries")
        for name, arr in (("hinge_axis", axis), ("hinge_reference", ref)):
            if arr is not None and arr.shape != (m, 3) and not (arr.ndim == 3 and arr.shape[1:] == (m, 3)):
                raise SolverInputError(f"joint limits: {name} must be ({m},3) or (B,{m},3), got {arr.shape}")
        if any_set((kind < FREE) | (kind > HINGE)):
            raise SolverInputError("joint limits: kind must be FREE=0, CONE=1 or HINGE=2")
        for name, arr in (("cone_angle", cone), ("hinge_axis", axis), ("hinge_min", lo), ("hinge_max", hi),
                          ("hinge_twist", twist), ("hinge_reference", ref)):
            if arr is not None and not all_set(np.isfinite(arr)):
                raise SolverInputError(f"joint limits: {name} has NaN/inf")
        for i in np.nonzero(kind == CONE)[0]:
            if not 0.0 <= cone[i] <= math.pi:
                raise SolverInputError(f"joint {i}: cone angle must be in [0, pi]")
        for i in np.nonzero(kind == HINGE)[0]:
            if not -math.pi <= lo[i] <= hi[i] <= math.pi:
                raise SolverInputError(f"joint {i}: hinge range must satisfy -pi <= min <= max <= pi")
            if any_set(norm(axis[..., i, :]) <= 1e-12):
                raise SolverInputError(f"joint {i}: hinge axis has zero length")
            if not 0.0 <= twist[i] < math.pi / 2:
                raise SolverInputError(f"joint {i}: hinge twist must be in [0, pi/2)")
            if ref is not None and i > 0 and any_set(norm(ref[..., i, :]) <= 1e-12):
                raise SolverInputError(f"joint {i}: hinge reference direction has zero length")
        for arr in (kind, cone, axis, lo, hi, twist) + (() if ref is None else (ref,)):
            arr.setflags(write=False)
        for name, arr in (("kind", kind), ("cone_angle", cone), ("hinge_axis", axis),
                          ("hinge_min", lo), ("hinge_max", hi), ("hinge_twist", twist), ("hinge_reference", ref)):
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

    def with_hinge(self, i, axis, lo, hi, twist=0.0):
        """A copy with joint i a hinge about `axis` (3,) or per problem (B,3), at the start pose, bend range
        [lo, hi] radians (positive = right-handed about the axis, from the parent direction), bend plane free
        to turn by up to +-twist radians about the parent direction."""
        self._check_index(i)
        axis = np.asarray(axis, dtype=np.float64)
        axes = self.hinge_axis
        if axis.ndim == 2 and axes.ndim == 2:
            axes = np.broadcast_to(axes, (axis.shape[0],) + axes.shape)
        axes = axes.copy()
        axes[..., i, :] = axis
        kind, lo_arr, hi_arr = self.kind.copy(), self.hinge_min.copy(), self.hinge_max.copy()
        twist_arr = self.hinge_twist.copy()
        kind[i], lo_arr[i], hi_arr[i], twist_arr[i] = HINGE, lo, hi, twist
        return replace(self, kind=kind, hinge_axis=axes, hinge_min=lo_arr, hinge_max=hi_arr, hinge_twist=twist_arr)

    def derived(self, **arrays):
        """A copy with some arrays replaced WITHOUT validation, for a solver's own per-solve copies of limits it
        has validated (e.g. hinge axes rotated along with the chain, references taken from checked chains):
        __post_init__ costs more than a small chain iteration."""
        out = object.__new__(type(self))
        out.__dict__.update(self.__dict__)
        for name, arr in arrays.items():
            if name not in self.__dataclass_fields__:
                raise TypeError(f"JointLimits has no field {name!r}")
            if arr is not None:
                arr = np.asarray(arr, dtype=np.float64)
                arr.setflags(write=False)
            object.__setattr__(out, name, arr)
        return out

    @property
    def any_active(self):
        return any_set(self.kind != FREE)

    def per_joint_key(self):
        """The limits every problem of a batch shares (kinds, cone angles, hinge ranges and twists), as a
        hashable value: limits with equal keys can be stacked into one batch (stack)."""
        return tuple(a.tobytes() for a in (self.kind, self.cone_angle, self.hinge_min, self.hinge_max,
                                           self.hinge_twist))

    @staticmethod
    def stack(parts):
        """One JointLimits for the batches of `parts` stacked in order: limits with the same per_joint_key and
        per-problem hinge axes and references (b_i,m,3), as a solver's own per-solve copies have them."""
        if len(parts) == 1:
            return parts[0]
        return parts[0].derived(hinge_axis=np.concatenate([p.hinge_axis for p in parts]),
                                hinge_reference=np.concatenate([p.hinge_reference for p in parts]))


def carry_axis(axis_at_start, start_parent_dir, parent_dir):
    """The hinge axis moved with its parent segment: the minimal swing from the start parent direction to the
    current one, applied to the start axis. Arrays (...,3) (carry on the arrays)."""
    axis, ref, parent = (np.asarray(a, dtype=np.float64) for a in (axis_at_start, start_parent_dir, parent_dir))
    return np.broadcast_to(carry(axis, ref, parent), np.broadcast_shapes(axis.shape, ref.shape, parent.shape))


def carry(axis, ref, parent):
    """carry_axis on components (maths/lanes.py): geometry.swing_rotation from ref to parent applied to the one
    vector axis, without building the matrix: x + (cos t - 1)(e1 (e1.x) + e2 (e2.x)) + sin t (e2 (e1.x) - e1 (e2.x))
    in the frame e1 = ref, e2 = the part of parent perpendicular to it (a half turn about any perpendicular where
    parent is opposite to ref)."""
    a, b = vec.divided(ref, vec.norm(ref)), vec.divided(parent, vec.norm(parent))
    c = vec.dot(a, b)
    w = vec.sub(b, vec.scaled(a, c))
    s = vec.norm(w)
    degenerate = lanes.not_(s > 1e-14)
    if lanes.any_(degenerate):
        w = lanes.pick(degenerate, vec.any_perpendicular(a), w)
        s = lanes.where(degenerate, 0.0, s)
    w = vec.sub(w, vec.scaled(a, vec.dot(w, a)))  # twice: w may be tiny, its first pass inexact
    e = vec.divided(w, vec.norm(w))
    t = lanes.arctan2(s, c)
    cos_less_1, sin_t = lanes.cos(t) - 1.0, lanes.sin(t)
    along_a, along_e = vec.dot(a, axis), vec.dot(e, axis)
    turned = vec.add(vec.scaled(a, along_a), vec.scaled(e, along_e))
    side = vec.sub(vec.scaled(e, along_a), vec.scaled(a, along_e))
    return vec.add(vec.add(axis, vec.scaled(turned, cos_less_1)), vec.scaled(side, sin_t))


def cone(parent, v, angle, fallback):
    """Unit direction v clamped into the cone of half-angle `angle` about the unit `parent`, on components: a
    direction outside is rotated toward the parent in their common plane to exactly the cone angle; `fallback`
    (the previous direction) gives the plane where v is antiparallel to the parent. (direction, binding)."""
    c = vec.dot(parent, v)
    w = vec.sub(v, vec.scaled(parent, c))
    wn = vec.norm(w)
    # atan2 of the perpendicular and parallel parts resolves small angles; cos alone only to ~1e-8 rad.
    over = lanes.arctan2(wn, c) > angle
    if not lanes.any_(over):
        return v, over  # nothing to clamp (the common case inside FABRIK's iterations)
    bad = lanes.not_(wn > _DEGENERATE)
    if lanes.any_(bad):
        w = lanes.pick(bad, vec.sub(fallback, vec.scaled(parent, vec.dot(fallback, parent))), w)
        bad = lanes.not_(vec.norm(w) > _DEGENERATE)
        if lanes.any_(bad):
            w = lanes.pick(bad, vec.any_perpendicular(parent), w)
    w = vec.sub(w, vec.scaled(parent, vec.dot(w, parent)))  # twice: w may be tiny, its first pass inexact
    e = vec.divided(w, vec.norm(w))
    limited = vec.add(vec.scaled(parent, lanes.cos(angle)), vec.scaled(e, lanes.sin(angle)))
    return lanes.pick(over, limited, v), over


def _clamp_angle(theta, lo, hi):
    """Angles theta in (-pi, pi] clamped to [lo, hi]: an angle outside goes to the bound nearer around the
    circle (a bend wanted at -2.9 rad is 0.68 rad from a 2.7 rad bound, 2.9 from a 0 bound), so the result is
    the nearest direction of the arc, not merely the nearer bound on the line."""
    inside = (theta >= lo) & (theta <= hi)
    if lanes.all_(inside):
        return theta
    to_lo = abs(lanes.remainder(theta - lo + math.pi, 2 * math.pi) - math.pi)
    to_hi = abs(lanes.remainder(theta - hi + math.pi, 2 * math.pi) - math.pi)
    return lanes.where(inside, theta, lanes.where(to_lo <= to_hi, lo, hi))


def hinge(parent, v, axis, lo, hi, fallback, twist=None):
    """Unit direction v put on the hinge, on components: in the plane perpendicular to `axis` (made perpendicular
    to the unit `parent` first), signed bend angle about the axis clamped to [lo, hi] (_clamp_angle). A v
    (nearly) parallel to the axis has no bend angle: the previous direction `fallback` stands in, and if that
    is degenerate too the clamped zero bend. With `twist` (radians, a number) the plane may turn about the
    parent by up to +-twist: the nearest direction of the two wedges the module docstring describes.
    Returns (limited direction, binding: the direction had to change)."""
    a, side = hinge_frame(parent, axis)
    if twist is not None and twist > 0.0:
        return _twisted_hinge(parent, v, a, side, lo, hi, fallback, twist)
    x, y = vec.dot(v, parent), vec.dot(v, side)
    bad = lanes.not_(lanes.hypot(x, y) > _DEGENERATE)
    if lanes.any_(bad):
        x, y = lanes.where(bad, vec.dot(fallback, parent), x), lanes.where(bad, vec.dot(fallback, side), y)
        bad = lanes.not_(lanes.hypot(x, y) > _DEGENERATE)
        x, y = lanes.where(bad, 1.0, x), lanes.where(bad, 0.0, y)
    theta = _clamp_angle(lanes.arctan2(y, x), lo, hi)
    limited = vec.add(vec.scaled(parent, lanes.cos(theta)), vec.scaled(side, lanes.sin(theta)))
    return limited, vec.norm(vec.sub(limited, v)) > 1e-12


def _twisted_hinge(parent, v, a, side, lo, hi, fallback, twist):
    """hinge with a twist range. In the frame (parent, side, a), v has azimuth phi about the parent (from the side
    toward the axis) and polar angle from the parent. The bend plane turned by tau has the side
    cos(tau) side + sin(tau) a. Candidates: the plane nearest v's azimuth with v on its positive side
    (tau = clip(phi)) and with v on its negative side (tau = clip(phi -+ pi)); in each, v's projection with
    its bend clamped to [lo, hi] (the nearest point of that arc). The nearer candidate wins."""
    x, y, z = vec.dot(v, parent), vec.dot(v, side), vec.dot(v, a)
    r, phi = lanes.hypot(y, z), lanes.arctan2(z, y)
    # v along the axis with no twist to turn to it: the previous direction stands in.
    bad = lanes.not_(lanes.hypot(x, r * lanes.cos(phi - lanes.clip(phi, -twist, twist))) > _DEGENERATE)
    if lanes.any_(bad):
        x = lanes.where(bad, vec.dot(fallback, parent), x)
        y2, z2 = vec.dot(fallback, side), vec.dot(fallback, a)
        r, phi = lanes.where(bad, lanes.hypot(y2, z2), r), lanes.where(bad, lanes.arctan2(z2, y2), phi)
        bad = lanes.not_(lanes.hypot(x, r * lanes.cos(phi - lanes.clip(phi, -twist, twist))) > _DEGENERATE)
        x, r, phi = lanes.where(bad, 1.0, x), lanes.where(bad, 0.0, r), lanes.where(bad, 0.0, phi)
    best = best_dot = None
    for wanted in (phi, lanes.where(phi > 0.0, phi - math.pi, phi + math.pi)):
        tau = lanes.clip(wanted, -twist, twist)
        theta = _clamp_angle(lanes.arctan2(r * lanes.cos(phi - tau), x), lo, hi)
        plane = vec.add(vec.scaled(side, lanes.cos(tau)), vec.scaled(a, lanes.sin(tau)))
        cand = vec.add(vec.scaled(parent, lanes.cos(theta)), vec.scaled(plane, lanes.sin(theta)))
        c = vec.dot(cand, v)
        if best is None:
            best, best_dot = cand, c
        else:
            best = lanes.pick(c > best_dot, cand, best)
    return best, vec.norm(vec.sub(best, v)) > 1e-12


def limit(limits, i, parent, v, fallback, axis, reverse=False):
    """Joint i's limit (JointLimits `limits`) on the unit direction v of its segment, on components (reverse: the
    forward pass's counterpart, `parent` then the child's direction and the hinge range mirrored); `axis` the
    hinge axis carried to where it applies. Returns (direction, binding)."""
    if limits.kind[i] == CONE:
        return cone(parent, v, float(limits.cone_angle[i]), fallback)
    lo, hi = float(limits.hinge_min[i]), float(limits.hinge_max[i])
    if reverse:
        lo, hi = -hi, -lo
    return hinge(parent, v, axis, lo, hi, fallback, float(limits.hinge_twist[i]))


def hinge_twist(parent, child, axis):
    """The twist (radians, in (-pi/2, pi/2]) by which the bend plane of unit `child` about unit `parent` is
    turned from the plane perpendicular to `axis` (the carried axis, made perpendicular to the parent), about
    the parent direction; 0 where the child lies along the parent (every plane holds it). On components
    (maths/lanes.py) or arrays (...,3)."""
    a, side = hinge_frame(parent, axis)
    y, z = vec.dot(child, side), vec.dot(child, a)
    phi = lanes.arctan2(z, y)
    plane = lanes.where(phi > math.pi / 2, phi - math.pi, lanes.where(phi <= -math.pi / 2, phi + math.pi, phi))
    return lanes.where(lanes.hypot(y, z) > _DEGENERATE, plane, 0.0)


def hinge_frame(parent, axis):
    """The unit hinge axis made perpendicular to the unit `parent` (any perpendicular if it lies along the parent)
    and the side of positive bend, axis x parent, on components (maths/lanes.py)."""
    a = vec.sub(axis, vec.scaled(parent, vec.dot(axis, parent)))
    a_bad = lanes.not_(vec.norm(a) > _DEGENERATE)
    if lanes.any_(a_bad):
        a = lanes.pick(a_bad, vec.any_perpendicular(parent), a)
    a = vec.sub(a, vec.scaled(parent, vec.dot(a, parent)))  # twice: a may be tiny, its first pass inexact
    a = vec.divided(a, vec.norm(a))
    return a, vec.cross(a, parent)
