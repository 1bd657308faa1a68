"""The collision tests on a few points or segments (solver/obstacles/boxes.py, plain floats) against the numpy path on
many at once: the same answers, also on a box's faces, for segments along a face or an axis, with per-problem
boxes and with NaN coordinates."""

import numpy as np
import pytest

from fullbody_adjust.solver.obstacles.boxes import _FEW_TESTS, Boxes, penetrates_few, points_inside, segments_cross


def _points(rng, n, mins, maxs):
    """n points around the boxes, many of them on a face, an edge or a corner (coordinates copied from the box)."""
    lo, hi = mins.min(axis=-2), maxs.max(axis=-2)
    p = rng.uniform(lo - 0.5, hi + 0.5, (n, 3))
    snap = rng.random((n, 3)) < 0.3
    face = np.where(rng.random((n, 3)) < 0.5, mins.reshape(-1, 3)[0], maxs.reshape(-1, 3)[0])
    return np.where(snap, face, p)


@pytest.mark.parametrize("seed", range(4))
def test_few_tests_answer_as_the_numpy_path(seed):
    rng = np.random.default_rng(seed)
    k = 1 + seed % 2
    mins = rng.uniform(-1.0, 0.0, (k, 3))
    boxes = Boxes(mins, mins + rng.uniform(0.2, 1.0, (k, 3)))
    n = 600
    a = _points(rng, n, boxes.mins, boxes.maxs)
    b = _points(rng, n, boxes.mins, boxes.maxs)
    b[::5, seed % 3] = a[::5, seed % 3]  # segments that do not move along an axis (on a face, or outside a slab)
    b[::7] = a[::7]  # segments of no length
    a[3::50, 1] = np.nan
    assert n * k > _FEW_TESTS  # the whole arrays take the numpy path
    inside_all, cross_all = points_inside(a, boxes), segments_cross(a, b, boxes)
    assert inside_all.any() and not inside_all.all() and cross_all.any() and not cross_all.all()
    assert (cross_all & ~inside_all).any()  # segments crossing a box with both ends outside it
    for shape in ((1,), (2,), (1, 2), (2, 2)):
        size = int(np.prod(shape))
        assert size * k <= _FEW_TESTS
        for start in range(0, n - size, size):
            rows = slice(start, start + size)
            pa, pb = a[rows].reshape(shape + (3,)), b[rows].reshape(shape + (3,))
            np.testing.assert_array_equal(points_inside(pa, boxes), inside_all[rows].reshape(shape + (k,)))
            np.testing.assert_array_equal(segments_cross(pa, pb, boxes), cross_all[rows].reshape(shape + (k,)))


def test_few_tests_pair_per_problem_boxes_with_the_first_axis():
    rng = np.random.default_rng(9)
    problems, per = 2, 3
    mins = rng.uniform(-1.0, 0.0, (problems, 2, 3))
    boxes = Boxes(mins, mins + 0.8)
    a = rng.uniform(-1.2, 1.0, (problems, per, 3))
    b = rng.uniform(-1.2, 1.0, (problems, per, 3))
    for p in range(problems):
        shared = Boxes(boxes.mins[p], boxes.maxs[p])
        many_a = np.concatenate([a[p]] * 3)  # shared boxes, enough rows for the numpy path
        many_b = np.concatenate([b[p]] * 3)
        np.testing.assert_array_equal(points_inside(a, boxes)[p], points_inside(many_a, shared)[:per])
        np.testing.assert_array_equal(segments_cross(a, b, boxes)[p], segments_cross(many_a, many_b, shared)[:per])


