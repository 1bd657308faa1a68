"""feet.refit_step: refitting the held feet to the solved pose (a sole skinned partly to the shin) lands where the
targets and the feet they shape agree, on a model of that agreement a test can solve exactly."""

import numpy as np

from fullbody_adjust.solver.retarget import motion as rt
from fullbody_adjust.solver.retarget.feet import raised_offsets, refit_step, resting_offsets


def _refits(wanted, start, accelerate, count=2):
    """Targets after ``count`` refits (each solve gives the pose the last targets ask for; ``wanted(targets)`` the
    targets that pose's feet want), as bridge/retarget/run.py calls plan.refit_feet."""
    asked, before = start, None
    for _ in range(count):
        moved = wanted(asked) - asked
        asked, before = asked + (moved if before is None or not accelerate else refit_step(moved, before, 1e-9)), \
            moved
    return asked


def test_two_refits_land_where_a_steady_series_ends():
    rng = np.random.default_rng(5)
    agreed = rng.normal(0.0, 0.05, (40, 4, 3))
    start = agreed + rng.normal(0.0, 0.01, agreed.shape)
    for ratio in (-0.67, -0.3, 0.2, 0.45):  # how far each refit moves a target, of the one before
        def wanted(asked, ratio=ratio):
            return agreed + ratio * (asked - agreed)
        plain = _refits(wanted, start, accelerate=False)
        fast = _refits(wanted, start, accelerate=True)
        assert np.abs(fast - agreed).max() < 1e-12
        assert np.abs(plain - agreed).max() > 1e-5  # plain refits stop short by ratio^2 of the first gap


def test_a_refit_that_grows_is_taken_as_it_is():
    moved, before = np.array([4.0, -3.0, 1e-3, 2.0]), np.array([1.0, 1.0, 1e-12, -2.0])
    # growing (4), flipping and growing (-3), a first move too small to tell (1e-12), flipping as much (-1: -0.95 is
    # the last taken): each moved by the plain refit
    np.testing.assert_array_equal(refit_step(moved, before, 1e-9), moved)
    np.testing.assert_allclose(refit_step(np.array([1.0]), np.array([2.0]), 1e-9), [2.0])  # ratio 0.5: twice


def test_a_climb_stands_the_targets_soles_where_the_scaled_sources_are():
    """feet.raised_offsets: neither source foot comes down to the floor (a climb): the body moves so that each
    target sole stands where the source's, scaled about the floor, does on the frames it is lowest, whatever the
    target's foot below its ankle."""
    frames, floor, ratio = 40, 0.1, 0.45
    rng = np.random.default_rng(2)
    source_soles = floor + 0.8 + 0.3 * np.abs(rng.normal(size=(frames, 2)))  # on bars 0.8 m and more up
    s_points = {}
    for i, e in enumerate(rt.FEET):  # the ankle 8 cm above the sole, then two sole points (the lowest first)
        s_points[e] = np.zeros((frames, 3, 3))
        s_points[e][:, :, 2] = source_soles[:, [i]] + [0.08, 0.0, 0.02]
    s_points.update({e: np.zeros((frames, 2, 3)) for e in ("hand.L", "hand.R")})
    soles = np.full((frames, 2), 0.25)  # a big foot: its ankle 0.25 above its sole
    ankles = floor + ratio * (source_soles - floor) + 0.03  # scaled with the legs: the scaled source's 3 cm foot
    settings = rt.RetargetSettings()
    assert resting_offsets(ankles, s_points, soles, floor, 0.9, settings) == {}  # no foot comes down
    offsets = raised_offsets(ankles, s_points, soles, floor, ratio)
    np.testing.assert_allclose([offsets[0], offsets[1]], [0.25 - 0.03, 0.25 - 0.03], atol=1e-12)
