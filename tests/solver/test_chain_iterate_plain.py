"""A few limited or obstructed chains iterate in plain floats (solver/chain/iterate_plain.py): chain solves and
whole-body solves give the very same positions, iterations, residuals and statuses as numpy's iterations."""

import numpy as np
import pytest

from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.body.model import default_limits
from fullbody_adjust.solver.chain.iterate_plain import PlainIterations
from fullbody_adjust.solver.chain.model import ChainModel
from fullbody_adjust.solver.obstacles.response import ObstacleResponse
from fullbody_adjust.solver.chain.settings import ChainSettings
from fullbody_adjust.solver.limits.joint_limits import JointLimits
from fullbody_adjust.solver.obstacles.boxes import Boxes
from fullbody_adjust.solver.limits.rig_limits import rig_limits

from .test_adjust import EFFECTORS
from .test_obstacle_response import _problems
from .test_rig_limits import bone_axes, pulled, spec, synthetic_humanoid


def _chain_problems(seed, count=60):
    """Batches of 1-3 chains (3-5 joints, cones and hinges, twist or none) without boxes, toward targets within
    reach, near full stretch (where the two-segment finish acts) and beyond reach of what the limits allow."""
    rng = np.random.default_rng(2000 + seed)
    for k, (starts, targets, limits, parents, _boxes) in enumerate(_problems(seed, count)):
        reach = np.linalg.norm(np.diff(starts, axis=1), axis=2).sum(axis=1)
        scale = [rng.uniform(0.2, 0.8), rng.uniform(0.85, 0.99), rng.uniform(0.95, 1.0)][k % 3]
        targets = targets / np.linalg.norm(targets, axis=1)[:, None] * (reach * scale)[:, None]
        if k % 4 == 0:
            limits = limits.with_cone(0, float(rng.uniform(0.3, 1.2)))
        yield starts, targets, limits, parents


def _both_ways(solve, monkeypatch, calls):
    plain_iterate = PlainIterations._iterate_plain

    def counted(self, *args):
        out = plain_iterate(self, *args)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(PlainIterations, "_iterate_plain", counted)
    plain = solve()
    monkeypatch.setattr(PlainIterations, "_iterate_plain", lambda self, *args: None)
    numpy = solve()
    monkeypatch.undo()
    return plain, numpy


@pytest.mark.parametrize("seed", range(3))
def test_chain_solves_iterate_the_same_in_plain_floats(seed, monkeypatch):
    calls, iterations = [], []
    for starts, targets, limits, parents in _chain_problems(seed):
        plain, numpy = _both_ways(lambda: solve_chain_batch(starts, targets, limits=limits,
                                                            parent_directions=parents), monkeypatch, calls)
        np.testing.assert_array_equal(plain.positions, numpy.positions)
        np.testing.assert_array_equal(plain.iterations, numpy.iterations)
        np.testing.assert_array_equal(plain.residual, numpy.residual)
        assert list(plain.status) == list(numpy.status) and list(plain.reason) == list(numpy.reason)
        iterations.extend(numpy.iterations.tolist())
    # The plain path ran, on chains that iterate long (limits holding them short) as well as briefly.
    assert calls.count(True) >= 20 and max(iterations) >= 20 and min(iterations) <= 2


@pytest.mark.parametrize("seed", [1, 5])  # among them: an iterate with fewer penetrations and a larger residual
def test_chains_among_boxes_iterate_the_same_in_plain_floats(seed, monkeypatch):
    """Chains with one or two boxes on the way, with their limits and without, toward targets within reach, near
    their base, beyond reach and inside a box: the joints the boxes move are moved by the same response, a stalled
    chain the boxes pushed is not nudged, and the best iterate (fewest penetrations, then the nearest), its
    penetrations and the notes are the same."""
    calls, responses = [], []
    avoid = ObstacleResponse.avoid

    def counted_avoid(self, *args):
        out = avoid(self, *args)
        responses.append(bool(out[1].any()))
        return out

    for starts, targets, limits, parents, boxes in _problems(seed, 40):
        # Also a box around every target, which the last joint and segment ignore.
        held = Boxes(np.concatenate([boxes.mins, targets - 0.1]), np.concatenate([boxes.maxs, targets + 0.1]))
        for scale, limited, obstacles in ((1.0, True, boxes), (1.0, False, boxes), (1.6, True, boxes),
                                          (0.5, True, boxes), (1.0, True, held)):
            kwargs = {"limits": limits, "parent_directions": parents} if limited else {}
            monkeypatch.setattr(ObstacleResponse, "avoid", counted_avoid)

            def solve(goals=targets * scale, obstacles=obstacles, kwargs=kwargs):
                return solve_chain_batch(starts, goals, obstacles=obstacles, **kwargs)

            plain, numpy = _both_ways(solve, monkeypatch, calls)
            np.testing.assert_array_equal(plain.positions, numpy.positions)
            np.testing.assert_array_equal(plain.iterations, numpy.iterations)
            np.testing.assert_array_equal(plain.residual, numpy.residual)
            assert list(plain.status) == list(numpy.status) and list(plain.reason) == list(numpy.reason)
    # The plain path ran, and the boxes made it respond.
    assert calls.count(True) >= 100 and responses.count(True) >= 50


