"""A limb's clearance from obstacle boxes (AdjustSettings.clearance, obstacles.grown_clear_of): its centre line keeps
the clearance from every box, less where its target lies nearer; none set is the paper's behaviour, bit for bit."""

import numpy as np
import pytest

from fullbody_adjust.solver import Boxes, SolverInputError
from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames, adjust_pose
from fullbody_adjust.solver.obstacles.boxes import distances_to_boxes, grown_clear_of, points_inside
from tests.helpers import metarig


def _rotation(angles):
    a, b, c = angles
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _surface_samples(boxes, k, count=41):
    """Points on box k's surface (world), a grid on each face."""
    lo, hi = boxes.mins[k], boxes.maxs[k]
    s = np.linspace(0.0, 1.0, count)
    u, v = np.meshgrid(s, s)
    faces = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for side in (lo[axis], hi[axis]):
            p = np.empty((u.size, 3))
            p[:, axis] = side
            p[:, others[0]] = lo[others[0]] + u.ravel() * (hi[others[0]] - lo[others[0]])
            p[:, others[1]] = lo[others[1]] + v.ravel() * (hi[others[1]] - lo[others[1]])
            faces.append(p)
    local = np.concatenate(faces)
    return local if boxes.axes is None else local @ boxes.axes[k].T


@pytest.mark.parametrize("oriented", [False, True])
def test_distances_to_boxes_is_the_distance_to_the_nearest_surface_point(oriented):
    rng = np.random.default_rng(3)
    axes = np.stack([_rotation(rng.uniform(-1, 1, 3)) for _ in range(2)]) if oriented else None
    mins = rng.uniform(-1.0, 0.0, (2, 3))
    boxes = Boxes(mins, mins + rng.uniform(0.2, 1.0, (2, 3)), axes)
    points = rng.uniform(-2.0, 2.0, (50, 3))
    got = distances_to_boxes(points, boxes)
    for k in range(2):
        sampled = np.linalg.norm(points[:, None] - _surface_samples(boxes, k)[None], axis=-1).min(axis=1)
        outside = got[:, k] > 0.0
        # The exact distance lies below every sampled surface point's and within the grid's spacing of them.
        assert (got[outside, k] <= sampled[outside] + 1e-12).all()
        np.testing.assert_allclose(got[outside, k], sampled[outside], atol=0.03)
    np.testing.assert_array_equal(got == 0.0, points_inside(points, boxes))


def test_a_box_grows_by_the_clearance_but_less_near_the_target():
    boxes = Boxes(np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0]]), np.array([[1.0, 1.0, 1.0], [6.0, 6.0, 6.0]]))
    base = np.array([[-3.0, 0.5, 0.5], [-3.0, 0.5, 0.5]])
    target = np.array([[1.1, 0.5, 0.5], [3.0, 0.5, 0.5]])  # 0.1 from box 0, then 2 from it
    grown = grown_clear_of(boxes, np.array([0.3, 0.3]), np.stack([base, target], axis=1))
    assert grown.batched
    # Problem 0: box 0 grown by 0.9 x 0.1 (its target's distance), box 1 by the clearance; problem 1: both by it.
    np.testing.assert_allclose(grown.mins[0] - boxes.mins, -np.array([[0.09], [0.3]]) * np.ones(3))
    np.testing.assert_allclose(grown.maxs[1] - boxes.maxs, 0.3)
    inside_box = np.array([[[0.5, 0.5, 0.5], [-3.0, 0.5, 0.5]]])  # a base inside box 0: not grown at all
    np.testing.assert_array_equal(grown_clear_of(boxes, np.array([0.3]), inside_box).mins[0, 0], boxes.mins[0])


@pytest.mark.parametrize("clearance, message", [
    ({"arm.X": 0.1}, "unknown limb"), ({"arm.L": -0.1}, ">= 0"), ({"arm.L": float("nan")}, ">= 0"),
    ({"arm.L": "5"}, ">= 0"), (3.0, "map limb names")])
def test_bad_clearances_are_one_line(clearance, message):
    with pytest.raises(SolverInputError, match=message):
        AdjustSettings(clearance=clearance)


def test_clearances_are_kept_as_sorted_pairs():
    settings = AdjustSettings(clearance={"leg.L": 0.2, "arm.L": 0.05})
    assert settings.clearance == (("arm.L", 0.05), ("leg.L", 0.2))
    assert settings.clearance_of("arm.L") == 0.05 and settings.clearance_of("trunk") == 0.0
    assert settings == AdjustSettings(clearance=[("arm.L", 0.05), ("leg.L", 0.2)])


