"""Every calculation written once on components (solver/maths/lanes.py): F frames solved together against each frame
solved alone, bit for bit, on random problems (hypothesis) and on captured degenerate ones; and the lanes'
primitives on one float against numpy on many."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.limits import human
from fullbody_adjust.solver.maths import geometry, lanes, vectors
from fullbody_adjust.solver.fullbody import limb_rotations as lr
from fullbody_adjust.solver.limits import joint_limits as jl
from fullbody_adjust.solver.limits.joint_limits import CONE, FREE, HINGE, JointLimits
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.fullbody.reach_balls import nearest_in_balls, nearest_on_sphere_in_balls, sub_base_point
from fullbody_adjust.solver.fullbody.trunk_curl import curl_chord, curl_start
from fullbody_adjust.solver.chain.two_bone_start import two_bone_start
from fullbody_adjust.solver.errors import SolverInputError

BENT = np.radians(15.0)
MANY = lanes.FEW + 3  # more frames than lanes.run solves one at a time


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _alone_and_together(fn, frames, *args):
    """fn on all frames against fn on each frame alone (rows of (F,...) arrays; None passes): the same bits. A
    batch that raises must raise an error some frame alone raises; the frames that raise nothing alone are then
    compared as a batch of their own. Returns the number of frames compared."""
    alone, errors = {}, []
    for k in range(frames):
        try:
            alone[k] = fn(*[None if a is None else a[k:k + 1] for a in args])[0]
        except SolverInputError as error:
            errors.append(str(error))
    try:
        together = fn(*args)
    except SolverInputError as error:
        assert str(error) in errors
        keep = np.array(sorted(alone), dtype=int)
        if keep.size == 0:
            return 0
        together = fn(*[None if a is None else a[keep] for a in args])
        alone = {i: alone[k] for i, k in enumerate(keep)}
    else:
        assert not errors
    for k, row in alone.items():
        np.testing.assert_array_equal(_bits(row), _bits(together[k]), err_msg=f"frame {k}")
    return len(alone)


def _hinge_frames(rng, n):
    """Captured-style limbs: bent, about the clear-bend and slight-bend thresholds, straight, hyperextended,
    folded back, along the bend side, X axes along the limb."""
    parent = rng.normal(size=(n, 3)) * rng.uniform(0.05, 2.0, (n, 1))
    child, side, x = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    u = parent / np.linalg.norm(parent, axis=1, keepdims=True)
    perp = np.cross(u, side)
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    theta = np.concatenate([rng.uniform(-0.3, 0.3, n // 4), BENT + rng.uniform(-1e-9, 1e-9, n // 8),
                            rng.uniform(-2e-3, 2e-3, n // 8), np.zeros(n // 8), rng.uniform(-3.0, 3.0, n)])[:n]
    child[: n // 2] = (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * perp)[: n // 2]
    child[3::17] = -u[3::17]
    side[5::11] = u[5::11] * 2.0
    side[6::13] = u[6::13] + 0.29 * perp[6::13]
    x[7::9] = u[7::9] * 3.0
    x[8::9] = u[8::9] + 1e-7 * perp[8::9]
    return parent, child, side, x


def _hinge(parent, child, side, x):
    return human._hinge_axis(parent, child, side, x, BENT)


@pytest.mark.parametrize("with_x", [True, False])
def test_hinge_axes_captured(with_x):
    parent, child, side, x = _hinge_frames(np.random.default_rng(11 + with_x), 600)
    assert _alone_and_together(_hinge, 600, parent, child, side, x if with_x else None) == 600


vectors3 = st.integers(1, 2 * MANY).flatmap(
    lambda f: st.tuples(*[arrays(np.float64, (f, 3), elements=st.floats(-1e3, 1e3) | st.sampled_from([0.0, 1e-12]))
                          for _ in range(4)], st.booleans()))


@settings(max_examples=200, deadline=None)
@given(vectors3)
def test_hinge_axes_random(problem):
    parent, child, side, x, with_x = problem
    _alone_and_together(_hinge, len(parent), parent, child, side, x if with_x else None)


@pytest.mark.parametrize("bad", ["zero parent", "zero child", "nan"])
def test_hinge_axes_degenerate(bad):
    parent, child, side, x = (a[:MANY] for a in _hinge_frames(np.random.default_rng(5), 40))
    {"zero parent": parent, "zero child": child, "nan": x}[bad][1] = 0.0 if bad != "nan" else np.nan
    assert _alone_and_together(_hinge, MANY, parent, child, side, x) >= MANY - 1


def _limbs(rng, b, joints):
    """b random chains of `joints` joints, targets from within reach to far beyond, hinge axes, poles on some;
    a target at the two segments' pivot, a hinge axis along the line to the target, a target straight along the
    first segment, a folded upper segment."""
    steps = rng.normal(size=(b, joints - 1, 3))
    steps *= rng.uniform(0.1, 0.4, (b, joints - 1, 1)) / np.linalg.norm(steps, axis=-1, keepdims=True)
    start = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1) + 0.05 * rng.normal(size=(b, 1, 3))
    reach = np.linalg.norm(steps, axis=-1).sum(axis=1)
    direction = rng.normal(size=(b, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    targets = start[:, 0] + direction * (reach * rng.uniform(0.2, 2.0, b))[:, None]
    axis = rng.normal(size=(b, 3))
    pole = np.where(rng.random((b, 1)) < 0.4, start[:, -2] + rng.normal(size=(b, 3)), np.nan)
    targets[1::11] = start[1::11, -3]
    axis[2::13] = targets[2::13] - start[2::13, -3]
    targets[3::7] = start[3::7, 0] + 3.0 * (start[3::7, 1] - start[3::7, 0])
    start[4::17, -2] = start[4::17, -3]
    return start, targets, axis, pole


@pytest.mark.parametrize("joints", [3, 4, 5])
@pytest.mark.parametrize("with_pole", [True, False])
def test_two_bone_start_captured(joints, with_pole):
    rng = np.random.default_rng(joints)
    with np.errstate(invalid="ignore", divide="ignore"):
        for frames in (MANY, 40):
            start, targets, axis, pole = _limbs(rng, frames, joints)
            compared = _alone_and_together(two_bone_start, frames, start, targets, axis, pole if with_pole else None)
            assert compared >= frames - frames // 11 - 1


@settings(max_examples=150, deadline=None)
@given(st.integers(3, 5).flatmap(lambda n: st.integers(1, 2 * MANY).flatmap(lambda f: st.tuples(
    arrays(np.float64, (f, n, 3), elements=st.floats(-2.0, 2.0)), arrays(np.float64, (f, 3), elements=st.floats(-5, 5)),
    arrays(np.float64, (f, 3), elements=st.floats(-1, 1)),
    arrays(np.float64, (f, 3), elements=st.floats(-1, 1) | st.just(np.nan))))))
def test_two_bone_start_random(problem):
    with np.errstate(invalid="ignore", divide="ignore"):
        _alone_and_together(two_bone_start, len(problem[0]), *problem)


def _trunks(rng, b, segments):
    """Spines near upright, some straight; targets about the end, some straight along the spine's chord."""
    steps = np.array([0.0, 0.0, 0.12]) + 0.04 * rng.normal(size=(b, segments, 3))
    steps[::10] = [0.0, 0.0, 0.12]
    chains = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    targets = chains[:, -1] + rng.normal(size=(b, 3)) * 0.2
    targets[2::5] = 1.3 * chains[2::5, -1]
    return chains, targets