def test_the_plain_two_segment_finish_picks_what_numpys_picks():
    """TwoBoneFinish._two_bone_finish_one against _two_bone_finish on the same chain: random chains among boxes (some
    with a box around the base), with forward-pass joints moved off the chain, targets within the last two segments'
    range, just inside and just outside its ends (where the finish declines), and a middle joint on the pivot-target
    line (no swivel direction: any perpendicular). Where it answers, the same finish, middle and end joints, bit for
    bit."""
    rng = np.random.default_rng(11)
    answers = []
    for k, (starts, targets, limits, parents, boxes) in enumerate(_problems(3, 60)):
        if k % 2:  # a box around the base (at the origin), which the base's segment ignores
            boxes = Boxes(np.concatenate([boxes.mins, [[-0.05] * 3]]), np.concatenate([boxes.maxs, [[0.05] * 3]]))
        model = ChainModel(starts, targets, ChainSettings(), limits, boxes, parents)
        if not model._finishes:
            continue
        j = model.n - 3
        for r in range(model.B):
            a, c = model.lengths[r, j], model.lengths[r, j + 1]
            pivot = starts[r, j]
            for case in range(5):
                P = starts[r] + rng.normal(scale=0.05, size=starts[r].shape)
                aims = starts[r] + rng.normal(scale=0.2, size=starts[r].shape)
                P[j] = pivot
                direction = rng.normal(size=3)
                direction /= np.linalg.norm(direction)
                reach = [rng.uniform(abs(a - c), a + c), (a + c) * (1 - 5e-10), (a + c) * (1 - 2e-9),
                         abs(a - c) * (1 + 5e-10), rng.uniform(abs(a - c), a + c)][case]
                model.targets[r] = pivot + direction * reach
                if case == 4:
                    aims[j + 1] = pivot + direction * 0.3 * reach
                plain = model._two_bone_finish_one(r, P.tolist(), aims.tolist())
                done, middle, end = model._two_bone_finish(P[None], np.array([r]), aims[None])
                if plain is None:
                    answers.append("numpy")
                    continue
                assert plain[0] == bool(done[0]), (case, plain, done)
                if plain[0]:
                    np.testing.assert_array_equal(plain[1], middle[0])
                    np.testing.assert_array_equal(plain[2], end[0])
                answers.append(("declined", "finished")[plain[0]])
    assert answers.count("finished") >= 20 and answers.count("declined") >= 20


def test_body_solves_with_a_rigs_locks_iterate_the_same_in_plain_floats(monkeypatch):
    """The elbow locked, so the arm is held short of most goals and the limit passes run: every result field of
    the whole-body solve is the same as with numpy's iterations, frame by frame (one frame at a time, as clicks
    solve, and the frames as one batch)."""
    model, h0, t0 = synthetic_humanoid()
    a0 = bone_axes(model, h0, t0)
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    calls = []
    for frames in [[f] for f in range(len(targets))] + [list(range(len(targets)))]:
        h, t, x = heads[frames], tails[frames], axes[frames]
        limits = rig_limits(default_limits(model, h, t, bone_x_axes=x[..., 0]), model, h, t, x,
                            spec(model, a0, "forearm.L", locked=(True, False, True)))

        def solve(h=h, t=t, goals=targets[frames], limits=limits):
            return adjust_frames(model, h, t, goals, EFFECTORS, limits=limits)
        plain, numpy = _both_ways(solve, monkeypatch, calls)
        for field in ("heads", "tails", "rotations", "residuals", "iterations", "sc_displacement",
                      "root_displacement"):
            np.testing.assert_array_equal(getattr(plain, field), getattr(numpy, field), err_msg=field)
        assert plain.status.tolist() == numpy.status.tolist() and plain.reasons.tolist() == numpy.reasons.tolist()
    assert calls.count(True) >= len(targets)


def test_straight_chains_nudged_off_their_line_iterate_the_same_in_plain_floats(monkeypatch):
    """Straight chains whose targets lie on their own line, short of the last two segments' range: FABRIK stalls
    there and pushes the joints sideways (the nudge), here as numpy does."""
    nudged_one = PlainIterations._nudged_one
    nudges, calls = [], []

    def counted(self, *args):
        nudges.append(args)
        return nudged_one(self, *args)

    rng = np.random.default_rng(7)
    for _ in range(30):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        lengths = rng.uniform(0.3, 1.0, 4)
        starts = np.concatenate([np.zeros((1, 3)), np.cumsum(d[None] * lengths[:, None], axis=0)])[None]
        targets = (d * lengths.sum() * 0.2)[None]
        limits = JointLimits.free(5).with_cone(0, 2.5)
        monkeypatch.setattr(PlainIterations, "_nudged_one", counted)
        plain, numpy = _both_ways(lambda: solve_chain_batch(starts, targets, limits=limits, parent_directions=d[None]),
                                  monkeypatch, calls)
        np.testing.assert_array_equal(plain.positions, numpy.positions)
        np.testing.assert_array_equal(plain.iterations, numpy.iterations)
        assert list(plain.status) == list(numpy.status)
    assert len(nudges) >= 2 and all(calls)
