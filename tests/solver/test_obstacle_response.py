"""The obstacle response's shortcut (solver/obstacles/response.py): a joint inside a box takes the first clear point of
the paper's circle without the sphere's samples being tested. Chain solves with boxes across the chains' way, with
and without joint limits, give the very same results as when every candidate is tested."""

import numpy as np
import pytest

from fullbody_adjust.solver import Boxes
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.limits.joint_limits import JointLimits
from fullbody_adjust.solver.obstacles import response as chain_obstacles
from fullbody_adjust.solver.maths.geometry import any_perpendicular


def _problems(seed, count=40):
    """Batches of 1-3 chains (3-5 joints, a cone or a hinge at some joints) toward reachable targets, with one or two
    boxes on the way: on a joint of the start chain, or between the chain and its target."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(3, 6))
        b = int(rng.integers(1, 4))
        lengths = rng.uniform(0.3, 1.0, n - 1)
        parent = rng.normal(size=3)
        parent /= np.linalg.norm(parent)
        starts, targets = [], []
        for _ in range(b):
            d = parent + 0.6 * rng.normal(size=(n - 1, 3))
            d /= np.linalg.norm(d, axis=1)[:, None]
            start = np.concatenate([np.zeros((1, 3)), np.cumsum(d * lengths[:, None], axis=0)])
            starts.append(start)
            direction = rng.normal(size=3)
            targets.append(direction / np.linalg.norm(direction) * rng.uniform(0.3, 0.8) * lengths.sum())
        starts, targets = np.array(starts), np.array(targets)
        limits = JointLimits.free(n)
        for i in range(n - 1):
            kind = rng.choice(["free", "cone", "hinge"])
            if kind == "cone":
                limits = limits.with_cone(i, float(rng.uniform(0.4, 2.5)))
            elif kind == "hinge" and i > 0:
                axis = any_perpendicular(starts[0, i] - starts[0, i - 1])
                limits = limits.with_hinge(i, axis, -0.2, 2.6, float(rng.choice([0.0, 0.4])))
        centres = [starts[0, int(rng.integers(1, n))], 0.5 * (starts[0, -1] + targets[0])]
        size = rng.uniform(0.1, 0.5, (len(centres), 3)) * lengths.mean()
        boxes = Boxes(np.array(centres) - size, np.array(centres) + size)
        parents = np.broadcast_to(parent, (b, 3)).copy()
        yield starts, targets, limits, parents, boxes


def _solve(problem):
    starts, targets, limits, parents, boxes = problem
    return solve_chain_batch(starts, targets, limits=limits, parent_directions=parents, obstacles=boxes)


@pytest.mark.parametrize("seed", range(2))
def test_the_circle_first_gives_what_testing_every_candidate_gives(seed, monkeypatch):
    scored = chain_obstacles.ObstacleResponse._scored
    circles = []

    def counted(self, h, anchors, lengths, dirs, *rest):
        out = scored(self, h, anchors, lengths, dirs, *rest)
        if dirs.shape[1] == chain_obstacles._CIRCLE_SAMPLES:
            circles.append(bool((out[1] == 0).any(axis=1).all()))
        return out

    def circle_never_clear(self, h, anchors, lengths, dirs, *rest):
        pts, score = scored(self, h, anchors, lengths, dirs, *rest)
        return pts, score + (dirs.shape[1] == chain_obstacles._CIRCLE_SAMPLES)  # every candidate is tested

    for problem in _problems(seed):
        monkeypatch.setattr(chain_obstacles.ObstacleResponse, "_scored", counted)
        fast = _solve(problem)
        monkeypatch.setattr(chain_obstacles.ObstacleResponse, "_scored", circle_never_clear)
        every = _solve(problem)
        np.testing.assert_array_equal(fast.positions, every.positions)
        np.testing.assert_array_equal(fast.iterations, every.iterations)
        assert list(fast.status) == list(every.status) and list(fast.reason) == list(every.reason)
    assert sum(circles) >= 10  # the shortcut was taken