@pytest.mark.parametrize("segments", [3, 4])
@pytest.mark.parametrize("fn", [curl_chord, curl_start])
def test_trunk_curl_captured(segments, fn):
    rng = np.random.default_rng(segments)
    for frames in (MANY, 60):
        chains, targets = _trunks(rng, frames, segments)
        for shares in (rng.uniform(0.2, 1.0, segments), rng.uniform(0.2, 1.0, (frames, segments))):
            per_frame = shares if shares.ndim == 1 else None
            call = (lambda c, t, s=None: fn(c, t, per_frame if s is None else s))  # noqa: E731
            args = (chains, targets) if per_frame is not None else (chains, targets, shares)
            assert _alone_and_together(call, frames, *args) == frames


@settings(max_examples=100, deadline=None)
@given(st.integers(2, 5).flatmap(lambda m: st.integers(1, 2 * MANY).flatmap(lambda f: st.tuples(
    arrays(np.float64, (f, m + 1, 3), elements=st.floats(-1.0, 1.0)), arrays(np.float64, (f, 3), elements=st.floats(-2, 2)),
    arrays(np.float64, (f, m), elements=st.floats(0.0, 1.0))))))
def test_trunk_curl_random(problem):
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for fn in (curl_chord, curl_start):
            _alone_and_together(fn, len(problem[0]), *problem)


