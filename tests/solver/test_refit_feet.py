"""plan._secant_step: refitting the held feet to the solved pose (a sole skinned partly to the shin) lands where the
targets and the feet they shape agree, on a model of that agreement a test can solve exactly."""

import numpy as np

from fullbody_adjust.solver.retarget.plan import _secant_step


def _refits(wanted, start, accelerate, count=2):
    """Targets after ``count`` refits (each solve gives the pose the last targets ask for; ``wanted(targets)`` the
    targets that pose's feet want), as bridge/retarget/run.py calls plan.refit_feet."""
    asked, before = start, None
    for _ in range(count):
        moved = wanted(asked) - asked
        asked, before = asked + (moved if before is None or not accelerate else _secant_step(moved, before, 1e-9)), \
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
    np.testing.assert_array_equal(_secant_step(moved, before, 1e-9), moved)
    np.testing.assert_allclose(_secant_step(np.array([1.0]), np.array([2.0]), 1e-9), [2.0])  # ratio 0.5: twice
