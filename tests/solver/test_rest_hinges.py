"""Elbow and knee hinge axes from the rest pose's joints and the body's facing (solver/body/rest_hinges.py), not from
bone roll: they agree with the Rigify metarig's own X axes, ignore any roll, turn with the body, and on a far
reach keep straight-legged knees from swinging sideways where arbitrary X axes swing them. Expectations are
computed here from the joints."""

import math

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody.adjust import adjust_pose
from fullbody_adjust.solver.limits.human import HumanLimits
from fullbody_adjust.solver.body.rest_hinges import REST_BENT, rest_facing, rest_hinge_axes
from tests.helpers import metarig
from tests.helpers.rotations import about_axis

LIMBS = ("arm.L", "arm.R", "leg.L", "leg.R")


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _world_axes(model, heads, rotations):
    """{limb: the rest hinge axis in the rest space} (rest_hinge_axes carried by its carriers' rest rotations)."""
    bones, carriers, local = rest_hinge_axes(model, heads, rotations)
    by_bone = {int(b): rotations[c] @ a for b, c, a in zip(bones, carriers, local)}
    return {name: by_bone[model.limbs[name].bones[-1]] for name in LIMBS}


def _eyes(model):
    return np.broadcast_to(np.eye(3), (len(model.names), 3, 3))


def _straightened(model, heads, tails):
    """Every elbow and knee turned straight (the forearm/shin and everything below it swung onto the upper
    segment's direction about the elbow/knee)."""
    heads, tails = heads.copy(), tails.copy()
    for name in LIMBS:
        limb = model.limbs[name]
        joints = limb.joints(heads, tails)
        u, v = joints[-2] - joints[-3], joints[-1] - joints[-2]
        axis = np.cross(v, u)
        turn = about_axis(axis, math.atan2(np.linalg.norm(axis), u @ v))
        below = {limb.bones[-1]}
        for j in model.order.tolist():
            if model.parents[j] in below:
                below.add(j)
        below = sorted(below)
        pivot = joints[-2].copy()
        heads[below] = (heads[below] - pivot) @ turn.T + pivot
        tails[below] = (tails[below] - pivot) @ turn.T + pivot
    return heads, tails


def test_the_metarigs_x_axes_are_its_rest_hinge_axes(rig):
    """Rigify's forearms and shins bend about their X axes: the rest axes agree with them, the shins' exactly,
    the forearms' within the 11.6 degrees their roll sits off the arm's rest plane."""
    model, h, t, x = rig
    axes = _world_axes(model, h, _eyes(model))
    for name in LIMBS:
        limb = model.limbs[name]
        joints = limb.joints(h, t)
        u = _unit(joints[-2] - joints[-3])
        bone_x = x[limb.bones[-1]] - (x[limb.bones[-1]] @ u) * u
        angle = math.degrees(math.acos(np.clip(_unit(bone_x) @ axes[name], -1.0, 1.0)))
        assert angle < (1e-6 if name.startswith("leg") else 11.7), (name, angle)
        # The rest plane itself (the metarig is bent at rest), the bend positive about it.
        bend = np.cross(joints[-2] - joints[-3], joints[-1] - joints[-2])
        np.testing.assert_allclose(axes[name], _unit(bend), atol=1e-12)


def test_the_axes_ignore_roll_and_turn_with_the_body(rig):
    """Any rotations of the bones (rolls, an importer's axes) leave the rest axis in space as it is; the whole
    rest pose turned to face -X, +X or +Y turns the axes with it."""
    model, h, t, _x = rig
    at_rest = _world_axes(model, h, _eyes(model))
    rng = np.random.default_rng(7)
    rolled = np.array([about_axis(rng.normal(size=3), rng.uniform(-math.pi, math.pi)) for _ in model.names])
    for name, axis in _world_axes(model, h, rolled).items():
        np.testing.assert_allclose(axis, at_rest[name], atol=1e-12)
    for angle in (math.pi / 2, -math.pi / 2, math.pi):
        turn = about_axis([0.0, 0.0, 1.0], angle)
        turned = _world_axes(model, (h + [0.3, -0.2, 0.0]) @ turn.T, rolled)
        for name in LIMBS:
            np.testing.assert_allclose(turned[name], turn @ at_rest[name], atol=1e-12)