@pytest.mark.parametrize("kind", [(CONE, HINGE, CONE), (FREE, HINGE, HINGE), (HINGE, CONE, HINGE), None])
def test_segment_rotations_captured(kind):
    """Chains with hinges (one, or two in a row), cones and free joints; segments that do not turn, turn right
    round, fold onto their parent, a hinge axis along its parent; a segment of no length (an error)."""
    rng = np.random.default_rng(7)
    for frames in (MANY, 50):
        n = 4
        start = np.cumsum(rng.normal(size=(frames, n, 3)) * 0.3, axis=1)
        joints = start + rng.normal(size=(frames, n, 3)) * rng.choice([0.0, 0.05, 0.5], size=(frames, 1, 1))
        joints[1::7, 2] = joints[1::7, 1] - (start[1::7, 2] - start[1::7, 1])
        joints[2::7, 2] = joints[2::7, 1] + 0.7 * (joints[2::7, 1] - joints[2::7, 0])
        joints[5::19, 3] = joints[5::19, 2]
        axes = rng.normal(size=(frames, n - 1, 3))
        axes[3::7, 1] = start[3::7, 1] - start[3::7, 0]
        k = None if kind is None else np.array(kind)
        fn = (lambda s, j, a: lr._segment_rotations(s, j, k, None if k is None else a))  # noqa: E731
        assert _alone_and_together(fn, frames, start, joints, axes) >= frames - frames // 19 - 1


def _ball_frames(k, n=400, seed=0):
    """n frames of k balls: points (n,3), centres (n,k,3), radii (n,k), active (n,k), spheres' centres (n,3) and
    radii (n,); a quarter random, the rest with one degeneracy each."""
    rng = np.random.default_rng(seed + 17 * k)
    points = rng.uniform(-1.5, 1.5, (n, 3))
    centres = rng.uniform(-1.0, 1.0, (n, k, 3))
    radii = rng.uniform(0.2, 1.6, (n, k))
    active = rng.random((n, k)) < 0.8
    centre = rng.uniform(-1.0, 1.0, (n, 3))
    radius = rng.uniform(0.3, 1.5, n)
    kind = np.arange(n) % 8
    for f in range(n):
        if k >= 2 and kind[f] == 1:  # concentric balls
            centres[f, 1] = centres[f, 0]
        elif k >= 2 and kind[f] == 2:  # tangent spheres: their circle is one point
            gap = np.linalg.norm(centres[f, 1] - centres[f, 0])
            radii[f, 1] = gap - radii[f, 0] if gap > radii[f, 0] else radii[f, 0] - gap
        elif k >= 2 and kind[f] == 3:  # the point on the line through two centres (their circle's axis)
            points[f] = centres[f, 0] + 0.3 * (centres[f, 1] - centres[f, 0])
            centre[f] = centres[f, 0] + 0.7 * (centres[f, 1] - centres[f, 0])
        elif k >= 3 and kind[f] == 4:  # collinear centres: no three-sphere points
            centres[f, 2] = centres[f, 0] + 2.0 * (centres[f, 1] - centres[f, 0])
        elif kind[f] == 5:  # the point at the sphere's centre, in every ball
            centre[f] = points[f]
            if k:
                centres[f] = points[f] + rng.uniform(-0.1, 0.1, (k, 3))
        elif k and kind[f] == 6:  # balls far apart: no common point
            centres[f] *= 6.0
            radii[f] *= 0.3
        elif k and kind[f] == 7:  # the point exactly on a ball's boundary
            d = points[f] - centres[f, 0]
            radii[f, 0] = np.sqrt(d @ d)
    return points, centres, radii, active, centre, radius


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4, 5])
def test_reach_balls_captured(k):
    """Concentric balls, tangent spheres, a point on a circle's axis, collinear centres, a point at the sphere's
    centre, no common point, a point on a boundary."""
    points, centres, radii, active, centre, radius = _ball_frames(k)
    x_all, ok_all = nearest_in_balls(points, centres, radii, active)
    s_all, found_all = nearest_on_sphere_in_balls(points, centre, radius, centres, radii, active)
    assert ok_all.any() and found_all.any()
    if k >= 2:  # the cases reach every kind of answer: inside, infeasible, moved
        assert not ok_all.all() and not found_all.all()
        assert np.any(ok_all & np.any(x_all != points, axis=1))
    for f in range(len(points)):
        one = slice(f, f + 1)
        x, ok = nearest_in_balls(points[one], centres[one], radii[one], active[one])
        assert ok.dtype == bool and x.shape == (1, 3)
        np.testing.assert_array_equal(x[0], x_all[f], err_msg=f"nearest_in_balls, frame {f}")
        assert ok[0] == ok_all[f]
        s, found = nearest_on_sphere_in_balls(points[one], centre[one], radius[one], centres[one], radii[one],
                                              active[one])
        np.testing.assert_array_equal(s[0], s_all[f], err_msg=f"nearest_on_sphere_in_balls, frame {f}")
        assert found[0] == found_all[f]


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("variant", ["priority", "weighted", "fabrik"])
def test_sub_base_point_captured(k, variant):
    points, centres, radii, active, _, _ = _ball_frames(k, seed=1)
    rng = np.random.default_rng(k)
    for priorities in (rng.choice([0.0, 1.0, 2.0], k), np.append(rng.random(k - 1), -np.inf)):
        if variant == "weighted" and np.isinf(priorities).any():
            continue
        x_all, ok_all = sub_base_point(points, centres, radii, active, priorities, variant)
        if k >= 2:  # some frames have balls without a common point: the priorities decide there
            assert not ok_all.all()
        for f in range(len(points)):
            one = slice(f, f + 1)
            x, ok = sub_base_point(points[one], centres[one], radii[one], active[one], priorities, variant)
            np.testing.assert_array_equal(x[0], x_all[f], err_msg=f"frame {f}, priorities {priorities}")
            assert ok[0] == ok_all[f]


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_primitives_on_one_value_as_numpy_on_many(a, b):
    arr_a, arr_b = np.array([a, a]), np.array([b, b])
    with np.errstate(invalid="ignore"):
        pairs = [(lanes.divide(a, b), lanes.divide(arr_a, arr_b)), (lanes.sqrt(a), lanes.sqrt(arr_a)),
                 (lanes.arctan2(a, b), lanes.arctan2(arr_a, arr_b)), (lanes.cos(a), lanes.cos(arr_a)),
                 (lanes.sin(a), lanes.sin(arr_a))]
    for one, many in pairs:
        assert isinstance(one, float)
        np.testing.assert_array_equal(_bits(one), _bits(many[0]))


