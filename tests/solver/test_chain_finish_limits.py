"""The chain solver's two-segment finish checks a few chains' limits in plain floats first, on each chain's first
candidate clear of the boxes (solver/chain/finish.py, _first_clear_holds): chain solves with joint limits, with and
without boxes in the way, give the very same positions, iterations and statuses as when every candidate is checked
on arrays."""

import numpy as np
import pytest

from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.chain.limited import ChainLimits
from fullbody_adjust.solver.maths import lanes

from .test_obstacle_response import _problems


def _near_full_stretch(seed, count=40):
    """The same chains and limits, with a cone at joint 0, toward targets near the full stretch (where the finish
    acts), without boxes."""
    rng = np.random.default_rng(1000 + seed)
    for starts, targets, limits, parents, _ in _problems(seed, count):
        reach = np.linalg.norm(np.diff(starts, axis=1), axis=2).sum(axis=1)
        stretched = targets / np.linalg.norm(targets, axis=1)[:, None] * (reach * rng.uniform(0.85, 0.99))[:, None]
        yield starts, stretched, limits.with_cone(0, 1.2), parents, None


def _solve(problem):
    starts, targets, limits, parents, boxes = problem
    return solve_chain_batch(starts, targets, limits=limits, parent_directions=parents, obstacles=boxes)


@pytest.mark.parametrize("seed", range(2))
@pytest.mark.parametrize("problems", [_problems, _near_full_stretch])
def test_the_first_clear_candidate_checked_alone_gives_what_checking_every_candidate_gives(problems, seed,
                                                                                          monkeypatch):
    holds = ChainLimits.finish_holds
    answers = []

    def counted(self, rows, *args):
        out = holds(self, rows, *args)
        if rows.__class__ is int:  # one chain's first clear candidate
            answers.append(out)
        return out

    for problem in problems(seed):
        monkeypatch.setattr(ChainLimits, "finish_holds", counted)
        first = _solve(problem)
        monkeypatch.setattr(lanes, "FEW", 0)  # every candidate checked on arrays
        every = _solve(problem)
        monkeypatch.undo()
        np.testing.assert_array_equal(first.positions, every.positions)
        np.testing.assert_array_equal(first.iterations, every.iterations)
        assert list(first.status) == list(every.status) and list(first.reason) == list(every.reason)
    # Both ways were taken: candidates that hold, and chains whose every candidate numpy checked.
    assert answers.count(True) >= 10 and answers.count(False) >= 10
