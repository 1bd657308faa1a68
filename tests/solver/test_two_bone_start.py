"""The two-bone warm start of one chain (plain floats) against the same chain as a row of a batch (numpy): equal
within 1e-9, on random chains with and without segments before the two (a clavicle), reachable and unreachable
targets, and poles."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.errors import SolverInputError
from fullbody_adjust.solver.two_bone_start import two_bone_start

from .strategies import chains, coords, unit_vectors


def _batch_row(start, target, axis, pole):
    """The chain solved as row 0 of a batch of two (the batch path), the second row a copy of the first."""
    twice = lambda a: None if a is None else np.repeat(a[None], 2, axis=0)
    return two_bone_start(twice(start), twice(target), twice(axis), twice(pole))[0]


@settings(max_examples=300, deadline=None)
@given(chains(min_joints=3, max_joints=5), arrays(np.float64, 3, elements=coords), unit_vectors(),
       st.one_of(st.none(), st.just("nan"), arrays(np.float64, 3, elements=coords)))
def test_one_chain_equals_its_row_of_a_batch(start, target, axis, pole):
    if isinstance(pole, str):
        pole = np.full(3, np.nan)
    one, row = _outcome(lambda: two_bone_start(start[None], target[None], axis[None],
                                               None if pole is None else pole[None])[0]), \
        _outcome(lambda: _batch_row(start, target, axis, pole))
    if isinstance(row, str) or isinstance(one, str):  # a degenerate chain (e.g. the target on the pivot)
        assert one == row
    else:
        np.testing.assert_allclose(one, row, atol=1e-9, rtol=0)


def _outcome(solve):
    """The result, or the SolverInputError's message."""
    try:
        return solve()
    except SolverInputError as ex:
        return str(ex)


def test_the_one_chain_path_moves_the_end_onto_a_reachable_target():
    """An arm (clavicle, upper arm, forearm) with its target 0.8 of the two segments away: the end lands on it,
    the segments keep their lengths, and it bends to the positive side of the hinge axis."""
    start = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0], [0.8, 0.0, 0.0]])
    target = np.array([0.2 + 0.48 * np.cos(0.3), 0.48 * np.sin(0.3), 0.0])
    axis = np.array([0.0, 0.0, 1.0])
    out = two_bone_start(start[None], target[None], axis[None])[0]
    np.testing.assert_allclose(out[-1], target, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=0), axis=1), [0.2, 0.3, 0.3], atol=1e-12)
    upper, lower = out[2] - out[1], out[3] - out[2]
    assert np.cross(upper, lower) @ axis > 0.0