def _limit_frames(rng, f):
    """f unit parents, directions (some along the parent, opposite, along the axis), axes (some along the parent)
    and fallbacks (some degenerate too)."""
    unit = (lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True))  # noqa: E731
    parent, v, axis, fallback = (unit(rng.normal(size=(f, 3))) for _ in range(4))
    v[1::7], v[2::7] = parent[1::7], -parent[2::7]
    v[3::7] = unit(axis[3::7] - (axis[3::7] * parent[3::7]).sum(-1, keepdims=True) * parent[3::7])
    axis[4::9] = parent[4::9]
    fallback[2::14] = -parent[2::14]
    return parent, v, axis, fallback


@pytest.mark.parametrize("twist", [0.0, 0.4])
def test_limits_one_and_many(twist):
    """The joint limits' kernels (cone, hinge with and without twist, the hinge axis carried by the parent's swing)
    on F directions at once (arrays (F,3)) and on each alone, bit for bit."""
    rng = np.random.default_rng(int(twist * 10))
    for f in (MANY, 300):
        parent, v, axis, fallback = _limit_frames(rng, f)
        ref = parent[::-1].copy()
        calls = [lambda p, d, a, fb, r: jl.cone(p, d, 1.1, fb), lambda p, d, a, fb, r: jl.cone(p, d, 0.2, fb),
                 lambda p, d, a, fb, r: jl.hinge(p, d, a, -0.3, 2.2, fb, twist),
                 lambda p, d, a, fb, r: jl.hinge(p, d, a, 0.5, 0.5, fb, twist),
                 lambda p, d, a, fb, r: (jl.carry(a, r, p), False)]
        for call in calls:
            whole, whole_binding = call(parent, v, axis, fallback, ref)  # (F,3) arrays
            for k in range(f):
                one, bind = call(*(tuple(x[k].tolist()) for x in (parent, v, axis, fallback, ref)))
                assert isinstance(one[0], float) and bind == np.broadcast_to(whole_binding, (f,))[k]
                np.testing.assert_array_equal(_bits(np.array(one)), _bits(whole[k]), err_msg=f"frame {k}")


