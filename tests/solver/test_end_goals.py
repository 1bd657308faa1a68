"""The pieces behind a target's rotation and a pole: end_rotation (a hand or foot turned toward a wanted
orientation within its cone) and two_bone_start with a pole."""

import numpy as np

from fullbody_adjust.solver.fullbody.limb_rotations import END_SWING, end_rotation
from fullbody_adjust.solver.chain.two_bone_start import two_bone_start
from tests.helpers.rotations import about_axis


def _angle(a, b):
    return np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))


def test_end_rotation_keeps_a_wanted_turn_within_the_cone_and_stops_at_its_edge_beyond():
    direction = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    carried = np.stack([about_axis([1, 0, 0], 0.2)] * 2)
    wanted = np.stack([about_axis([0.3, 0.0, 1.0], 0.9), about_axis([0.0, 0.2, 1.0], 2.8)])
    got = end_rotation(wanted, carried, direction)
    np.testing.assert_allclose(got[0], wanted[0], atol=1e-12)
    ride = carried[1] @ direction[1]
    assert abs(_angle(got[1] @ direction[1], ride) - END_SWING) < 1e-9
    # Stopped on the way from where the parent carries it to the wanted direction.
    assert _angle(got[1] @ direction[1], wanted[1] @ direction[1]) < _angle(ride, wanted[1] @ direction[1])
    np.testing.assert_allclose(got[1] @ got[1].T, np.eye(3), atol=1e-12)


def test_two_bone_start_bends_toward_the_pole_in_its_plane():
    chain = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, -0.5], [0.0, 0.0, -1.0]]] * 3)
    target = np.array([[0.3, 0.2, -0.7]] * 3)
    poles = np.array([[0.0, 1.0, -0.5], [1.0, 0.0, -0.5], [-1.0, -1.0, 0.0]])
    placed = two_bone_start(chain, target, np.tile([1.0, 0.0, 0.0], (3, 1)), poles)
    np.testing.assert_allclose(placed[:, -1], target, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(placed, axis=1), axis=-1), 0.5, atol=1e-12)
    along = target / np.linalg.norm(target, axis=-1, keepdims=True)
    for middle, pole, line in zip(placed[:, 1], poles, along):
        side = middle - line * (middle @ line)
        wanted = pole - line * (pole @ line)
        assert _angle(side, wanted) < 1e-6


def test_end_rotation_stays_finite_for_a_wanted_direction_right_opposite():
    direction = np.array([[0.0, 1.0, 0.0]])
    carried = np.eye(3)[None]
    wanted = about_axis([1.0, 0.0, 0.0], np.pi)[None]
    got = end_rotation(wanted, carried, direction)
    assert np.all(np.isfinite(got))
    assert abs(_angle(got[0] @ direction[0], direction[0]) - END_SWING) < 1e-9
