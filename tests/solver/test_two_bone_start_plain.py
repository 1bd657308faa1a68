"""The two-bone warm start of a few chains (solver/two_bone_start_plain.py, plain floats) against the numpy path
(solver/two_bone_start.py) on the same batches: the same bits, also for batches where some chains must first
turn toward a far target and the others not, with poles on some rows, targets at the pivot or along the hinge
axis, and the same error where the numpy path raises one; a chain plain floats cannot take is left to numpy."""

import numpy as np
import pytest

from fullbody_adjust.solver import two_bone_start as tbs
from fullbody_adjust.solver.errors import SolverInputError


def _numpy_path(monkeypatch, *args):
    with monkeypatch.context() as m:
        m.setattr(tbs, "_FEW_CHAINS", 0)
        return tbs.two_bone_start(*args)


def _batch(rng, b, joints):
    """b random chains of `joints` joints, targets from within reach to far beyond, hinge axes, poles on some."""
    steps = rng.normal(size=(b, joints - 1, 3))
    steps *= rng.uniform(0.1, 0.4, (b, joints - 1, 1)) / np.linalg.norm(steps, axis=-1, keepdims=True)
    start = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1) + 0.05 * rng.normal(size=(b, 1, 3))
    reach = np.linalg.norm(steps, axis=-1).sum(axis=1)
    direction = rng.normal(size=(b, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    targets = start[:, 0] + direction * (reach * rng.uniform(0.2, 2.0, b))[:, None]
    axis = rng.normal(size=(b, 3))
    pole = np.where(rng.random((b, 1)) < 0.4, start[:, -2] + rng.normal(size=(b, 3)), np.nan)
    kind = rng.integers(0, 8)  # 4-7: no special case
    if kind == 1:  # a target at the two segments' pivot
        targets[0] = start[0, -3]
    elif kind == 2:  # the hinge axis along the line to the target: no bend plane
        axis[0] = targets[0] - start[0, -3]
    elif kind == 3:  # a target straight along the chain's first segment
        targets[0] = start[0, 0] + 3.0 * (start[0, 1] - start[0, 0])
    return start, targets, axis, pole


@pytest.mark.parametrize("joints", [3, 4])
def test_a_few_chains_get_the_bits_of_the_numpy_path(monkeypatch, joints):
    rng = np.random.default_rng(joints)
    turned_some = turned_all = raised = 0
    for trial in range(150):
        b = 1 + trial % tbs._FEW_CHAINS
        start, targets, axis, pole = _batch(rng, b, joints)
        pole = pole if trial % 3 else None
        try:
            expected = _numpy_path(monkeypatch, start, targets, axis, pole)
        except SolverInputError as ex:  # e.g. a target at the pivot: no direction to swing the segments to
            with pytest.raises(SolverInputError, match=str(ex)):
                tbs.two_bone_start(start, targets, axis, pole)
            raised += 1
            continue
        got = tbs.two_bone_start(start, targets, axis, pole)
        np.testing.assert_array_equal(got, expected, err_msg=f"trial {trial}")
        if joints == 4:  # how many rows the first step turned: it moves joint 1 off its start
            moved = np.any(expected[:, 1] != start[:, 1], axis=1)
            turned_some += bool(moved.any() and not moved.all())
            turned_all += bool(moved.all())
    assert 0 < raised < 30
    if joints == 4:  # both kinds of batch were seen: some rows turned, or all of them
        assert turned_some and turned_all


def test_a_chain_folded_onto_itself_is_left_to_the_numpy_path(monkeypatch):
    """An upper segment of zero length: plain floats would divide by zero where numpy gives NaN; the numpy path
    answers (with its NaNs), so the result is still its own."""
    start = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.3, 0.0]]])
    args = (start, np.array([[0.0, 0.0, 0.5]]), np.array([[1.0, 0.0, 0.0]]))
    with np.errstate(invalid="ignore", divide="ignore"):
        assert tbs.two_bone_start_plain.two_bone_start(*args) is None
        np.testing.assert_array_equal(tbs.two_bone_start(*args), _numpy_path(monkeypatch, *args))
