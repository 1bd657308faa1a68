"""One frame's nearest points (solver/reach_balls_plain.py, plain floats) against the numpy path on many frames at
once (reach_balls.py): the same bits on every frame, also where the geometry degenerates (concentric balls,
tangent spheres, a point on a circle's axis, collinear centres, a point at the sphere's centre, no common point);
and the priority variant's sub-base point where the balls have no common point."""

import numpy as np
import pytest

from fullbody_adjust.solver.reach_balls import nearest_in_balls, nearest_on_sphere_in_balls, sub_base_point


def _frames(k, n=400, seed=0):
    """n frames of k balls: points (n,3), centres (n,k,3), radii (n,k), active (n,k), spheres' centres (n,3) and
    radii (n,); a quarter random, the rest with one degeneracy each."""
    rng = np.random.default_rng(seed + 17 * k)
    points = rng.uniform(-1.5, 1.5, (n, 3))
    centres = rng.uniform(-1.0, 1.0, (n, k, 3))
    radii = rng.uniform(0.2, 1.6, (n, k))
    active = rng.random((n, k)) < 0.8
    centre = rng.uniform(-1.0, 1.0, (n, 3))
    radius = rng.uniform(0.3, 1.5, n)
    kind = np.arange(n) % 8
    for f in range(n):
        if k >= 2 and kind[f] == 1:  # concentric balls
            centres[f, 1] = centres[f, 0]
        elif k >= 2 and kind[f] == 2:  # tangent spheres: their circle is one point
            gap = np.linalg.norm(centres[f, 1] - centres[f, 0])
            radii[f, 1] = gap - radii[f, 0] if gap > radii[f, 0] else radii[f, 0] - gap
        elif k >= 2 and kind[f] == 3:  # the point on the line through two centres (their circle's axis)
            points[f] = centres[f, 0] + 0.3 * (centres[f, 1] - centres[f, 0])
            centre[f] = centres[f, 0] + 0.7 * (centres[f, 1] - centres[f, 0])
        elif k >= 3 and kind[f] == 4:  # collinear centres: no three-sphere points
            centres[f, 2] = centres[f, 0] + 2.0 * (centres[f, 1] - centres[f, 0])
        elif kind[f] == 5:  # the point at the sphere's centre, in every ball
            centre[f] = points[f]
            if k:
                centres[f] = points[f] + rng.uniform(-0.1, 0.1, (k, 3))
        elif k and kind[f] == 6:  # balls far apart: no common point
            centres[f] *= 6.0
            radii[f] *= 0.3
        elif k and kind[f] == 7:  # the point exactly on a ball's boundary
            d = points[f] - centres[f, 0]
            radii[f, 0] = np.sqrt(d @ d)
    return points, centres, radii, active, centre, radius


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4, 5])
def test_one_frame_gives_the_bits_of_the_numpy_path(k):
    points, centres, radii, active, centre, radius = _frames(k)
    x_all, ok_all = nearest_in_balls(points, centres, radii, active)
    s_all, found_all = nearest_on_sphere_in_balls(points, centre, radius, centres, radii, active)
    assert ok_all.any() and found_all.any()
    if k >= 2:  # the cases reach every kind of answer: inside, infeasible, moved
        assert not ok_all.all() and not found_all.all()
        assert np.any(ok_all & np.any(x_all != points, axis=1))
    for f in range(len(points)):
        one = slice(f, f + 1)
        x, ok = nearest_in_balls(points[one], centres[one], radii[one], active[one])
        assert ok.dtype == bool and x.shape == (1, 3)
        np.testing.assert_array_equal(x[0], x_all[f], err_msg=f"nearest_in_balls, frame {f}")
        assert ok[0] == ok_all[f]
        s, found = nearest_on_sphere_in_balls(points[one], centre[one], radius[one], centres[one], radii[one],
                                              active[one])
        np.testing.assert_array_equal(s[0], s_all[f], err_msg=f"nearest_on_sphere_in_balls, frame {f}")
        assert found[0] == found_all[f]


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_one_frame_priority_sub_base_gives_the_bits_of_the_numpy_path(k):
    points, centres, radii, active, _, _ = _frames(k, seed=1)
    rng = np.random.default_rng(k)
    for priorities in (rng.choice([0.0, 1.0, 2.0], k), np.append(rng.random(k - 1), -np.inf)):
        x_all, ok_all = sub_base_point(points, centres, radii, active, priorities, "priority")
        if k >= 2:  # some frames have balls without a common point: the priorities decide there
            assert not ok_all.all()
        for f in range(len(points)):
            one = slice(f, f + 1)
            x, ok = sub_base_point(points[one], centres[one], radii[one], active[one], priorities, "priority")
            np.testing.assert_array_equal(x[0], x_all[f], err_msg=f"frame {f}, priorities {priorities}")
            assert ok[0] == ok_all[f]
