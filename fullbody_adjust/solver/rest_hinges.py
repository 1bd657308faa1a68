"""Elbows and knees bend in the plane their joints show at rest, not about an axis the bone's roll happens to give.

The default hinge of an elbow or knee whose start pose is (nearly) straight needs an axis the start pose cannot
give (body.LimitStart). A bone's X axis is that axis on rigs whose rolls were set for it (Rigify's shins turn
about their X axes; its forearms about an X axis 11.6 degrees off the arm's rest plane), but an importer sets
rolls as it likes (glTF, FBX with automatic bone orientation off), and a far reach about such an axis swings the
knees sideways into an X. So the axis is found at REST from joint positions (bone heads, never tails) and the
body's facing at rest:

  - the limb's rest bend plane where it is bent at rest: clearly (more than HumanLimits.bent), or slightly (more
    than REST_BENT) in a plane within 60 degrees of the facing rule below, which then gives the bend side;
  - else the facing rule: elbows bend forward, knees backward (axis = upper segment x bend side), with forward
    = left x up, left = right hip -> left hip, up = hips -> shoulders (the arms' bases), as body.body_frame.

The axis is kept in the rest frame of the limb's upper bone (upper arm, thigh), which carries it into a pose as
an elbow's or knee's axis rides on the humerus or femur: a forearm turned about its own length (pronation, often
keyed on the forearm bone) does not turn the elbow's plane, an upper arm turned about its length does. The
caller passes the carried axes where the solver takes bone X axes (adjust_frames' bone_x_axes, the rows of the
forearms and shins).
"""

import math

import numpy as np

from .body import HumanLimits
from .geometry import any_perpendicular, cross, dot, norm, normalize

# A rest bend below this (radians, about 3 degrees) is modelling noise unless it lies near the facing rule's plane.
REST_BENT = 0.05
_HINGED = (("arm.L", 1.0), ("arm.R", 1.0), ("leg.L", -1.0), ("leg.R", -1.0))  # limb, bend side along forward


def rest_facing(model, heads):
    """Unit (up, left, forward) of a rest pose from its joints: heads (J,3) (see the module docstring)."""
    hips = heads[model.groups["leg.L"][0]], heads[model.groups["leg.R"][0]]
    shoulders = heads[model.groups["arm.L"][0]], heads[model.groups["arm.R"][0]]
    up = normalize(0.5 * (shoulders[0] + shoulders[1]) - 0.5 * (hips[0] + hips[1]),
                   fallback=np.array([0.0, 0.0, 1.0]))
    left = hips[0] - hips[1]
    left = normalize(left - dot(left, up) * up, fallback=any_perpendicular(up))
    return up, left, cross(left, up)


def rest_hinge_axis(upper, lower, bend_side, bent):
    """The unit hinge axis (3,) of a joint between segments upper -> lower (3,) at rest (module docstring), with
    bend_side the direction the limb bends toward."""
    u = normalize(upper)
    rule = cross(u, normalize(bend_side))
    rule = normalize(rule) if norm(rule) >= 0.3 else any_perpendicular(u)
    v = normalize(lower)
    bend = cross(u, v)
    angle = math.atan2(norm(bend), dot(u, v))
    if angle <= REST_BENT:
        return rule
    plane = normalize(bend)
    agree = dot(plane, rule)
    if angle > bent:
        return plane
    if abs(agree) >= 0.5:
        return plane if agree >= 0.0 else -plane
    return rule


def rest_hinge_axes(model, heads, rotations, bent=HumanLimits().bent):
    """The elbows' and knees' rest hinge axes: (bones (k,), carriers (k,), axes (k,3)): the hinge's lower bone
    (forearm, shin: the row of bone_x_axes the solver reads), its upper bone (upper arm, thigh) that carries the
    axis, and the axis in the carrier's own rest frame. heads (J,3) and rotations (J,3,3) (the bones' axes as
    columns, any scale) at rest, in one space; ``bent``: as HumanLimits.bent."""
    heads = np.asarray(heads, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    _up, _left, forward = rest_facing(model, heads)
    bones, carriers, axes = [], [], []
    for name, side in _HINGED:
        limb = model.limbs[name]
        if len(limb.bones) < 2:
            continue
        joints = limb.joints(heads, heads)  # arms and legs end at the hand's / foot's head: heads only
        axis = rest_hinge_axis(joints[-2] - joints[-3], joints[-1] - joints[-2], side * forward, bent)
        carrier = limb.bones[-2]
        frame = rotations[carrier] / norm(rotations[carrier].T)  # unit columns
        bones.append(limb.bones[-1])
        carriers.append(carrier)
        axes.append(frame.T @ axis)
    return np.array(bones, dtype=np.int64), np.array(carriers, dtype=np.int64), np.array(axes).reshape(-1, 3)
