"""The body's default joint limits: HumanLimits, ranges measured on captured human motion, and default_limits,
which makes each limb's LimbLimits from them at the start poses (hinge axes from the start bend, the rest pose's
axes or the body frame; every range widened to hold the start pose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec
from ..errors import SolverInputError
from ..maths.geometry import all_set, apply_matrix, dot, norm, normalize
from ..body.model import BodyModel
from .joint_limits import CONE, HINGE, JointLimits
from .start_range import widened_ranges

# A slight start bend (up to HumanLimits.bent) keeps its own plane only within this cosine (10 degrees) of the given
# or body-frame axis: further off it is more likely noise on a nearly straight limb than the plane the limb bends
# in, and the hinge's twist range holds such a start anyway (45 degrees for knees, 80 for elbows).
SLIGHT_AGREES = math.cos(math.radians(10.0))


@dataclass(frozen=True)
class HumanLimits:
    """Default joint limits, radians. Cones bound the angle between a segment and its parent direction, hinges
    bound the signed bend about the joint's axis (positive = the limb's natural bend side).

    Chosen to hold every captured pose of the five shared CMU clips (99.9th percentile of the measured angle,
    plus a margin) so a captured start pose is never pushed by its own limits:
      lumbar  trunk segment 0 vs the pelvis' up direction     measured <= 49 deg  -> 55
      spine   between consecutive trunk segments             measured <= 30 deg  -> 35
      clavicle swing from its start direction (rides on chest)                    -> 30
      shoulder upper arm vs clavicle                          measured <= 128 deg -> 135
      elbow   hinge, never bends backwards (small hyperextension allowed)         -> [-0.2, 2.7] rad
      hip     thigh vs the pelvis' down direction             measured <= 108 deg -> 115
      knee    hinge                                           measured <= 159 deg -> [-0.2, 2.85] rad
      neck    each neck segment (vs its start direction / the one below)  measured <= 45 deg -> 50
    Hinge twists: how far the elbow's / knee's bend plane may turn about the upper arm / thigh (humeral and
    femoral rotation) from the start plane carried by that segment's minimal swing (limits/joint_limits.py, hinge twist).
    Measured from each pose of a pair to the other (pairs 60 frames apart, and random pairs, in the same
    clips), captured limb bent by more than 0.5 rad. A twist must stay below 90 deg (beyond it a bend plane
    is the same plane bent the other way), which about 3 % of the pairs would need (the dance's turned-out
    legs, arms swung past 90 deg, where the swing frame itself has turned):
      elbow_twist  upper arm: 95th percentile 69-80 deg, 95-96 % of pairs within 80 deg     -> 80
      knee_twist   thigh:     95th percentile 39-49 deg, 94-95 % of pairs within 45 deg     -> 45
    """

    lumbar: float = math.radians(55)
    spine: float = math.radians(35)
    clavicle: float = math.radians(30)
    shoulder: float = math.radians(135)
    elbow: tuple = (-0.2, 2.7)
    hip: float = math.radians(115)
    knee: tuple = (-0.2, 2.85)
    neck: float = math.radians(50)
    elbow_twist: float = math.radians(80)
    knee_twist: float = math.radians(45)
    # A start bend above this (radians) defines the hinge plane and its positive side; below it the bend side
    # is ambiguous (mocap noise on a straight limb), so the given hinge axis (bone_x_axes) or the body-frame
    # heuristic decides the side. Kept below -elbow[0] and -knee[0] so a start pose is never outside its own
    # hinge range.
    bent: float = 0.15


@dataclass(frozen=True)
class LimbLimits:
    """Joint limits of one limb for F start poses, plus the direction joint 0 is limited against, at the start
    pose (F,3) (None when joint 0 is free). The solver carries both with the limb's parent rotation."""

    limits: JointLimits
    parent_direction: np.ndarray | None

    def for_chains(self, chains, frames, carry=None):
        """(JointLimits, joint 0's parent directions (b,3) or None) for the chain solves of frames ``frames``
        (b,) whose start chains are ``chains`` (b,n,3). The hinge axes of joints > 0 stay in the start pose's
        frame: each is referenced to its start parent direction, from which the solver carries it by the
        parent's minimal swing, as limb_rotations turns the bones, so the elbow or knee written out is the hinge
        the solver enforced. Joint 0's hinge axis and parent direction ride on the limb's parent: turned by
        ``carry`` (b,3,3), its rotation since the start (None: not turned)."""
        lim = self.limits
        axes = lim.hinge_axis[frames] if lim.hinge_axis.ndim == 3 else \
            np.broadcast_to(lim.hinge_axis, (len(frames),) + lim.hinge_axis.shape).copy()
        pdir = None if self.parent_direction is None else self.parent_direction[frames]
        reference = chains[:, 1:] - chains[:, :-1]  # np.diff's differences, without its per-call cost
        reference = np.concatenate([reference[:, :1], reference[:, :-1]], axis=1)
        if carry is not None:
            axes[:, 0] = apply_matrix(carry, axes[:, 0])
            pdir = None if pdir is None else apply_matrix(carry, pdir)
        return lim.derived(hinge_axis=axes, hinge_reference=reference), pdir


