"""The swivelled starts a limb's eased retries begin from (solver/obstacles/swivel.py): every start meets the target
with the segments' lengths and the joints before the two kept, the elbow going round the circle about the line
from the two segments' root to the target; and the intrusion that picks among them against distances sampled
independently."""

import numpy as np

from fullbody_adjust.solver import Boxes
from fullbody_adjust.solver.obstacles.swivel import ANGLES, intrusion, swivel_starts


def _arm():
    """A clavicle, upper arm and forearm (4 joints) bent at the elbow, and a target the two segments reach."""
    start = np.array([[[0.0, 0.0, 1.5], [0.15, 0.0, 1.5], [0.45, 0.0, 1.5], [0.45, -0.25, 1.45]]])
    return start, np.array([[0.5, -0.3, 1.2]])


def test_every_swivel_meets_the_target_with_the_segments_lengths_round_the_root_to_target_line():
    start, target = _arm()
    out = swivel_starts(start, target)
    assert out.shape == (1, len(ANGLES), 4, 3)
    lengths = np.linalg.norm(np.diff(start[0], axis=0), axis=1)
    root = out[0, :, 1]
    np.testing.assert_allclose(root, np.repeat(start[:, 1], len(ANGLES), axis=0), atol=1e-12)  # clavicle kept
    np.testing.assert_allclose(out[0, :, -1], np.repeat(target, len(ANGLES), axis=0), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out[0], axis=1), axis=2), np.tile(lengths, (len(ANGLES), 1)),
                               atol=1e-9)
    # The elbows lie on one circle about the root -> target line, at the sampled angles apart.
    axis = (target[0] - start[0, 1]) / np.linalg.norm(target[0] - start[0, 1])
    offsets = out[0, :, 2] - start[0, 1]
    radial = offsets - np.outer(offsets @ axis, axis)
    np.testing.assert_allclose(offsets @ axis, offsets[0] @ axis, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), np.linalg.norm(radial[0]), atol=1e-9)
    first = radial[0] / np.linalg.norm(radial[0])
    turned = np.arctan2(np.cross(first, radial / np.linalg.norm(radial, axis=1)[:, None]) @ axis,
                        radial @ first / np.linalg.norm(radial, axis=1))
    np.testing.assert_allclose(np.abs(turned), np.abs(np.angle(np.exp(1j * ANGLES))), atol=1e-9)
    # Angle 0 bends the elbow to the start's own side.
    bend = np.cross(start[0, 2] - start[0, 1], start[0, 3] - start[0, 2])
    assert np.cross(out[0, 0, 2] - out[0, 0, 1], out[0, 0, 3] - out[0, 0, 2]) @ bend > 0.0


def test_intrusion_sums_how_far_points_along_the_segments_come_into_the_clearance():
    start, target = _arm()
    chains = swivel_starts(start, target)
    middle = 0.5 * (chains[0, 0, 2] + chains[0, 0, 3])  # a box on the forearm of the start's own bend
    box = Boxes(middle[None] - 0.02, middle[None] + 0.02)
    clearance = 0.05
    got = intrusion(chains, box, np.array([clearance]))
    # Sampled independently: 9 points along each segment, distance to the box by clamping into it.
    t = np.linspace(0.0, 1.0, 9)[:, None]
    for k in range(len(ANGLES)):
        points = np.concatenate([a + t * (b - a) for a, b in zip(chains[0, k, :-1], chains[0, k, 1:])])
        d = np.linalg.norm(points - np.clip(points, box.mins[0], box.maxs[0]), axis=1)
        assert np.isclose(got[0, k], np.maximum(clearance - d, 0.0).sum(), atol=1e-12)
    # The start's own bend goes through the box, the half turn (ANGLES' last) is farthest from it.
    assert np.argmax(got[0]) == 0 and np.argmin(got[0]) == len(ANGLES) - 1
    far = Boxes(np.array([[5.0, 5.0, 5.0]]), np.array([[6.0, 6.0, 6.0]]))
    np.testing.assert_array_equal(intrusion(chains, far, np.array([clearance])), 0.0)