@pytest.mark.parametrize("seed", range(4))
def test_penetrates_few_answers_as_the_numpy_tests_with_what_each_row_ignores(seed):
    """The obstacle response's first question (does a joint lie in, or its segment meet, a box it does not
    ignore?) in plain floats against points_inside / segments_cross on all rows at once, row by row and a few rows
    at a time: shared and per-problem boxes, rows ignoring some boxes for the joint or the segment (or both),
    segments along a face, NaN."""
    rng = np.random.default_rng(20 + seed)
    k, n = 1 + seed % 2, 800
    mins = rng.uniform(-1.0, 0.0, (k, 3))
    maxs = mins + rng.uniform(0.2, 1.0, (k, 3))
    a, b = _points(rng, n, mins, maxs), _points(rng, n, mins, maxs)
    b[::5, seed % 3] = a[::5, seed % 3]
    a[3::50, 1] = np.nan
    ign_point, ign_seg = rng.random((n, k)) < 0.4, rng.random((n, k)) < 0.4
    batched = seed >= 2
    if batched:  # each problem its own boxes, shifted
        shift = rng.uniform(-0.3, 0.3, (n, 1, 3))
        boxes = Boxes(mins[None] + shift, maxs[None] + shift)
    else:
        boxes = Boxes(mins, maxs)
    inside, crossing = points_inside(b, boxes), segments_cross(a, b, boxes)
    hit = ((inside & ~ign_point) | (crossing & ~ign_seg)).any(axis=-1)
    assert hit.any() and not hit.all() and (inside & ign_point & ign_seg).any()
    for size in (1, _FEW_TESTS // k):
        for start in range(0, n, size):
            rows = np.arange(start, min(start + size, n))
            sub = boxes.select(rows) if batched else boxes
            assert penetrates_few(a[rows], b[rows], sub, ign_point[rows], ign_seg[rows]) == hit[rows].any(), rows
            assert penetrates_few(a[rows], b[rows], sub) == (inside[rows] | crossing[rows]).any(), rows
    rows = np.arange(_FEW_TESTS // k + 1)
    assert penetrates_few(a[rows], b[rows], boxes.select(rows) if batched else boxes) is None  # numpy's turn


@pytest.mark.parametrize("batched", [False, True])
def test_chain_penetration_counts_of_a_few_chains_as_the_numpy_path(monkeypatch, batched):
    """ChainModel.penetration_counts of 1-4 chains (count_penetrations_few, plain floats) against the numpy
    path: the same counts, with the boxes the end and the base ignore (a target or the base inside a box)
    left out, for 2- to 5-joint chains around one or two boxes, shared or per problem."""
    from fullbody_adjust.solver.obstacles import boxes as obstacles
    from fullbody_adjust.solver.chain.model import ChainModel
    from fullbody_adjust.solver.chain.settings import ChainSettings
    rng = np.random.default_rng(3 + batched)
    counted = 0
    for trial in range(300):
        b, n, k = 1 + trial % 4, 2 + trial % 4, 1 + trial % 2
        mins = rng.uniform(-0.6, 0.0, (b, k, 3) if batched else (k, 3))
        boxes = Boxes(mins, mins + rng.uniform(0.2, 0.8, mins.shape))
        start = np.cumsum(rng.normal(scale=0.4, size=(b, n, 3)), axis=1)
        targets = start[:, -1] + rng.normal(scale=0.05, size=(b, 3))
        model = ChainModel(start, targets, ChainSettings(), None, boxes, None)
        pose = start + rng.normal(scale=0.2, size=start.shape)
        pose[:, 1:][rng.random((b, n - 1)) < 0.2] = mins.reshape(-1, 3)[0]  # on a box's corner
        rows = np.arange(b)
        got = model.penetration_counts(pose, rows)
        with monkeypatch.context() as numpy_path:
            numpy_path.setattr(obstacles, "_FEW_COUNTS", 0)
            expected = model.penetration_counts(pose, rows)
        for g, e in zip(got, expected):
            assert g.dtype == e.dtype and g.tolist() == e.tolist()
        counted += int(expected[0].sum() + expected[1].sum() > 0)
    assert 0 < counted < 300  # penetrating poses and clear ones