def _obstacle_case(along=0.25, turn=0.0):
    """The full metarig, its feet planted and its left hand's target in front of it with the elbow bent (0.65 of
    the arm's reach from its base, up and forward), and a 6 cm box `along` the way from the elbow to the wrist
    of the pose solved without it, turned by `turn` radians about the vertical (an oriented box)."""
    model, heads, tails, x_axes = metarig.load()
    targets, _ = metarig.left_hand_in_front(model, heads, tails)
    arm = model.limbs["arm.L"]
    free = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x_axes)
    elbow, wrist = free.heads[arm.bones[-1]], free.heads[arm.end_bone]
    centre = elbow + along * (wrist - elbow)
    axes = _rotation((0.0, 0.0, turn))
    local = axes.T @ centre
    boxes = Boxes(local[None] - 0.03, local[None] + 0.03, axes[None] if turn else None)
    return model, heads, tails, x_axes, targets, boxes


def _arm_clearance(model, result, boxes):
    """The nearest approach of arm.L's upper arm and forearm centre line to the box."""
    joints = model.limbs["arm.L"].joints(result.heads, result.tails)[-3:]
    t = np.linspace(0.0, 1.0, 400)[:, None]
    samples = np.concatenate([a + t * (b - a) for a, b in zip(joints[:-1], joints[1:])])
    return float(distances_to_boxes(samples, boxes).min())


@pytest.mark.parametrize("turn", [0.0, 0.5])
def test_the_arm_keeps_its_clearance_from_the_box_and_reaches(turn):
    model, heads, tails, x_axes, targets, boxes = _obstacle_case(turn=turn)

    def solve(settings):
        return adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                           settings=settings, bone_x_axes=x_axes)

    paper = solve(AdjustSettings())
    assert _arm_clearance(model, paper, boxes) < 0.05  # the paper keeps the centre line out, not 5 cm off
    kept = solve(AdjustSettings(clearance={"arm.L": 0.05}))
    assert kept.status[0] == "reached" and "clearance" not in kept.reasons[0]
    assert _arm_clearance(model, kept, boxes) >= 0.05 - 1e-9
    # No clearance, or one on limbs nowhere near the box: the paper's pose, bit for bit.
    for settings in (AdjustSettings(clearance={}), AdjustSettings(clearance={"leg.R": 0.05})):
        other = solve(settings)
        np.testing.assert_array_equal(other.heads, paper.heads)
        np.testing.assert_array_equal(other.rotations, paper.rotations)


def test_a_clearance_that_keeps_the_hand_from_its_target_is_eased():
    model, heads, tails, x_axes, targets, boxes = _obstacle_case(along=0.5)
    wrist = targets[0]
    gap = float(distances_to_boxes(wrist, boxes)[0])
    # A clearance beyond the target's own distance to the box leaves no way to reach keeping it in full.
    result = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                         settings=AdjustSettings(clearance={"arm.L": 4.0 * gap}), bone_x_axes=x_axes)
    assert result.status[0] == "reached", result.reasons[0]
    assert "clearance" in result.reasons[0]
    # Eased, the elbow swings round to the side clear of the box (obstacle_swivel) rather than stopping with the
    # centre line just out of it as the paper does (measured before the swivel: 1.9 mm, the paper's 3 mm).
    paper = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                        bone_x_axes=x_axes)
    kept = _arm_clearance(model, result, boxes)
    assert kept >= 0.5 * gap and kept > 10.0 * _arm_clearance(model, paper, boxes), (kept, gap)


def test_per_frame_boxes_each_frame_keeps_its_clearance_as_solved_alone():
    """adjust_frames with a box per frame (two frames, the second box turned): each frame's pose is the one
    solved alone with its box, and keeps the clearance from it."""
    model, heads, tails, x_axes, targets, aligned = _obstacle_case()
    *_, turned = _obstacle_case(turn=0.5)
    settings = AdjustSettings(clearance={"arm.L": 0.04})
    frames = Boxes(np.stack([aligned.mins, turned.mins]), np.stack([aligned.maxs, turned.maxs]),
                   np.stack([np.eye(3)[None], turned.axes]))
    both = adjust_frames(model, np.stack([heads, heads]), np.stack([tails, tails]), np.stack([targets, targets]),
                         metarig.EFFECTORS, metarig.PRIORITIES, obstacles=frames, settings=settings,
                         bone_x_axes=np.stack([x_axes, x_axes]))
    for f, boxes in enumerate((aligned, turned)):
        alone = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                            settings=settings, bone_x_axes=x_axes)
        np.testing.assert_allclose(both[f].heads, alone.heads, atol=1e-9)
        assert _arm_clearance(model, both[f], boxes) >= 0.04 - 1e-9
