"""A limb's surface as points riding on its segments (solver/obstacles/surface.py, AdjustSettings.surface): the points
follow the bones as the product turns them, and where a limb reaches its target with some of them in a box, the
swivel round the target that keeps them out is taken (obstacles/easing.py, _surface_clear). Checked against the bone
rotations the solve returns, not the module's own arithmetic."""

import numpy as np
import pytest

from fullbody_adjust.solver import Boxes, SolverInputError
from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames, adjust_pose
from fullbody_adjust.solver.obstacles.surface import LimbSurface, depth_in_boxes, posed_points
from fullbody_adjust.solver.fullbody.limb_rotations import chain_rotations
from tests.helpers import metarig


def _chain():
    start = np.array([[[0.0, 0.0, 1.5], [0.3, 0.0, 1.5], [0.3, -0.25, 1.45]]])
    moved = np.array([[[[0.0, 0.0, 1.5], [0.2, -0.2, 1.35], [0.45, -0.2, 1.3]]]])
    return start, moved


def test_points_ride_rigidly_on_their_segments():
    start, moved = _chain()
    rng = np.random.default_rng(5)
    segment = np.repeat([0, 1], 20)
    roots, ends = start[0, segment], start[0, segment + 1]
    along = rng.uniform(-0.2, 1.3, 40)[:, None]  # past either joint too (a fist beyond the wrist)
    points = roots + along * (ends - roots) + rng.normal(0.0, 0.04, (40, 3))
    surface = LimbSurface(segment, points[None])
    turns = chain_rotations(start, moved[:, 0], None, np.array([0]))
    out = posed_points(surface, np.array([0]), start, moved, turns[:, None])[0, 0]
    new_roots, new_ends = moved[0, 0, segment], moved[0, 0, segment + 1]
    # Each keeps its distance to its segment's root and its place along the segment's line.
    np.testing.assert_allclose(np.linalg.norm(out - new_roots, axis=1), np.linalg.norm(points - roots, axis=1),
                               atol=1e-12)
    old_axis = (ends - roots) / np.linalg.norm(ends - roots, axis=1)[:, None]
    new_axis = (new_ends - new_roots) / np.linalg.norm(new_ends - new_roots, axis=1)[:, None]
    np.testing.assert_allclose(np.sum((out - new_roots) * new_axis, axis=1),
                               np.sum((points - roots) * old_axis, axis=1), atol=1e-12)
    # Unmoved chains leave them where they are.
    same = posed_points(surface, np.array([0]), start, start[:, None],
                        chain_rotations(start, start, None, np.array([0]))[:, None])
    np.testing.assert_allclose(same[0, 0], points, atol=1e-12)


def test_weighted_points_blend_their_bones_moves():
    """Given weights, a point goes where linear blend skinning puts it: its weights times where each segment's
    rotation about its root, the end joint's move and the base's move would take it."""
    start, moved = _chain()
    rng = np.random.default_rng(9)
    points = rng.uniform(-0.3, 0.3, (1, 30, 3)) + start[0, 1]
    weights = rng.dirichlet(np.ones(4), 30)  # segments 0 and 1, the end, the base
    surface = LimbSurface(np.argmax(weights[:, :2], axis=1), points, weights)
    turns = chain_rotations(start, moved[:, 0], None, np.array([0]))[0]
    got = posed_points(surface, np.array([0]), start, moved, turns[None, None])[0, 0]
    c, s0, p = moved[0, 0], start[0], points[0]
    want = (weights[:, :1] * (c[0] + (p - s0[0]) @ turns[0].T) + weights[:, 1:2] * (c[1] + (p - s0[1]) @ turns[1].T)
            + weights[:, 2:3] * (p + c[2] - s0[2]) + weights[:, 3:] * (p + c[0] - s0[0]))
    np.testing.assert_allclose(got, want, atol=1e-12)
    # One-hot weights on a point's own segment: the rigid ride.
    rigid = LimbSurface(surface.segment, points, np.eye(4)[surface.segment])
    np.testing.assert_allclose(posed_points(rigid, np.array([0]), start, moved, turns[None, None]),
                               posed_points(LimbSurface(surface.segment, points), np.array([0]), start, moved,
                                            turns[None, None]), atol=1e-12)


def test_depth_in_boxes_adds_up_how_deep_each_point_lies_in_its_deepest_box():
    rng = np.random.default_rng(2)
    points = rng.uniform(-1.0, 1.0, (2, 3, 50, 3))
    mins, maxs = np.array([[-0.5, -0.5, -0.5], [-0.2, -0.2, -0.2]]), np.array([[0.0, 0.0, 0.0], [0.9, 0.9, 0.9]])
    got = depth_in_boxes(points, Boxes(mins, maxs))
    # Sampled independently: a point inside a box lies as deep as the largest ball round it the box holds.
    flat = points.reshape(-1, 3)
    want = np.zeros(len(flat))
    for lo, hi in zip(mins, maxs):
        inside = ((flat >= lo) & (flat <= hi)).all(axis=1)
        ball = np.minimum(flat - lo, hi - flat).min(axis=1)
        want = np.maximum(want, np.where(inside, ball, 0.0))
    np.testing.assert_allclose(got, want.reshape(2, 3, 50).sum(axis=-1), atol=1e-12)
    assert (got > 0.0).all()  # 150 points in the boxes' 3 / 8 of the cube: some in each group
    turned = Boxes(mins[:1], maxs[:1], np.eye(3)[[1, 2, 0]][None])  # the same box with its axes permuted
    np.testing.assert_allclose(depth_in_boxes(points[..., [1, 2, 0]], turned),
                               depth_in_boxes(points, Boxes(mins[:1], maxs[:1])), atol=1e-12)


