"""A rig's own joint limits (Blender's per-bone IK settings and Limit Rotation constraints, read by the bridge
into BoneLimitSpec) as overrides of the default human limits, in the CONE/HINGE vocabulary of limits/joint_limits.py.

What a spec measures. Every angle is the bone's rotation relative to its rest orientation in its parent's
frame, as Blender's IK solver and a LOCAL Limit Rotation both measure it: X and Z swing the bone's direction,
Y twists the bone about its own length. The solver keeps each bone's twist (it writes the smallest swing of
each segment), so Y locks and ranges constrain nothing it changes and are left out here.

Mapping, per chain joint whose bone sets X or Z (the joint's default limit is replaced; a joint whose bone
sets neither keeps its default, so an elbow or knee keeps "never bends backwards" only where the rig sets
nothing). "The rest frame" is the bone's rest axes carried by its parent's pose; a hinge about one of its
axes is made perpendicular to the parent direction, as limits/joint_limits.py does with every hinge axis:
  X and Z locked   held where it starts: a hinge in the plane of the parent direction and the start direction,
                   bend range = the start bend (over frames whose start bends differ, their span, as a bend
                   range is one pair of numbers for every frame).
  one locked       a hinge about the other axis of the rest frame; bend range = that axis's range (the whole
                   circle when it has none) from the rest bend (_ranged: each bound is where the hinge's plane
                   meets the directions turned exactly that far about the axis). Blender keeps a locked axis
                   at its start value; a start pose turned about the locked axis is not on that hinge's plane
                   (the directions left to it form no plane through the parent), so there the lock wins and
                   the direction is held as above.
  neither locked, ranged
                   a hinge about a ranged axis with that axis's range: the other axis stays at its rest value 0.
                   Conservative on purpose: a direction turned about both axes at once has no single "rotation
                   about X" (each Euler order reads other angles), while a turn about one rest axis reads the
                   same angle in every order, so the range holds whichever order a Limit Rotation uses. The
                   axis is the one whose range is wider among those whose other axis admits 0 (free, or a range
                   holding 0); when neither does, the direction is held at the nearest corner of both ranges
                   (Euler XYZ: the X turn first). A start pose turned about the other axis is brought onto
                   the hinge's plane by the first solve.
Joint 0's parent direction becomes the bone's rest direction carried by its parent (the start direction when
held), so its ranges are exact on every frame; for joints > 0 the parent is the previous chain segment, whose
rest bend is the same on every frame when the parent bone is rigid (bounds are averaged over the frames).
A bone that does not inherit its parent's rotation is read as if it did.
Every hinge made here has no twist allowance: the bend plane stays where the rig puts it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..body.model import BodyModel
from .human import LimbLimits
from ..errors import SolverInputError
from ..maths.geometry import (all_set, any_perpendicular, any_set, apply_matrix, cross, dot, norm, normalize,
    rotate_about_axis)

AXES = "XYZ"

# A start pose turned by less than this (radians) about a locked axis counts as not turned about it (Blender's
# pose is float32).
_ON_PLANE = 1e-3


@dataclass(frozen=True)
class BoneLimitSpec:
    """One bone's own rotation limits, plain data. Per axis X, Y, Z: `locked` (bool) and `ranges` ((lo, hi)
    radians, or None for no range), relative to the bone's rest orientation in its parent's frame;
    `rest_in_parent` (3,3): the bone's rest axes (columns) in its parent's rest frame (the armature's for a
    bone without parent)."""

    locked: tuple = (False, False, False)
    ranges: tuple = (None, None, None)
    rest_in_parent: np.ndarray = None

    def __post_init__(self):
        locked = tuple(bool(v) for v in self.locked)
        ranges = tuple(self.ranges)
        if len(locked) != 3 or len(ranges) != 3:
            raise SolverInputError("bone limits need one entry per axis X, Y, Z")
        checked = []
        for axis, r in zip(AXES, ranges):
            if r is not None:
                lo, hi = (float(v) for v in r)
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    raise SolverInputError(f"{axis} range has NaN/inf")
                if lo > hi:
                    raise SolverInputError(f"{axis} range is empty (min {math.degrees(lo):.4g} deg above max "
                                           f"{math.degrees(hi):.4g} deg)")
                r = (lo, hi)
            checked.append(r)
        rest = np.eye(3) if self.rest_in_parent is None else np.array(self.rest_in_parent, dtype=np.float64)
        if rest.shape != (3, 3) or not all_set(np.isfinite(rest)):
            raise SolverInputError("rest_in_parent must be a finite 3x3 matrix")
        rest.setflags(write=False)
        object.__setattr__(self, "locked", locked)
        object.__setattr__(self, "ranges", tuple(checked))
        object.__setattr__(self, "rest_in_parent", rest)

    @property
    def limits_direction(self) -> bool:
        """Whether the spec says anything about the bone's direction (X or Z locked or ranged)."""
        return any(self.locked[k] or self.ranges[k] is not None for k in (0, 2))


