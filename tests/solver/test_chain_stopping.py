"""When a chain's iterations stop (chain/iteration.py, constants in chain/settings.py): a problem whose best iterate
no longer improves by a share of its residual within _PATIENCE iterations stops there and keeps its best iterate,
one problem alone and among many alike.

The problem below was captured from bench/fuzz.py (batch [0, 306], frame 7: the left leg, its target on its own
foot, a hip cone and a twisting knee hinge the start breaks, a box beside it): its iterations swing between two
poses (residuals about 15.3 and 32.6) while the better one creeps toward its limit by less and less; the rule it
replaced (an improvement of tolerance * 1e-3 per _PATIENCE iterations) kept it iterating 155 times."""

import numpy as np
import pytest

from fullbody_adjust.solver import Boxes, ChainSettings
from fullbody_adjust.solver.chain import iteration
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.chain.settings import _GAIN, _PROGRESS, _WINDOW
from fullbody_adjust.solver.limits.joint_limits import JointLimits
from fullbody_adjust.solver.maths import lanes
from .one_chain import solve_chain

START = np.array([[38.63869699335494, 3.4648431005482125, 2.5877773547321246],
                  [55.18217088616812, 2.7605199189401683, 11.035677368765075],
                  [69.38574197569031, -1.7643160382167484, 16.09398103192777]])
TARGET = np.array([69.38574197569031, -1.7643160382167482, 16.09398103192777])
PARENT = np.array([-0.8675446403608493, -0.006098371662383221, -0.49732193481107595])
LIMITS = JointLimits(kind=np.array([1, 2]), cone_angle=np.array([2.007128639793479, np.pi]),
                     hinge_axis=np.array([[0.0, 0.0, 1.0], [0.3701845695139709, -0.7458773836491773,
                                                            -0.5537420997670431]]),
                     hinge_min=np.array([-np.pi, -0.2]), hinge_max=np.array([np.pi, 2.85]),
                     hinge_twist=np.array([0.0, 0.7853981633974483]),
                     hinge_reference=np.array([[-17.234619891244986, -4.821902842896362, -5.026603665638494]] * 2))
BOX = Boxes(np.array([[47.08939991720151, -8.002386632630904, -9.052803607861403]]),
            np.array([[48.31518066967785, -2.2478704354141277, -7.631314524963334]]))
SETTINGS = ChainSettings()


def _solve():
    return solve_chain(START, TARGET, settings=SETTINGS, limits=LIMITS, obstacles=BOX, parent_direction=PARENT)


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def test_a_creeping_limited_chain_stops_and_keeps_its_best_iterate(monkeypatch):
    result = _solve()
    # Without the window rule (patience as long as the cap) the same problem creeps on.
    monkeypatch.setattr(iteration, "_PATIENCE", SETTINGS.max_iterations)
    monkeypatch.setattr(iteration, "_WINDOW", SETTINGS.max_iterations + 1)
    creeping = _solve()
    monkeypatch.undo()
    assert creeping.status == result.status == "limited"
    assert creeping.iterations > SETTINGS.max_iterations // 2 >= result.iterations
    # Its last window cut the residual by less than _PROGRESS of it, so little is left to gain by going on.
    assert creeping.residual <= result.residual <= creeping.residual * (1.0 + _PROGRESS)
    assert result.residual == pytest.approx(np.linalg.norm(result.positions[-1] - TARGET), rel=1e-12)
    # The pose returned is the best the iterations saw: an iteration from it does not find a better one.
    again = solve_chain(result.positions, TARGET, settings=ChainSettings(max_iterations=1), limits=LIMITS,
                        obstacles=BOX, parent_direction=PARENT)
    assert again.residual >= result.residual
    np.testing.assert_allclose(np.linalg.norm(np.diff(result.positions, axis=0), axis=1),
                               np.linalg.norm(np.diff(START, axis=0), axis=1), rtol=1e-12)


@pytest.mark.parametrize("others", [0, 2 * lanes.FEW])
def test_the_stopping_rule_gives_one_problem_the_bits_of_its_row_among_many(others):
    """The problem alone (on its floats) and as row 0 of a batch with `others` jittered copies (on arrays beyond
    lanes.FEW problems): the same iterations and bits."""
    rng = np.random.default_rng(5)
    starts = np.concatenate([START[None], START[None] + rng.normal(size=(others, 3, 3)) * 1e-3])
    targets = np.concatenate([TARGET[None], TARGET[None] + rng.normal(size=(others, 3)) * 1e-3])
    batch = solve_chain_batch(starts, targets, settings=SETTINGS, limits=LIMITS, obstacles=BOX,
                              parent_directions=np.tile(PARENT, (others + 1, 1)))
    alone = _solve()
    assert (batch.iterations[0], batch.status[0]) == (alone.iterations, alone.status)
    np.testing.assert_array_equal(_bits(batch.positions[0]), _bits(alone.positions))
    np.testing.assert_array_equal(_bits(batch.residual[0]), _bits(alone.residual))
    # Every copy stops by the rule, none at the cap (a copy's start is off its target: plain FABRIK's pose gives it
    # a second start, whose iterations its count includes).
    assert all("stalled after" in why for why in batch.reason), batch.reason