@pytest.mark.parametrize("segment, points, message", [
    (np.array([0, 1]), np.zeros((1, 3, 3)), "segment"),
    (np.array([0, -1]), np.zeros((1, 2, 3)), "segment indices"),
    (np.array([0, 1]), np.full((1, 2, 3), np.nan), "NaN"),
    (np.array([0, 1]), np.zeros((1, 2, 3)), "weights"),
])
def test_bad_surfaces_are_one_line(segment, points, message):
    with pytest.raises(SolverInputError, match=message):
        LimbSurface(segment, points, np.zeros((2, 2)) if message == "weights" else None)
    with pytest.raises(SolverInputError, match="unknown limb"):
        AdjustSettings(surface={"tail": LimbSurface(np.array([0]), np.zeros((1, 1, 3)))})
    with pytest.raises(SolverInputError, match="LimbSurface"):
        AdjustSettings(surface={"arm.L": np.zeros((1, 1, 3))})


def _fist_case():
    """The metarig's left hand target in front of it (0.65 of the arm's reach, up and forward), a 'fist' of points
    riding on the forearm past the wrist (a hand-less arm's mesh: rings of 5 cm radius up to 8 cm beyond the joint
    end), and a 4 cm box on the fist's side where it is when the arm reaches the target without the box, clear of the
    forearm's centre line and of the target."""
    model, heads, tails, x_axes = metarig.load()
    targets, joints = metarig.left_hand_in_front(model, heads, tails)
    arm = model.limbs["arm.L"]
    elbow, wrist = joints[-2], joints[-1]
    u = (wrist - elbow) / np.linalg.norm(wrist - elbow)
    e1 = np.cross(u, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    angles = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    fist = np.array([wrist + d * u + 0.05 * (np.cos(a) * e1 + np.sin(a) * e2)
                     for d in (0.0, 0.04, 0.08) for a in angles])
    surface = {"arm.L": LimbSurface(np.full(len(fist), len(arm.bones) - 1), fist[None])}
    free = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, bone_x_axes=x_axes)
    forearm = arm.bones[-1]
    posed = _posed(free, heads, forearm, fist)
    centre = 0.5 * (posed[12] + posed[24])  # between the outer two rings, on their first points
    boxes = Boxes(centre[None] - 0.02, centre[None] + 0.02)
    return model, heads, tails, x_axes, targets, boxes, surface, forearm, fist


def _posed(result, heads, bone, points):
    """Where `points` riding on `bone` are after `result`: its new head plus its world rotation delta applied."""
    return result.heads[bone] + (points - heads[bone]) @ result.rotations[bone].T


def test_a_surface_in_the_box_turns_the_limb_round_its_target():
    model, heads, tails, x_axes, targets, boxes, surface, forearm, fist = _fist_case()

    def solve(settings):
        return adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                           settings=settings, bone_x_axes=x_axes)

    def inside(result):
        p = _posed(result, heads, forearm, fist)
        return int(((p >= boxes.mins[0]) & (p <= boxes.maxs[0])).all(axis=1).sum())

    paper = solve(AdjustSettings())
    assert paper.status[0] == "reached" and inside(paper) > 0  # the centre line clear, the fist in the box
    kept = solve(AdjustSettings(surface=surface))
    assert kept.status[0] == "reached" and kept.residuals[0] <= 1e-6, kept.reasons[0]
    assert inside(kept) == 0 and "surface" in kept.reasons[0]
    # A surface on a limb the box is nowhere near changes nothing, bit for bit.
    other = solve(AdjustSettings(surface={"leg.R": LimbSurface(np.zeros(1, dtype=np.int64), heads[None, :1])}))
    np.testing.assert_array_equal(other.heads, paper.heads)
    np.testing.assert_array_equal(other.rotations, paper.rotations)


def test_over_frames_each_frame_turns_as_solved_alone():
    """adjust_frames on two frames, the box on the first only (the second's far away): the first frame's pose is
    the one solved alone with the surface, the second the one solved without the box."""
    model, heads, tails, x_axes, targets, boxes, surface, forearm, fist = _fist_case()
    far = Boxes(boxes.mins + 10.0, boxes.maxs + 10.0)
    frames = Boxes(np.stack([boxes.mins, far.mins]), np.stack([boxes.maxs, far.maxs]))
    two = {limb: LimbSurface(s.segment, np.concatenate([s.points, s.points])) for limb, s in surface.items()}
    both = adjust_frames(model, np.stack([heads, heads]), np.stack([tails, tails]), np.stack([targets, targets]),
                         metarig.EFFECTORS, metarig.PRIORITIES, obstacles=frames,
                         settings=AdjustSettings(surface=two), bone_x_axes=np.stack([x_axes, x_axes]))
    for f, box in enumerate((boxes, far)):
        alone = adjust_pose(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=box,
                            settings=AdjustSettings(surface=surface), bone_x_axes=x_axes)
        np.testing.assert_allclose(both[f].heads, alone.heads, atol=1e-9)
    assert "surface" in both[0].reasons[0] and "surface" not in both[1].reasons[0]
