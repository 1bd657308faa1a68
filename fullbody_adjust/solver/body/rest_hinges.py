"""Elbows and knees bend in the plane their joints show at rest, not about an axis the bone's roll happens to give.

The default hinge of an elbow or knee whose start pose is (nearly) straight needs an axis the start pose cannot
give (human.LimitStart). A bone's X axis is that axis on rigs whose rolls were set for it (Rigify's shins turn
about their X axes; its forearms about an X axis 11.6 degrees off the arm's rest plane), but an importer sets
rolls as it likes (glTF, FBX with automatic bone orientation off), and a far reach about such an axis swings the
knees sideways into an X. So the axis is found at REST from joint positions (bone heads, never tails) and the
body's facing at rest:

  - the limb's rest bend plane where it is bent at rest: clearly (more than HumanLimits.bent), or slightly (more
    than REST_BENT, about 5 degrees) in a plane within 60 degrees of the facing rule below, which then gives the
    bend side;
  - else the facing rule: elbows bend forward, knees backward (axis = upper segment x bend side), with up = hips ->
    shoulders (the arms' bases) and forward where the toes point across up, else square across the hip line
    (left = right hip -> left hip): solver/body/facing.py, the facing the bone mapping and the retarget read too.

The axis is kept in the rest frame of the limb's upper bone (upper arm, thigh), which carries it into a pose as
an elbow's or knee's axis rides on the humerus or femur: a forearm turned about its own length (pronation, often
keyed on the forearm bone) does not turn the elbow's plane, an upper arm turned about its length does. The
caller passes the carried axes where the solver takes bone X axes (adjust_frames' bone_x_axes, the rows of the
forearms and shins).
"""

import numpy as np

from ..limits.human import HumanLimits
from .facing import skeleton_facing
from ..maths.geometry import any_perpendicular, cross, dot, norm, normalize

_UP = np.array([0.0, 0.0, 1.0])
# A rest bend below this (radians, about 5 degrees) is modelling noise: GDQuest's mannequin rests its knees bent 4
# degrees in planes 15 degrees off its hips' facing, and bending them there swings the knees 16 mm sideways.
REST_BENT = 0.09
_HINGED = (("arm.L", 1.0), ("arm.R", 1.0), ("leg.L", -1.0), ("leg.R", -1.0))  # limb, bend side along forward


def rest_facing(model, heads):
    """Unit (up, left, forward) of a rest pose from its joints: heads (J,3) (see the module docstring): up = hips ->
    shoulders, forward across it as facing.skeleton_facing reads the legs (the map's left leg on the left), left =
    up x forward."""
    hips = heads[[model.groups["leg.L"][0], model.groups["leg.R"][0]]]
    shoulders = heads[model.groups["arm.L"][0]], heads[model.groups["arm.R"][0]]
    up = normalize(0.5 * (shoulders[0] + shoulders[1]) - 0.5 * (hips[0] + hips[1]),
                   fallback=np.array([0.0, 0.0, 1.0]))
    feet = [model.groups["foot.L"][0], model.groups["foot.R"][0]]
    below = [heads[_below(model, foot)] for foot in feet]
    tiny = 1e-6 * max(float(np.linalg.norm(hips - heads[feet], axis=1).max()), 1e-300)
    forward = skeleton_facing(up, hips, heads[feet], below, tiny, left=0).forward
    if forward is None:  # the hips coincide across up and no toe is ahead of an ankle
        forward = cross(any_perpendicular(up), up)
    return up, cross(up, forward), forward


def _below(model, bone):
    """The bones below ``bone`` (model.order lists every parent before its children)."""
    inside = {bone}
    for j in model.order.tolist():
        if int(model.parents[j]) in inside:
            inside.add(j)
    return sorted(inside - {bone})


def rest_hinge_axis(upper, lower, bend_side, bent):
    """Unit hinge axes (k,3) of joints between segments upper -> lower (k,3) at rest (module docstring), with
    bend_side (k,3) the direction each limb bends toward."""
    u = normalize(upper, fallback=_UP)
    rule = cross(u, normalize(bend_side, fallback=_UP))
    rule = np.where((norm(rule) >= 0.3)[:, None], normalize(rule, fallback=_UP), any_perpendicular(u))
    v = normalize(lower, fallback=_UP)
    bend = cross(u, v)
    angle = np.arctan2(norm(bend), dot(u, v))
    plane = normalize(bend, fallback=rule)
    agree = dot(plane, rule)
    slight = (angle > REST_BENT) & (np.abs(agree) >= 0.5)
    axis = np.where(slight[:, None], np.where((agree < 0.0)[:, None], -plane, plane), rule)
    return np.where((angle > bent)[:, None], plane, axis)


def rest_hinge_axes(model, heads, rotations, bent=HumanLimits().bent):
    """The elbows' and knees' rest hinge axes: (bones (k,), carriers (k,), axes (k,3)): the hinge's lower bone
    (forearm, shin: the row of bone_x_axes the solver reads), its upper bone (upper arm, thigh) that carries the
    axis, and the axis in the carrier's own rest frame. heads (J,3) and rotations (J,3,3) (the bones' axes as
    columns, any scale) at rest, in one space; ``bent``: as HumanLimits.bent."""
    heads = np.asarray(heads, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    _up, _left, forward = rest_facing(model, heads)
    limbs = [(model.limbs[name], side) for name, side in _HINGED if len(model.limbs[name].bones) >= 2]
    # Heads only, but for an arm without a hand bone, whose wrist is its forearm's end: along the forearm's Y axis.
    tails = heads + rotations[:, :, 1]
    joints = np.array([limb.joints(heads, tails)[-3:] for limb, _side in limbs])
    sides = np.array([side * forward for _limb, side in limbs])
    axes = rest_hinge_axis(joints[:, 1] - joints[:, 0], joints[:, 2] - joints[:, 1], sides, bent)
    bones = np.array([limb.bones[-1] for limb, _side in limbs], dtype=np.int64)
    carriers = np.array([limb.bones[-2] for limb, _side in limbs], dtype=np.int64)
    frames = rotations[carriers]
    frames = frames / norm(np.swapaxes(frames, -1, -2))[:, None, :]  # unit columns
    return bones, carriers, np.einsum("kji,kj->ki", frames, axes).reshape(-1, 3)