def test_a_chain_that_still_improves_is_not_stopped():
    """A limited chain converging to its target reaches it: the window rule stops only creeping."""
    start = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.55, 0.0, -0.05]])
    limits = JointLimits.free(3).with_cone(0, 1.2).with_cone(1, 2.4)
    target = np.array([0.2, 0.25, 0.2])
    result = solve_chain(start, target, limits=limits, parent_direction=[1.0, 0.0, 0.0])
    assert result.status == "reached" and result.residual <= SETTINGS.tolerance


# The right arm (upper arm, forearm, hand) of bench/interactive.py's drag on the generated Rigify rig (step 166 of
# 300, the third solve of its limb passes): its start meets the target but breaks a limit beside the drag's box; at
# the edge of its limited reach it crept from 0.96 to 0.49 mm in 200 iterations, some 0.1-0.7 % an iteration.
ARM_START = np.array([[-0.11656320668593381, -0.2544916393090557, 1.4953818953308937],
                      [-0.31822894091212084, -0.24797606751311155, 1.5044227013098357],
                      [-0.36898731489661973, -0.522273010625671, 1.5780618809738975],
                      [-0.39240676164627075, -0.7763283848762512, 1.6412274837493896]])
ARM_TARGET = np.array([-0.39240676164627075, -0.7763283848762512, 1.6412274837493896])
ARM_PARENT = np.array([-0.8520726628621027, 0.5165124498271864, -0.08477656737922083])
ARM_LIMITS = JointLimits(kind=np.array([1, 1, 2]),
                         cone_angle=np.array([0.5235987755982988, 2.356194490192345, 3.141592653589793]),
                         hinge_axis=np.array([[-0.2756759520559276, -0.5184204400137056, 0.8094708251901694],
                                              [0.0, 0.0, 1.0],
                                              [-0.5102587045508997, -0.21371605439970132, 0.833043517783952]]),
                         hinge_min=np.array([-3.141592653589793, -3.141592653589793, -0.2]),
                         hinge_max=np.array([3.141592653589793, 3.141592653589793, 2.7]),
                         hinge_twist=np.array([0.0, 0.0, 1.3962634015954636]),
                         hinge_reference=np.array([[-0.1769999824464321, 0.09510000422596931, -0.0205000638961792],
                                                   [-0.1769999824464321, 0.09510000422596931, -0.0205000638961792],
                                                   [-0.2471001148223877, 0.06180034205317497, -0.13549983501434326]]))
ARM_BOX = Boxes(np.array([[-0.4793979749083519, -0.20776476711034775, 1.53265330940485]]),
                np.array([[-0.3664001598954201, -0.09476695209741592, 1.6456511244177818]]))


def _arm(starts=ARM_START[None], targets=ARM_TARGET[None]):
    return solve_chain_batch(starts, targets, settings=SETTINGS, limits=ARM_LIMITS, obstacles=ARM_BOX,
                             parent_directions=np.tile(ARM_PARENT, (len(starts), 1)))


def test_a_limited_arm_creeping_at_its_reach_stops_after_a_window(monkeypatch):
    """Its best residual shrinks over each window, but at that rate it would still miss the tolerance at the cap:
    it stops after the first window that shows so (not after 200 iterations), with its best iterate."""
    result = _arm()[0]
    monkeypatch.setattr(iteration, "_WINDOW", SETTINGS.max_iterations + 1)
    creeping = _arm()[0]
    monkeypatch.undo()
    assert creeping.iterations == SETTINGS.max_iterations and creeping.status == "limited"
    assert creeping.residual > SETTINGS.tolerance  # the cap did not reach the target: stopping early lost no hit
    assert result.status == "limited" and "stalled after" in result.reason
    assert result.iterations <= 2 * _WINDOW
    # What the window measured (from the first iterate, or the window before): its best residual shrank, and that
    # rate kept over the iterations left misses the tolerance and gains less than _GAIN of the residual.
    first = solve_chain(ARM_START, ARM_TARGET, limits=ARM_LIMITS, obstacles=ARM_BOX, parent_direction=ARM_PARENT,
                        settings=ChainSettings(max_iterations=max(1, result.iterations - _WINDOW)))
    rate = result.residual / first.residual
    assert rate < 1.0
    projected = result.residual * rate ** -(-(SETTINGS.max_iterations - result.iterations) // _WINDOW)
    assert projected > max(SETTINGS.tolerance, (1.0 - _GAIN) * result.residual)
    # What the creep to the cap gained instead (0.89 -> 0.49 mm measured).
    assert creeping.residual < result.residual < 2.0 * creeping.residual
    np.testing.assert_allclose(np.linalg.norm(np.diff(result.positions, axis=0), axis=1),
                               np.linalg.norm(np.diff(ARM_START, axis=0), axis=1), rtol=1e-12)


def test_the_window_rule_gives_one_arm_the_bits_of_its_row_among_many():
    rng = np.random.default_rng(11)
    others = 2 * lanes.FEW
    starts = np.concatenate([ARM_START[None], ARM_START[None] + rng.normal(size=(others, 4, 3)) * 1e-4])
    targets = np.concatenate([ARM_TARGET[None], ARM_TARGET[None] + rng.normal(size=(others, 3)) * 1e-4])
    batch, alone = _arm(starts, targets), _arm()
    assert (batch.iterations[0], batch.status[0]) == (alone.iterations[0], alone.status[0])
    np.testing.assert_array_equal(_bits(batch.positions[0]), _bits(alone.positions[0]))
    np.testing.assert_array_equal(_bits(batch.residual[0]), _bits(alone.residual[0]))
