"""Sub-base geometry (solver/fullbody/reach_balls.py) against brute force: the nearest point of a sphere inside every
active ball, checked on dense samples of the sphere; the nearest point of the balls within a plane, checked on a
dense grid of the plane; and frames without rows."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.fullbody.reach_balls import (nearest_in_balls, nearest_on_sphere_in_balls, sub_base_point,
                                                         sub_base_point_in_plane)


def _sphere_samples(n=20000):
    """Fibonacci points on the unit sphere (spacing about 0.025 rad)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


SAMPLES = _sphere_samples()
coords = st.floats(-1.0, 1.0)


@settings(deadline=None, max_examples=60)
@given(point=arrays(np.float64, 3, elements=coords), centre=arrays(np.float64, 3, elements=coords),
       radius=st.floats(0.3, 1.5), centres=arrays(np.float64, (3, 3), elements=coords),
       radii=arrays(np.float64, 3, elements=st.floats(0.3, 1.5)), active=arrays(bool, 3))
# A counterexample hypothesis found: the point 7e-161 from the sphere's centre, whose offset's squares are
# subnormal (the radial projection landed 2.6e-4 off the sphere).
@example(point=np.zeros(3), centre=np.full(3, 4.02661797e-161), radius=1.0, centres=np.zeros((3, 3)),
         radii=np.ones(3), active=np.zeros(3, dtype=bool))
def test_nearest_point_on_a_sphere_within_balls_beats_every_sample(point, centre, radius, centres, radii, active):
    _check_against_samples(point, centre, radius, centres, radii, active)


def test_a_corner_of_two_caps_is_found():
    """Two caps of the unit sphere that barely overlap, seen from straight above: the nearest point of the lens
    is its upper corner, where the sphere meets both ball boundaries."""
    a, b = np.radians(0.0), np.radians(50.0)
    centres = 1.2 * np.array([[np.cos(a), np.sin(a), 0.0], [np.cos(b), np.sin(b), 0.0], [0.0, 0.0, -3.0]])
    x = _check_against_samples(np.array([0.0, 0.0, 5.0]), np.zeros(3), 1.0, centres, np.array([0.6, 0.6, 1.0]),
                               np.array([True, True, False]))
    np.testing.assert_allclose(np.linalg.norm(x - centres[:2], axis=1), 0.6, rtol=1e-9)  # on both boundaries


def _check_against_samples(point, centre, radius, centres, radii, active):
    x, found = nearest_on_sphere_in_balls(point[None], centre[None], np.array([radius]), centres[None], radii[None],
                                          active[None])
    on_sphere = centre + radius * SAMPLES
    inside = np.all((np.linalg.norm(on_sphere[:, None] - centres, axis=-1) <= radii) | ~active, axis=1)
    if inside.any():
        assert found[0]
        best = np.min(np.linalg.norm(on_sphere[inside] - point, axis=1))
        assert np.linalg.norm(x[0] - point) <= best + 1e-9
    if found[0]:
        np.testing.assert_allclose(np.linalg.norm(x[0] - centre), radius, rtol=1e-9)
        assert np.all((np.linalg.norm(x[0] - centres, axis=1) <= radii * (1 + 1e-9)) | ~active)
    else:
        np.testing.assert_array_equal(x[0], point)
    return x[0]


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4])
def test_no_frames_give_no_rows(k):
    p, c, r, a = np.zeros((0, 3)), np.zeros((0, k, 3)), np.zeros((0, k)), np.zeros((0, k), dtype=bool)
    assert nearest_in_balls(p, c, r, a)[0].shape == (0, 3)
    assert nearest_on_sphere_in_balls(p, p, np.zeros(0), c, r, a)[0].shape == (0, 3)
    for variant in ("weighted", "priority", "fabrik"):
        assert sub_base_point(p, c, r, a, np.ones(k), variant)[0].shape == (0, 3)
        assert sub_base_point_in_plane(p, p, c, r, a, np.ones(k), variant)[0].shape == (0, 3)