def default_limits(model: BodyModel, heads, tails, human: HumanLimits = HumanLimits(), bone_x_axes=None):
    """Default human limits for every limb of `model` at the start poses heads/tails (F,J,3).

    bone_x_axes: optional per-bone axes in world space (J,3) or (F,J,3), read on the forearms' and shins' rows:
    the axis each elbow/knee bends about where the start pose is (nearly) straight and says nothing about the
    bend side. The bridge passes the axes found at rest (body/rest_hinges.py: rest joints and facing, never bone
    roll) carried into the start pose; a rig whose rolls were set for its hinges may pass its bones' X axes.
    Each range holds the start pose (limits/start_range.py). Returns {limb name: LimbLimits}."""
    start = LimitStart(model, heads, tails, bone_x_axes)
    return {limb.name: start.limb_limits(limb, human) for limb in model.limbs.values()}


class LimitStart:
    """What default_limits computes a limb's limits from at the start poses heads/tails (F,J,3): its joints,
    its bones' X axes, and the body frame every limb shares (forward, the pelvis' up direction, the SC)."""

    def __init__(self, model: BodyModel, heads, tails, bone_x_axes=None):
        heads = np.asarray(heads, dtype=np.float64)
        tails = np.asarray(tails, dtype=np.float64)
        self.heads, self.tails = heads, tails
        self.checked_ranges = model.memory.checked_ranges
        self.x_axes = None
        if bone_x_axes is not None:
            x_axes = np.asarray(bone_x_axes, dtype=np.float64)
            if x_axes.shape not in (heads.shape, heads.shape[1:]):
                raise SolverInputError(f"bone_x_axes must have shape {heads.shape[1:]} or {heads.shape}, got "
                                       f"{x_axes.shape}")
            self.x_axes = np.broadcast_to(x_axes, heads.shape)
            if not all_set(np.isfinite(self.x_axes)):
                raise SolverInputError("bone_x_axes have NaN/inf")
        _up, _left, self.forward = model.body_frame(heads, tails)
        # The pelvis never rotates during a solve, so its up direction is a fixed frame for the lumbar and hip
        # cones. The root bone points up in the common rigs (CMU/Blender import, Rigify, Mixamo); where it does
        # not (more than 60 deg from the lowest trunk segment) the lowest trunk segment stands in.
        trunk = model.limbs["trunk"].joints(heads, tails)
        lumbar_dir = normalize(trunk[:, 1] - trunk[:, 0])
        root = model.root
        root_dir = normalize(tails[:, root] - heads[:, root], fallback=lumbar_dir)
        self.pelvis_up = np.where((dot(root_dir, lumbar_dir) > math.cos(math.radians(60)))[:, None], root_dir,
                                  lumbar_dir)
        self.sc = trunk[:, -1]

    def inputs(self, limb):
        """Everything limb_limits(limb, ...) reads, as bytes: two limbs (of any model) with equal inputs and
        HumanLimits get equal limits, bit for bit."""
        joints = limb.joints(self.heads, self.tails)
        x = None if self.x_axes is None else self.x_axes[:, limb.bones[-1]].tobytes()
        return (limb.name, joints.shape, joints.tobytes(), x, self.forward.tobytes(), self.pelvis_up.tobytes(),
                self.sc.tobytes())

    def limb_limits(self, limb, human: HumanLimits = HumanLimits()):
        """The LimbLimits of one limb (see default_limits)."""
        joints = limb.joints(self.heads, self.tails)
        segs = joints[:, 1:] - joints[:, :-1]
        n_frames, m = segs.shape[:2]
        forward, pelvis_up = self.forward, self.pelvis_up
        kind = np.zeros(m, np.int64)
        cone = np.full(m, math.pi)
        lo = np.full(m, -math.pi)
        hi = np.full(m, math.pi)
        axes = np.zeros((n_frames, m, 3))
        axes[..., 2] = 1.0
        parent_dir = None

        def set_cone(i, angle):
            kind[i], cone[i] = CONE, angle

        twist = np.zeros(m)

        def set_hinge(i, bend_side, rng, child_bone, twist_range):
            kind[i], lo[i], hi[i], twist[i] = HINGE, rng[0], rng[1], twist_range
            x = None if self.x_axes is None else self.x_axes[:, child_bone]
            axes[:, i] = _hinge_axis(segs[:, i - 1], segs[:, i], bend_side, x, human.bent)

        if limb.name == "trunk":
            parent_dir = pelvis_up
            set_cone(0, human.lumbar)
            for i in range(1, m):
                set_cone(i, human.spine)
        elif limb.name.startswith("arm"):
            set_hinge(m - 1, forward, human.elbow, limb.bones[m - 1], human.elbow_twist)
            if m >= 3:
                # Clavicle(s): swing from the start direction, which rides on the chest.
                parent_dir = segs[:, 0]
                set_cone(0, human.clavicle)
                set_cone(m - 2, human.shoulder)
            else:
                # No clavicle: the SC -> shoulder direction plays its part for the shoulder cone.
                proxy = joints[:, 0] - self.sc
                if all_set(norm(proxy) > 1e-9 * norm(segs[:, 0])):
                    parent_dir = proxy
                    set_cone(0, human.shoulder)
        elif limb.name.startswith("leg"):
            parent_dir = -pelvis_up
            set_cone(0, human.hip)
            set_hinge(m - 1, -forward, human.knee, limb.bones[m - 1], human.knee_twist)
        else:  # head: neck segments swing from their start direction on the chest
            parent_dir = segs[:, 0]
            for i in range(m):
                set_cone(i, human.neck)
        parent_dir = None if parent_dir is None else normalize(parent_dir)
        # A start pose outside these ranges is the rig's own range there (start_range): widened to hold it.
        # the HumanLimits as given must be valid
        limits = _checked_ranges(self.checked_ranges, kind, cone, lo, hi, twist)
        wide = widened_ranges(kind, cone, lo, hi, axes, parent_dir, segs)
        if any(w is not given for w, given in zip(wide, (cone, lo, hi))):
            limits = _checked_ranges(self.checked_ranges, kind, *wide, twist)
        limits = limits.derived(hinge_axis=axes)
        return LimbLimits(limits, parent_dir)


