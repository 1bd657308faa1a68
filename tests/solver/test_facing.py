"""Where a skeleton faces at rest (solver/body/facing.py), the one calculation the bone mapping's sides, the retarget's
heading and the rest hinges read: two legs built here (hips, knees, ankles, a toe joint below each ankle) facing
-Y, then turned, their hips yawed, their toes or knees taken away; every expectation is the turn applied to -Y or
the direction computed here from the joints."""

import math

import numpy as np
import pytest

from fullbody_adjust.bone_mapping import body_sides, map_rig
from fullbody_adjust.solver.body.model import BodyModel
from fullbody_adjust.solver.body.facing import UP, skeleton_facing
from fullbody_adjust.solver.body.rest_hinges import rest_facing
from tests.test_mapping_rules import NAMED_RIGS
from tests.test_mapping_sides import turned

TINY = 1e-9


def _turn(degrees):
    a = math.radians(degrees)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _legs(yaw=0.0, toes=True, knee_bend=0.02):
    """Leg 0 on the left (+X) of a body facing -Y, all turned by ``yaw`` degrees about z: hips, knees (bent
    forward by ``knee_bend``), ankles, the joints below each ankle (a toe 0.15 ahead, or none), foot bones
    pointing ahead."""
    x = np.array([0.1, -0.1])
    hips = np.stack([x, [0.0, 0.0], [0.9, 0.9]], axis=1)
    knees = np.stack([x, [-knee_bend] * 2, [0.5, 0.5]], axis=1)
    ankles = np.stack([x, [0.0, 0.0], [0.1, 0.1]], axis=1)
    below = [a + [0.0, -0.15, -0.05] for a in ankles] if toes else [np.zeros((0, 3))] * 2
    feet = [np.array([0.0, -0.1, -0.05])] * 2
    turn = _turn(yaw)
    return (hips @ turn.T, knees @ turn.T, ankles @ turn.T, [np.reshape(b, (-1, 3)) @ turn.T for b in below],
            [turn @ f for f in feet])


@pytest.mark.parametrize("yaw", [0.0, 90.0, 180.0, -90.0, 37.0])
def test_the_joints_say_where_the_body_faces_whatever_its_turn(yaw):
    hips, knees, ankles, below, feet = _legs(yaw)
    expected = _turn(yaw) @ [0.0, -1.0, 0.0]
    found = skeleton_facing(UP, hips, ankles, below, TINY, knees=knees, feet=feet)
    assert found.clear and found.sign == -1  # leg 0 on the left: left = up x forward = -(up x lateral)
    np.testing.assert_allclose(found.forward, expected, atol=1e-12)
    np.testing.assert_allclose(found.sign * np.cross(UP, found.lateral), expected, atol=1e-12)
    # The legs named the other way round (leg 1 first): the same forward, the other sign.
    swapped = skeleton_facing(UP, hips[::-1], ankles[::-1], below[::-1], TINY, knees=knees[::-1], feet=feet[::-1])
    assert swapped.sign == 1
    np.testing.assert_allclose(swapped.forward, expected, atol=1e-12)


def test_yawed_hips_face_where_the_toes_point():
    """The hip joints turned 13 degrees about their centre (GDQuest's mannequin): forward is still the toes'."""
    hips, knees, ankles, below, feet = _legs()
    centre = hips.mean(axis=0)
    hips = (hips - centre) @ _turn(13.0).T + centre
    found = skeleton_facing(UP, hips, ankles, below, TINY, left=0)
    np.testing.assert_allclose(found.forward, [0.0, -1.0, 0.0], atol=1e-12)
    # Without toes: square across the hip line, on the side the known left says.
    square = skeleton_facing(UP, hips, ankles, [np.zeros((0, 3))] * 2, TINY, left=0).forward
    np.testing.assert_allclose(square, _turn(13.0) @ [0.0, -1.0, 0.0], atol=1e-12)
    mirrored = skeleton_facing(UP, hips, ankles, [np.zeros((0, 3))] * 2, TINY, left=1).forward
    np.testing.assert_allclose(mirrored, -square, atol=1e-12)


def test_toes_far_off_the_hips_do_not_turn_the_forward():
    """Toes pointing 70 degrees off square across the hips (feet turned out sideways): the hips decide."""
    hips, knees, ankles, below, feet = _legs()
    below = [ankles[k] + _turn(70.0) @ [0.0, -0.15, -0.05] for k in (0, 1)]
    found = skeleton_facing(UP, hips, ankles, below, TINY, left=0)
    np.testing.assert_allclose(found.forward, [0.0, -1.0, 0.0], atol=1e-12)


def test_without_toes_knees_and_foot_bones_decide_and_without_them_nothing_does():
    hips, knees, ankles, _below, feet = _legs(toes=False)
    none = [np.zeros((0, 3))] * 2
    found = skeleton_facing(UP, hips, ankles, none, TINY, knees=knees, feet=feet)
    assert (found.sign, found.clear) == (-1, True)
    np.testing.assert_allclose(found.forward, [0.0, -1.0, 0.0], atol=1e-12)
    straight = skeleton_facing(UP, hips, ankles, none, TINY, knees=0.5 * (hips + ankles), feet=[None, None])
    assert (straight.sign, straight.clear, straight.forward) == (0, False, None)


def test_forward_lies_across_a_tilted_up():
    """The rest hinges' up (hips -> shoulders) tilted 20 degrees forward: forward is perpendicular to it."""
    hips, knees, ankles, below, feet = _legs()
    a = math.radians(20.0)
    up = np.array([0.0, -math.sin(a), math.cos(a)])
    found = skeleton_facing(up, hips, ankles, below, TINY, left=0)
    assert abs(found.forward @ up) < 1e-12
    expected = np.array([0.0, -1.0, 0.0]) - math.sin(a) * up  # -Y across up, made unit
    np.testing.assert_allclose(found.forward, expected / np.linalg.norm(expected), atol=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 90.0, 200.0])
@pytest.mark.parametrize("kind", ["mixamo", "ue4", "genesis8"])
def test_the_mapping_and_the_rest_hinges_read_the_same_facing(kind, yaw):
    """A named rig turned by ``yaw``: the side body_sides reads (its sign across the hips) and rest_facing's
    forward (its up being the body's, not z) agree on where the body faces, within the spine's lean."""
    desc = turned(NAMED_RIGS[kind][0](), yaw)
    bone_map = map_rig(desc)
    sk = desc._skeleton
    legs = [body_sides.Limb(tuple(desc.index(b) for b in bone_map.bones(f"leg.{s}")),
                            desc.index(bone_map.bones(f"foot.{s}")[0])) for s in "LR"]
    lat = body_sides.lateral(sk, *legs)
    sign, clear = body_sides.facing(sk, legs)
    mapped = sign * np.cross(UP, lat)
    model = BodyModel.from_description(desc.names, desc.parents, dict(bone_map.groups))
    _up, _left, forward = rest_facing(model, sk.heads)
    flat = forward * [1.0, 1.0, 0.0]
    expected = _turn(yaw) @ [0.0, -1.0, 0.0]
    assert clear
    np.testing.assert_allclose(mapped, expected, atol=1e-9)
    assert flat @ expected > math.cos(math.radians(5.0)) * np.linalg.norm(flat)
