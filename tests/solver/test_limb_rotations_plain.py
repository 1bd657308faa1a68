"""The segment rotations of a few solved chains (solver/limb_rotations_plain.py, plain floats) against the numpy
path (solver/limb_rotations.py): the same bits for chains with hinges (one, or two in a row), cones and free
joints, also for segments that do not turn, turn right round, or fold onto their parent; the same error where the
numpy path raises one."""

import numpy as np
import pytest

from fullbody_adjust.solver import limb_rotations as lr
from fullbody_adjust.solver.errors import SolverInputError
from fullbody_adjust.solver.limits import CONE, FREE, HINGE


def _numpy_path(monkeypatch, *args):
    with monkeypatch.context() as m:
        m.setattr(lr, "_FEW_CHAINS", 0)
        return lr._segment_rotations(*args)


def _chains(rng, b, n):
    start = np.cumsum(rng.normal(size=(b, n, 3)) * 0.3, axis=1)
    joints = start + rng.normal(size=(b, n, 3)) * rng.choice([0.0, 0.05, 0.5], size=(b, 1, 1))
    special = rng.integers(0, 6)
    if special == 1:  # a segment turned right round
        joints[0, 2] = joints[0, 1] - (start[0, 2] - start[0, 1])
    elif special == 2:  # a child along its parent: no bend plane
        joints[0, 2] = joints[0, 1] + 0.7 * (joints[0, 1] - joints[0, 0])
    elif special == 3:  # a hinge axis along the parent segment
        pass
    return start, joints, special


@pytest.mark.parametrize("kind", [(CONE, HINGE, CONE), (FREE, HINGE, HINGE), (HINGE, CONE, HINGE), (CONE, CONE, CONE)])
def test_a_few_chains_get_the_bits_of_the_numpy_path(monkeypatch, kind):
    rng = np.random.default_rng(sum(kind))
    kind = np.array(kind)
    for trial in range(120):
        b = 1 + trial % lr._FEW_CHAINS
        start, joints, special = _chains(rng, b, len(kind) + 1)
        axes = rng.normal(size=(b, len(kind), 3))
        if special == 3:
            axes[0, 1] = start[0, 1] - start[0, 0]
        for k, ax in ((None, None), (kind, axes)):
            expected = _numpy_path(monkeypatch, start, joints, k, ax)
            got = lr._segment_rotations(start, joints, k, ax)
            np.testing.assert_array_equal(got, expected, err_msg=f"trial {trial}, kinds {k}")


def test_the_same_error_as_the_numpy_path(monkeypatch):
    """A solved segment of zero length has no direction to swing to: both paths say so."""
    start = np.array([[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.6, 0.0, 0.0]]])
    joints = np.array([[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.0, 0.0]]])
    with pytest.raises(SolverInputError) as numpy_error:
        _numpy_path(monkeypatch, start, joints, None, None)
    with pytest.raises(SolverInputError, match=str(numpy_error.value)):
        lr._segment_rotations(start, joints, None, None)