# JointLimits' checks of a limb's kinds and ranges (cone angles, hinge ranges and twists: the HumanLimits it was
# given), done once per such set and model (SolveMemory.checked_ranges): Adjust Pose builds every moved limb's
# limits again on every click, and the checks cost as much as the rest of limb_limits. The hinge axes need none:
# _hinge_axis returns unit vectors.
_CHECKED_CAPACITY = 64


def _checked_ranges(checked_ranges, kind, cone, lo, hi, twist):
    """A validated JointLimits with these per-joint arrays (hinge axes: placeholders for derived()), kept in
    the dict ``checked_ranges``."""
    key = tuple(a.tobytes() for a in (kind, cone, lo, hi, twist))
    checked = checked_ranges.get(key)
    if checked is None:
        checked = JointLimits(kind, cone, np.tile([0.0, 0.0, 1.0], (kind.shape[0], 1)), lo, hi, twist)
        if len(checked_ranges) >= _CHECKED_CAPACITY:
            checked_ranges.clear()
        checked_ranges[key] = checked
    return checked


def _hinge_axis(parent_seg, child_seg, bend_side, x_axis, bent_angle):
    """Hinge axes (F,3) at the start pose, oriented so the natural bend is positive (_hinge_axis_lanes)."""
    return lanes.run(_hinge_axis_lanes, (parent_seg, child_seg, bend_side, x_axis), bent_angle)


def _hinge_axis_lanes(parent_seg, child_seg, bend_side, x_axis, bent_angle):
    """The hinge axis on components (maths/lanes.py).

    A clearly bent start pose defines the hinge plane (axis = parent x child); a nearly straight one takes
    the bone's X axis (if given; sign matched to the heuristic) or the body-frame heuristic
    axis = parent x bend_side (elbows bend forward, knees backward)."""
    u = vec.normalize(parent_seg)
    heuristic = vec.cross(u, vec.normalize(bend_side))
    weak = vec.norm(heuristic) < 0.3  # limb nearly along the bend side: fall back to any perpendicular
    if lanes.any_(weak):
        heuristic = lanes.pick(weak, vec.any_perpendicular(u), heuristic)
    axis = vec.normalize(heuristic)
    if x_axis is not None:
        x = vec.sub(x_axis, vec.scaled(u, vec.dot(x_axis, u)))
        ok = vec.norm(x) > 1e-6
        x = vec.normalize(lanes.pick(ok, x, axis))
        x = lanes.pick(vec.dot(x, axis) < 0.0, vec.neg(x), x)
        axis = lanes.pick(ok, x, axis)
    # A clearly bent start pose is on the natural side (nobody hyperextends an elbow by 15 deg), so it wins.
    # A slightly bent (or slightly hyperextended) one still defines a plane: kept, signed to the natural side,
    # when it is within 10 deg of the fallback axis (SLIGHT_AGREES), so the start pose lies exactly on its own
    # hinge; further off, the fallback axis, whose twist range holds such a start (a nearly straight knee bent
    # 4 deg in a plane 15 deg off its body's is noise, not the plane it bends in).
    v = vec.normalize(child_seg)
    bend = vec.cross(u, v)
    angle = lanes.arctan2(vec.norm(bend), vec.dot(u, v))
    bend_axis = vec.normalize(bend, fallback=axis)
    agree = vec.dot(bend_axis, axis)
    slight = (angle > 1e-3) & (abs(agree) >= SLIGHT_AGREES)
    signed = lanes.pick(agree < 0.0, vec.neg(bend_axis), bend_axis)
    axis = lanes.pick(slight, signed, axis)
    return vec.normalize(lanes.pick(angle > bent_angle, bend_axis, axis))