def rig_limits(defaults, model: BodyModel, heads, tails, rotations, specs) -> dict:
    """`defaults` ({limb name: LimbLimits}, e.g. human.default_limits) with every chain joint whose bone has a
    spec that limits its direction replaced by the rig's own limit (module docstring).

    heads, tails (F,J,3) and rotations (F,J,3,3) (each bone's axes as columns, any scale) at the start poses,
    in the solve's space; specs {bone name: BoneLimitSpec}. Bones outside the limbs' chains (hands, feet, the
    root, unmapped bones) are not solved as joints: their specs are ignored. Returns a new dict; `defaults`
    is not changed. A limb missing from `defaults` (limits switched off for it) stays missing."""
    heads = np.asarray(heads, dtype=np.float64)
    tails = np.asarray(tails, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    if heads.ndim != 3 or rotations.shape != heads.shape + (3,):
        raise SolverInputError(f"rotations must have shape {heads.shape + (3,)}, got {rotations.shape}")
    for name, spec in specs.items():
        if not isinstance(spec, BoneLimitSpec):
            raise SolverInputError(f"limits of bone {name!r} must be a BoneLimitSpec")
    axes = rotations / np.maximum(norm(np.swapaxes(rotations, -1, -2)), 1e-300)[..., None, :]  # unit columns
    out = dict(defaults)
    for limb_name, current in defaults.items():
        limb = model.limbs[limb_name]
        joints = limb.joints(heads, tails)
        segs = normalize(joints[:, 1:] - joints[:, :-1])
        limits, parent_direction = current.limits, current.parent_direction
        for i, bone in enumerate(limb.bones):
            spec = specs.get(model.names[bone])
            if spec is None or not spec.limits_direction:
                continue
            parent = model.parents[bone]
            if parent < 0:
                continue  # no parent frame to measure against
            rest_frame = axes[:, parent] @ spec.rest_in_parent  # (F,3,3): rest axes carried by the parent
            own = np.einsum("fji,fj->fi", axes[:, bone], segs[:, i])  # the segment in the bone's own axes
            rest_dir = normalize(apply_matrix(rest_frame, own))
            p = rest_dir if i == 0 else segs[:, i - 1]
            hinge, held = _joint_limit(spec, p, segs[:, i], rest_dir, rest_frame)
            if held is not None:
                p = held if i == 0 else p  # joint 0: its parent direction is the held direction itself
                hinge = _held(p, held, rest_frame[..., 0])
            if i == 0:
                parent_direction = p
            limits = limits.with_hinge(i, *hinge, twist=0.0)
        if limits is not current.limits:
            out[limb_name] = LimbLimits(limits, parent_direction)
    return out


def _joint_limit(spec, p, start, rest_dir, rest_frame):
    """What stands for `spec` at one joint, given the parent directions p, the segment's start and rest
    directions (F,3) and its rest frame (F,3,3): ((axis (F,3), lo, hi), None) for a hinge, or (None, the
    direction (F,3) to hold the segment at)."""
    lock_x, lock_z = spec.locked[0], spec.locked[2]
    if lock_x and lock_z:
        return None, start
    if lock_x or lock_z:
        free = 2 if lock_x else 0
        axis = rest_frame[..., free]
        # Turned about the free axis alone, the segment keeps its rest component along that axis.
        if np.any(np.abs(dot(start, axis) - dot(rest_dir, axis)) > math.sin(_ON_PLANE)):
            return None, start
        return _ranged(p, rest_dir, axis, spec.ranges[free]), None
    x_range, z_range = spec.ranges[0], spec.ranges[2]
    admits_rest = [r is None or r[0] <= 0.0 <= r[1] for r in (x_range, z_range)]
    candidates = [k for k, r, other_ok in ((0, x_range, admits_rest[1]), (2, z_range, admits_rest[0]))
                  if r is not None and other_ok]
    if candidates:
        k = max(candidates, key=lambda k: spec.ranges[k][1] - spec.ranges[k][0])
        return _ranged(p, rest_dir, rest_frame[..., k], spec.ranges[k]), None
    # Neither range holds the rest: the corner of both ranges nearest the rest (Euler XYZ: X turns first).
    x, z = (min(max(0.0, r[0]), r[1]) for r in (x_range, z_range))
    turned = rotate_about_axis(rest_dir, rest_frame[..., 0], x)
    return None, rotate_about_axis(turned, rest_frame[..., 2], z)


def _perpendicular_axis(axis, p):
    """Unit `axis` made perpendicular to the unit parent direction p (any perpendicular where it lies along p)."""
    a = axis - dot(axis, p)[..., None] * p
    bad = ~(norm(a) > 1e-9)
    if any_set(bad):
        a = np.where(bad[..., None], any_perpendicular(p), a)
    return normalize(a)


def _bend(p, v, axis):
    """Signed bend angles (F,) of directions v about the unit hinge axis (perpendicular to p), from p."""
    return np.arctan2(dot(v, cross(axis, p)), dot(v, p))


def _held(p, direction, x_axis):
    """A hinge holding the segment at `direction` (F,3): the plane of p and the direction, its axis signed
    to agree with the rest X axis (that axis where the direction lies along p), bend range their span."""
    reference = _perpendicular_axis(x_axis, p)
    axis = cross(p, direction)
    straight = ~(norm(axis) > 1e-9)
    axis = normalize(np.where(straight[..., None], reference, axis))
    axis = np.where((dot(axis, reference) < 0.0)[..., None], -axis, axis)
    bend = _bend(p, direction, axis)
    return axis, float(bend.min()), float(bend.max())


def _ranged(p, rest_dir, rest_axis, rng):
    """A hinge about the rest axis (made perpendicular to p) with range `rng` (or the whole circle for None).
    Each bound is the bend at which the hinge's plane meets the directions the rest direction reaches by
    turning exactly that far about the rest axis: where the axis is not quite perpendicular to p (a rig's
    roll a few degrees off) the bounds still hold exactly as the rig measures them."""
    axis = _perpendicular_axis(rest_axis, p)
    if rng is None:
        return axis, -math.pi, math.pi
    rest_axis = normalize(rest_axis)
    toward = cross(rest_axis, rest_dir)  # where a right-handed turn about the rest axis takes the rest direction
    side = cross(axis, p)
    rest_bend = _bend(p, rest_dir, axis)
    bounds = []
    for angle in rng:
        # Directions turned by `angle` from the rest lie in the plane normal to n; its bend on the hinge plane:
        n = math.cos(angle) * toward - math.sin(angle) * rest_dir
        meet = np.arctan2(-dot(p, n), dot(side, n))
        # Of the two opposite meeting bends, the one nearer the rest bend shifted by the angle.
        off = np.remainder(meet - (rest_bend + angle) + math.pi / 2, math.pi) - math.pi / 2
        bounds.append(float(np.mean(rest_bend + angle + off)))
    lo, hi = (min(max(b, -math.pi), math.pi) for b in bounds)
    return axis, min(lo, hi), max(lo, hi)