def _chain_batches(seed, count):
    """Problems of tests/solver/test_obstacle_response.py (limits, boxes on the way) made MANY chains each (the
    first chain's start toward jittered targets), with and without their boxes."""
    from .test_obstacle_response import _problems
    rng = np.random.default_rng(seed)
    for k, (starts, targets, limits, parents, boxes) in enumerate(_problems(seed, count)):
        starts = np.repeat(starts[:1], MANY, axis=0)
        targets = targets[:1] + rng.normal(scale=0.3, size=(MANY, 3)) * (k % 3)
        targets[1] = starts[1, -1]  # a start already at its target
        targets[2] *= 10.0  # beyond reach
        yield starts, targets, limits, np.repeat(parents[:1], MANY, axis=0), boxes if k % 2 else None


@pytest.mark.parametrize("seed", range(3))
def test_chain_solves_one_and_many(seed):
    """FABRIK with limits (and boxes on every other problem): MANY chains solved together (on arrays) against each
    solved alone (on Python floats), bit for bit: positions, iterations, residuals, statuses and reasons."""
    for starts, targets, limits, parents, boxes in _chain_batches(seed, 12):
        together = solve_chain_batch(starts, targets, limits=limits, parent_directions=parents, obstacles=boxes)
        for k in range(MANY):
            one = slice(k, k + 1)
            alone = solve_chain_batch(starts[one], targets[one], limits=limits, parent_directions=parents[one],
                                      obstacles=boxes)
            np.testing.assert_array_equal(_bits(alone.positions[0]), _bits(together.positions[k]))
            assert alone.iterations[0] == together.iterations[k]
            np.testing.assert_array_equal(_bits(alone.residual[0]), _bits(together.residual[k]))
            assert (alone.status[0], alone.reason[0]) == (together.status[k], together.reason[k])


@pytest.mark.parametrize("seed", range(2))
def test_matrix_times_vector_one_and_many(seed):
    """geometry.apply_matrix on F matrices and vectors against vectors.apply_matrix on each frame's floats, bit for
    bit, the sign of zero included (values over many magnitudes, a fifth of them +0.0 or -0.0)."""
    rng = np.random.default_rng(seed)
    values = (lambda shape: np.where(rng.random(shape) < 0.2, np.where(rng.random(shape) < 0.5, 0.0, -0.0),  # noqa: E731
                                     rng.normal(size=shape) * np.exp(rng.normal(scale=4.0, size=shape))))
    for f in (1, MANY, 2000):
        m, v = values((f, 3, 3)), values((f, 3))
        many = geometry.apply_matrix(m, v)
        for k in range(f):
            one = vectors.apply_matrix(tuple(map(tuple, m[k].tolist())), tuple(v[k].tolist()))
            np.testing.assert_array_equal(_bits(np.array(one)), _bits(many[k]), err_msg=f"frame {k}")


def test_body_solves_with_a_rigs_locks_one_and_many():
    """The elbow locked, so the arm is held short of most goals and the limited passes iterate long: every result
    field of the whole-body solve of the frames as one batch equals that of each frame solved alone (as clicks
    solve)."""
    from fullbody_adjust.solver.limits.human import default_limits
    from fullbody_adjust.solver.fullbody.adjust import adjust_frames
    from fullbody_adjust.solver.limits.rig_limits import rig_limits
    from .test_adjust import EFFECTORS
    from .test_rig_limits import bone_axes, pulled, spec, synthetic_humanoid

    model, h0, t0 = synthetic_humanoid()
    a0 = bone_axes(model, h0, t0)
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    locked = spec(model, a0, "forearm.L", locked=(True, False, True))

    def solve(frames):
        h, t, x = heads[frames], tails[frames], axes[frames]
        limits = rig_limits(default_limits(model, h, t, bone_x_axes=x[..., 0]), model, h, t, x, locked)
        return adjust_frames(model, h, t, targets[frames], EFFECTORS, limits=limits)

    together = solve(list(range(len(targets))))
    assert len(targets) > lanes.FEW and np.max(together.iterations) >= 10
    for f in range(len(targets)):
        alone = solve([f])
        for field in ("heads", "tails", "rotations", "residuals", "iterations", "sc_displacement",
                      "root_displacement"):
            np.testing.assert_array_equal(_bits(getattr(alone, field)[0]), _bits(getattr(together, field)[f]),
                                          err_msg=f"{field}, frame {f}")
        assert (alone.status[0] == together.status[f]).all() and (alone.reasons[0] == together.reasons[f]).all()