def test_a_point_next_to_the_spheres_centre():
    """Every point of the sphere is about equally near a point 2e-12 off its centre: the answer is one of them,
    on the sphere and in the balls, not a point tilted off the sphere by rounding (hypothesis found this)."""
    centres = np.array([[0.625, 0.625, 0.625], [0.625, 0.625, 0.625], [0.625, 0.625, 0.625]])
    _check_against_samples(np.zeros(3), np.array([2.05703663e-12, 0.0, 0.0]), 1.0, centres,
                           np.array([1.5, 1.5, 1.5]), np.array([True, True, True]))


def _plane_grid(point, normal, half=3.0, n=601):
    """A square grid of the plane through `point` with unit `normal` (spacing 2 * half / (n - 1))."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a, b = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    return point + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v


@settings(deadline=None, max_examples=40)
@given(point=arrays(np.float64, 3, elements=coords), normal=arrays(np.float64, 3, elements=coords),
       centres=arrays(np.float64, (3, 3), elements=coords), radii=arrays(np.float64, 3, elements=st.floats(0.3, 1.5)),
       active=arrays(bool, 3), variant=st.sampled_from(["priority", "weighted", "fabrik"]))
def test_nearest_point_within_a_plane_beats_every_grid_point(point, normal, centres, radii, active, variant):
    """Where the plane meets every active ball and holds a point of all of them, the answer lies in the plane, in
    every ball, and no farther from the point than the nearest such grid point of the plane; where they have no
    common point in the plane, it still lies in the plane; where the plane misses a ball, meets says so."""
    if np.linalg.norm(normal) < 0.1:
        normal = np.array([0.0, 0.0, 1.0])
    normal = normal / np.linalg.norm(normal)
    x, feasible, meets = sub_base_point_in_plane(point[None], normal[None], centres[None], radii[None],
                                                 active[None], np.array([3.0, 2.0, 1.0]), variant)
    off = np.abs((centres - point) @ normal)
    assert meets[0] == bool(np.all((off <= radii) | ~active))
    assert abs((x[0] - point) @ normal) <= 1e-12
    grid = _plane_grid(point, normal)
    inside = np.all((np.linalg.norm(grid[:, None] - centres, axis=-1) <= radii) | ~active, axis=1)
    if inside.any():
        assert meets[0] and feasible[0]
        assert np.all((np.linalg.norm(x[0] - centres, axis=1) <= radii * (1 + 1e-9)) | ~active)
        assert np.linalg.norm(x[0] - point) <= np.min(np.linalg.norm(grid[inside] - point, axis=1)) + 1e-9


def test_a_plane_through_the_balls_centres_gives_the_3d_answer():
    """Balls centred in the plane, a point of the plane: the nearest point of their intersection lies in the plane
    already, so the plane changes nothing; a plane across that line gives a farther point off the 3-d one."""
    centres = np.array([[0.0, 0.0, 0.0], [1.2, 0.3, 0.0]])
    radii = np.array([1.0, 0.8])
    point = np.array([-0.5, 2.0, 0.0])
    on = np.ones((1, 2), dtype=bool)
    free, ok = nearest_in_balls(point[None], centres[None], radii[None], on)
    flat, flat_ok, meets = sub_base_point_in_plane(point[None], np.array([[0.0, 0.0, 1.0]]), centres[None],
                                                   radii[None], on, np.ones(2), "priority")
    assert ok[0] and flat_ok[0] and meets[0]
    np.testing.assert_allclose(flat, free, atol=1e-12)
    across, across_ok, _ = sub_base_point_in_plane(point[None], np.array([[1.0, 0.0, 0.0]]), centres[None],
                                                   radii[None], on, np.ones(2), "priority")
    assert across_ok[0] and across[0, 0] == pytest.approx(point[0], abs=1e-12)
    assert np.linalg.norm(across[0] - point) > np.linalg.norm(free[0] - point) + 1e-3
