"""The two-bone warm start of hinged limbs (solver/chain/two_bone_start.py), on a batch of chains."""

import numpy as np

from fullbody_adjust.solver.chain.two_bone_start import two_bone_start


def test_the_end_lands_on_a_reachable_target_bending_to_the_hinge_axis_side():
    """An arm (clavicle, upper arm, forearm) with its target 0.8 of the two segments away: the end lands on it,
    the segments keep their lengths, and it bends to the positive side of the hinge axis."""
    start = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0], [0.8, 0.0, 0.0]])
    target = np.array([0.2 + 0.48 * np.cos(0.3), 0.48 * np.sin(0.3), 0.0])
    axis = np.array([0.0, 0.0, 1.0])
    out = two_bone_start(start[None], target[None], axis[None])[0]
    np.testing.assert_allclose(out[-1], target, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=0), axis=1), [0.2, 0.3, 0.3], atol=1e-12)
    upper, lower = out[2] - out[1], out[3] - out[2]
    assert np.cross(upper, lower) @ axis > 0.0


def test_a_chain_without_a_bend_plane_keeps_its_start_and_the_others_are_placed():
    """Row 0: a straight two-bone chain whose hinge axis lies along its target direction (no bend plane
    perpendicular to it): it is left as it was, pointed at the target, instead of failing the whole batch;
    row 1, an ordinary chain beside it, reaches its target."""
    straight = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    bent = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    targets = np.array([[0.0, 0.0, 1.5], [1.2, 0.5, 0.0]])
    axes = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    out = two_bone_start(np.stack([straight, bent]), targets, axes)
    np.testing.assert_allclose(out[0], straight, atol=1e-12)
    np.testing.assert_allclose(out[1, -1], targets[1], atol=1e-12)