def test_straight_chains_nudged_off_their_line_one_and_many(monkeypatch):
    """Straight chains whose targets lie on their own line, short of the last two segments' range: FABRIK stalls
    there and pushes the joints sideways (the nudge); together and alone, the same bits."""
    from fullbody_adjust.solver.chain.iteration import Iteration
    nudge, nudged = Iteration.nudged, []
    monkeypatch.setattr(Iteration, "nudged", lambda self, *args: nudged.append(1) or nudge(self, *args))
    rng = np.random.default_rng(7)
    d = rng.normal(size=(MANY, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lengths = rng.uniform(0.3, 1.0, (MANY, 4))
    starts = np.concatenate([np.zeros((MANY, 1, 3)), np.cumsum(d[:, None] * lengths[..., None], axis=1)], axis=1)
    targets = d * lengths.sum(axis=1, keepdims=True) * 0.2
    limits = JointLimits.free(5).with_cone(0, 2.5)
    together = solve_chain_batch(starts, targets, limits=limits, parent_directions=d)
    for k in range(MANY):
        one = slice(k, k + 1)
        alone = solve_chain_batch(starts[one], targets[one], limits=limits, parent_directions=d[one])
        np.testing.assert_array_equal(_bits(alone.positions[0]), _bits(together.positions[k]))
        assert alone.iterations[0] == together.iterations[k] and alone.status[0] == together.status[k]
    assert len(nudged) >= 2


def test_two_segment_finish_one_and_many():
    """The two-segment finish of each chain alone (TwoBoneFinish.place on one problem's floats) against the finish of
    all the batch's chains at once: random chains among boxes (some with a box around the base), forward-pass joints
    off the chain, targets within the last two segments' range, just inside and just outside its ends (where the
    finish declines), and a middle joint on the pivot-target line. The same answers and joints, bit for bit."""
    from fullbody_adjust.solver.chain.model import ChainModel
    from fullbody_adjust.solver.chain.settings import ChainSettings
    from fullbody_adjust.solver.obstacles.boxes import Boxes
    from .test_obstacle_response import _problems
    rng = np.random.default_rng(11)
    answers = []
    for k, (starts, targets, limits, parents, boxes) in enumerate(_problems(3, 60)):
        if k % 2:  # a box around the base (at the origin), which the base's segment ignores
            boxes = Boxes(np.concatenate([boxes.mins, [[-0.05] * 3]]), np.concatenate([boxes.maxs, [[0.05] * 3]]))
        model = ChainModel(starts, targets, ChainSettings(), limits, boxes, parents)
        if model.finish is None:
            continue
        j, rows = model.n - 3, np.arange(model.B)
        a, c = model.lengths[:, j], model.lengths[:, j + 1]
        for case in range(5):
            P = starts + rng.normal(scale=0.05, size=starts.shape)
            aims = starts + rng.normal(scale=0.2, size=starts.shape)
            P[:, j] = starts[:, j]
            direction = rng.normal(size=(model.B, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            reach = [rng.uniform(abs(a - c), a + c), (a + c) * (1 - 5e-10), (a + c) * (1 - 2e-9),
                     abs(a - c) * (1 + 5e-10), rng.uniform(abs(a - c), a + c)][case]
            model.targets[:] = starts[:, j] + direction * reach[:, None]
            if case == 4:
                aims[:, j + 1] = starts[:, j] + direction * 0.3 * reach[:, None]
            done, middle, end = model.finish.place(rows, P, aims)
            for r in rows:
                one = model.finish.place(int(r), [tuple(p) for p in P[r].tolist()], [tuple(p) for p in aims[r].tolist()])
                assert one[0] == bool(done[r])
                if one[0]:
                    np.testing.assert_array_equal(_bits(np.array(one[1])), _bits(middle[r]))
                    np.testing.assert_array_equal(_bits(np.array(one[2])), _bits(end[r]))
                answers.append(("declined", "finished")[one[0]])
    assert answers.count("finished") >= 20 and answers.count("declined") >= 20


def _box_points(rng, n, mins, maxs):
    """n points around the boxes, many of them on a face, an edge or a corner (coordinates copied from the box)."""
    lo, hi = mins.reshape(-1, 3).min(axis=0), maxs.reshape(-1, 3).max(axis=0)
    p = rng.uniform(lo - 0.5, hi + 0.5, (n, 3))
    face = np.where(rng.random((n, 3)) < 0.5, mins.reshape(-1, 3)[0], maxs.reshape(-1, 3)[0])
    return np.where(rng.random((n, 3)) < 0.3, face, p)


@pytest.mark.parametrize("seed", range(4))
def test_box_tests_one_and_many(seed):
    """The collision tests of one point and its segment on floats, box by box (boxes.hits), against points_inside and
    segments_cross on every point and box at once: the same answers, with what each point ignores, on a box's faces,
    for segments along a face or an axis, of no length, with per-problem boxes and with NaN coordinates."""
    from fullbody_adjust.solver.obstacles.boxes import Boxes, hits, points_inside, segments_cross
    rng = np.random.default_rng(20 + seed)
    k, n = 1 + seed % 2, 800
    mins = rng.uniform(-1.0, 0.0, (k, 3))
    maxs = mins + rng.uniform(0.2, 1.0, (k, 3))
    a, b = _box_points(rng, n, mins, maxs), _box_points(rng, n, mins, maxs)
    b[::5, seed % 3] = a[::5, seed % 3]
    b[::7] = a[::7]
    a[3::50, 1] = np.nan
    ign_point, ign_seg = rng.random((n, k)) < 0.4, rng.random((n, k)) < 0.4
    if seed >= 2:  # each problem its own boxes, shifted
        shift = rng.uniform(-0.3, 0.3, (n, 1, 3))
        boxes = Boxes(mins[None] + shift, maxs[None] + shift)
    else:
        boxes = Boxes(mins, maxs)
    inside, crossing = points_inside(b, boxes), segments_cross(a, b, boxes)
    assert inside.any() and not inside.all() and (crossing & ~inside).any() and not crossing.all()
    for r in range(n):
        lo, hi = (boxes.mins[r], boxes.maxs[r]) if boxes.batched else (boxes.mins, boxes.maxs)
        one = hits(lo.tolist(), hi.tolist(), tuple(a[r].tolist()), tuple(b[r].tolist()))
        assert one == (bool(inside[r].any()), bool(crossing[r].any())), r
        one = hits(lo.tolist(), hi.tolist(), tuple(a[r].tolist()), tuple(b[r].tolist()), ign_point[r].tolist(),
                   ign_seg[r].tolist())
        assert one == (bool((inside[r] & ~ign_point[r]).any()), bool((crossing[r] & ~ign_seg[r]).any())), r


@pytest.mark.parametrize("batched", [False, True])
def test_chain_penetration_counts_one_and_many(batched):
    """ObstacleResponse.penetration_counts of each chain alone (on its floats) against all chains at once: the same
    counts, with the boxes the end and the base ignore (a target or the base inside a box) left out, for 2- to 5-joint
    chains around one or two boxes, shared or per problem, joints on a box's corner."""
    from fullbody_adjust.solver.chain.model import ChainModel
    from fullbody_adjust.solver.chain.settings import ChainSettings
    from fullbody_adjust.solver.obstacles.boxes import Boxes
    rng = np.random.default_rng(3 + batched)
    counted = 0
    for trial in range(60):
        b, n, k = MANY, 2 + trial % 4, 1 + trial % 2
        mins = rng.uniform(-0.6, 0.0, (b, k, 3) if batched else (k, 3))
        boxes = Boxes(mins, mins + rng.uniform(0.2, 0.8, mins.shape))
        start = np.cumsum(rng.normal(scale=0.4, size=(b, n, 3)), axis=1)
        targets = start[:, -1] + rng.normal(scale=0.05, size=(b, 3))
        model = ChainModel(start, targets, ChainSettings(), None, boxes, None)
        pose = start + rng.normal(scale=0.2, size=start.shape)
        pose[:, 1:][rng.random((b, n - 1)) < 0.2] = mins.reshape(-1, 3)[0]
        inside, crossing = model.obstacles.penetration_counts(pose, np.arange(b))
        for r in range(b):
            assert model.obstacles.penetration_counts([tuple(p) for p in pose[r].tolist()], r) == (inside[r], crossing[r])
        counted += int((inside + crossing > 0).sum())
    assert 0 < counted < 60 * MANY  # penetrating poses and clear ones