def test_straight_limbs_take_the_facing_rule(rig):
    """Straight at rest, elbows bend forward and knees backward: axis = upper segment x bend side."""
    model, h, t, _x = rig
    heads, tails = _straightened(model, h, t)
    _up, left, forward = rest_facing(model, heads)
    assert forward @ np.array([0.0, -1.0, 0.0]) > 0.95  # the metarig faces -Y
    axes = _world_axes(model, heads, _eyes(model))
    for name in LIMBS:
        joints = model.limbs[name].joints(heads, tails)
        side = forward if name.startswith("arm") else -forward
        expected = _unit(np.cross(joints[-2] - joints[-3], side))
        np.testing.assert_allclose(axes[name], expected, atol=1e-9)


def test_a_slight_rest_bend_gives_its_plane_only_near_the_facing_rule(rig):
    """A knee bent 1.5 REST_BENT at rest (still below HumanLimits.bent) in the rule's plane (backward) gives that
    plane; bent as much sideways, the facing rule; bent less than REST_BENT, the rule too. The rule is the bent
    rest pose's own: its foot's toes turned with the shin turn the facing (solver/body/facing.py) a little."""
    model, h, t, _x = rig
    heads, tails = _straightened(model, h, t)
    _up, left, forward = rest_facing(model, heads)
    leg = model.limbs["leg.L"]
    thigh = leg.joints(heads, tails)[1] - leg.joints(heads, tails)[0]
    rule = _unit(np.cross(thigh, -forward))
    assert 1.5 * REST_BENT < HumanLimits().bent
    for about, angle, plane in ((rule, 1.5 * REST_BENT, rule), (_unit(np.cross(thigh, rule)), 1.5 * REST_BENT, None),
                                (rule, 0.5 * REST_BENT, None)):
        bent_heads, bent_tails = heads.copy(), tails.copy()
        below = [leg.bones[-1]] + [j for j in range(len(model.names)) if j != leg.bones[-1]
                                   and _descends(model, j, leg.bones[-1])]
        pivot = heads[leg.bones[-1]].copy()
        turn = about_axis(about, angle)
        bent_heads[below] = (heads[below] - pivot) @ turn.T + pivot
        bent_tails[below] = (tails[below] - pivot) @ turn.T + pivot
        got = _world_axes(model, bent_heads, _eyes(model))["leg.L"]
        expected = plane if plane is not None else _unit(np.cross(thigh, -rest_facing(model, bent_heads)[2]))
        np.testing.assert_allclose(got, expected, atol=1e-9)


def _descends(model, j, ancestor):
    while j >= 0:
        j = model.parents[j]
        if j == ancestor:
            return True
    return False


def test_a_far_reach_bends_straight_knees_in_their_plane(rig):
    """Straight arms and legs, every bone's X axis rolled at random, a hand target low in front of the feet (the
    pelvis must come down, so the knees bend): with the rest axes each knee moves along the hips' line by less
    than 1 cm; about the rolled X axes (as an importer leaves them) they swing sideways by more."""
    model, h, t, _x = rig
    heads, tails = _straightened(model, h, t)
    rng = np.random.default_rng(3)
    rolled_x = np.array([about_axis(tails[j] - heads[j], rng.uniform(0.5, 2.5)) @ _unit(
        np.cross(tails[j] - heads[j], [0.0, 0.0, 1.0]) + [0.0, 0.0, 1e-3]) for j in range(len(model.names))])
    hints = rolled_x.copy()
    bones, carriers, local = rest_hinge_axes(model, heads, _eyes(model))  # the rest is the start: nothing turned
    hints[bones] = local
    targets = metarig.wrists_and_ankles(model, heads)
    _up, left, forward = rest_facing(model, heads)
    arm = model.limbs["arm.L"].joints(heads, tails)
    reach = np.linalg.norm(np.diff(arm, axis=0), axis=1).sum()
    feet = 0.5 * (targets[2] + targets[3])
    targets[0] = feet + 0.4 * reach * forward + 0.1 * reach * _up
    targets[1] = np.nan
    sideways = {}
    for label, axes in (("rest", hints), ("rolled", rolled_x)):
        res = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=axes)
        assert res.status[0] == "reached" and res.root_displacement > 0.1 * reach
        sideways[label] = [abs((res.heads[k] - heads[k]) @ left) for k in
                           (model.limbs["leg.L"].bones[-1], model.limbs["leg.R"].bones[-1])]
    assert max(sideways["rest"]) < 0.01, sideways
    assert max(sideways["rolled"]) > 0.02, sideways
