"""The chain solver: B chains (B, n, 3) with joint limits and obstacles, each problem leaving the active set when it
converges, so a problem's result does not depend on what else is in the batch. FABRIK's passes are written once, on
one problem's floats or many problems' arrays; a few problems are solved one at a time on floats (maths/lanes.py
decides), with the same bits as among many. The model owns its limits (ChainLimits), obstacles (ObstacleResponse),
two-segment finish (TwoBoneFinish) and the stages of a solve: the stretched pass, the start's check and the
iteration loop (Iteration)."""

import numpy as np

from .finish import _MIN_FINISH_TWIST, TwoBoneFinish
from .iteration import Iteration
from ..obstacles.response import ObstacleResponse
from .settings import _COINCIDENT, ChainBatchResult, statuses, _reach_bounds, _segment_lengths
from ..errors import SolverInputError
from ..maths import lanes
from ..maths import vectors as vec
from ..maths.geometry import all_set, any_set, norm
from ..limits.joint_limits import FREE, HINGE, JointLimits
from .limited import ChainLimits
from ..obstacles.boxes import as_boxes


class ChainModel:
    """Per-solve constant data of B chains and the two FABRIK passes on any subset of them.

    Built from the start positions: segment lengths and directions, limits (per joint), obstacles, and the
    boxes each problem ignores (those containing its target for the end joint and last segment, those
    containing its base for segment 0 — unavoidable, reported in the reason)."""

    def __init__(self, start, targets, settings, limits, obstacles, parent_directions):
        self.B, self.n = start.shape[0], start.shape[1]
        self.settings = settings
        self.targets = targets
        self.base = start[:, 0].copy()
        self.lengths = _segment_lengths(start)
        self.start_dirs = (start[:, 1:] - start[:, :-1]) / self.lengths[..., None]
        m = self.n - 1

        if limits is not None and not isinstance(limits, JointLimits):
            raise SolverInputError("limits must be a JointLimits")
        if limits is not None and len(limits) != m:
            raise SolverInputError(f"limits cover {len(limits)} joints but the chain has {m} limitable joints")
        self.limits = limits if limits is not None and limits.any_active else None
        self.parent_dirs = None
        if parent_directions is not None:
            pd = np.asarray(parent_directions, dtype=np.float64)
            if pd.shape != (self.B, 3):
                raise SolverInputError(f"parent_directions must have shape ({self.B},3), got {pd.shape}")
            if not all_set(np.isfinite(pd)):
                raise SolverInputError("parent_direction has NaN/inf")
            pn = norm(pd)
            if any_set(pn <= 1e-12):
                raise SolverInputError("parent_direction has zero length")
            self.parent_dirs = pd / pn[:, None]
        if self.limits is not None and self.limits.kind[0] != FREE and self.parent_dirs is None:
            raise SolverInputError("joint 0 has a limit but no parent_direction was given")
        self._floats = {}
        self.limiting = None if self.limits is None else ChainLimits(self.limits, self.start_dirs, self.parent_dirs)
        # The analytic two-segment finish needs a swivel range to pick from: not a hinge whose plane is fixed.
        self._finishes = self.limits is not None and self.n >= 3 and (
            self.limits.kind[m - 1] != HINGE or self.limits.hinge_twist[m - 1] >= _MIN_FINISH_TWIST)
        self.finish = TwoBoneFinish(self) if self._finishes else None

        obstacles = as_boxes(obstacles)
        self.boxes = obstacles if obstacles is not None and len(obstacles) > 0 else None
        self.obstacles = None if self.boxes is None else ObstacleResponse(self.boxes, targets, self.base, self.n,
                                                                          settings.margin)
        self.iteration = Iteration(self)

    # -- passes -----------------------------------------------------------------------------------------

    def _problem(self, r):
        """Problem r's (segment lengths, target, base, parent direction) as Python floats (passes on one problem)."""
        if r not in self._floats:
            self._floats[r] = (self.lengths[r].tolist(), tuple(self.targets[r].tolist()),
                               tuple(self.base[r].tolist()),
                               None if self.parent_dirs is None else self.parent_dirs[r].tolist())
        return self._floats[r]

    def _columns(self, rows, P, *poses):
        """The passes' view of problems `rows`: (segment lengths, one per segment, and each pose as a list of joints).
        One problem (rows an int): its floats, P and poses lists of joints already; many: (b,) and (b,3) views of
        the arrays (P's joints written through P itself)."""
        if rows.__class__ is int:
            return (self._problem(rows)[0], P) + poses
        return (list(self.lengths[rows].T), [P[:, i] for i in range(self.n)]) + tuple(
            None if Q is None else [Q[:, i] for i in range(self.n)] for Q in poses)

    def _place(self, P, joints, i, point):
        """Joint i of the pose being placed at `point` (P: many problems' array, joints: one problem's list)."""
        if joints is P:
            P[i] = point
        else:
            P[:, i] = point

    def forward(self, P, rows, prev, ref):
        """Forward pass in place on P of problems `rows`: effector to the target, joints toward the base. prev:
        positions at the start of the iteration (fallback directions); ref: obstacle-response reference. Many
        problems: rows an index array, P, prev, ref (b,n,3); one: rows an int, P, prev, ref lists of n joints.
        Returns (obstacles responded, failed), per problem."""
        lengths, joints, prev, ref = self._columns(rows, P, prev, ref)
        one = joints is P
        self._place(P, joints, self.n - 1, self._problem(rows)[1] if one else self.targets[rows])
        responded = failed = False if one else np.zeros(len(rows), dtype=bool)
        kind = None if self.limits is None else self.limiting.kind
        for i in range(self.n - 2, -1, -1):
            anchor = joints[i + 1]
            d = vec.sub(joints[i], anchor)
            L = lengths[i]
            dn = vec.norm(d)
            bad = lanes.not_(dn > L * _COINCIDENT)
            if lanes.any_(bad):
                d = lanes.pick(bad, vec.sub(prev[i], prev[i + 1]), d)
                dn = vec.norm(d)
            if kind is not None and i < self.n - 2 and kind[i + 1] != FREE:
                child = vec.divided(vec.sub(joints[i + 2], anchor), lengths[i + 1])
                child = vec.divided(child, vec.norm(child))
                fallback = vec.sub(prev[i + 1], prev[i])
                fallback = vec.divided(fallback, vec.norm(fallback))
                u = self.limiting.step(i + 1, rows, child, vec.divided(vec.neg(d), dn), fallback, True)[0]
                cand = vec.sub(anchor, vec.scaled(u, L))
            else:
                cand = vec.add(anchor, vec.scaled(d, L / dn))
            if self.boxes is not None and i > 0:  # joint 0 is re-pinned by the backward pass anyway
                cand, resp, fail = self._avoid(rows, anchor, cand, L, ref[i], i, i, None)
                responded, failed = responded | resp, failed | fail
            self._place(P, joints, i, cand)
        return responded, failed

    def backward(self, P, rows, aims, prev, ref, stretch=False):
        """Backward pass in place on P (as forward takes it): base pinned, joint i+1 placed
        toward aims[i+1] (the forward-pass positions, or with `stretch` the target for every joint), limits then
        obstacles applied. Returns (limit binding, obstacle responded, obstacle failed), per problem."""
        finish_on = None if stretch or not self._finishes else (P, aims)
        lengths, joints, aims, prev, ref = self._columns(rows, P, aims, prev, ref)
        one = joints is P
        self._place(P, joints, 0, self._problem(rows)[2] if one else self.base[rows])
        binding = responded = failed = False if one else np.zeros(len(rows), dtype=bool)
        kind = None if self.limits is None else self.limiting.kind
        pivot = self.n - 3 if finish_on is not None else -1
        finished = None
        for i in range(self.n - 1):
            if i == pivot:
                finished, elbow, wrist = self.finish.place(rows, *finish_on)
            anchor = joints[i]
            d = vec.sub(aims[i + 1], anchor)
            if not stretch and kind is not None and i + 1 < self.n - 1 and kind[i + 1] == HINGE:
                # The parent segment of a hinge keeps its forward-pass direction instead of aiming at the
                # forward-pass joint from the moved anchor: the hinge plane is carried by this direction, and
                # the forward pass fitted that plane to the child (the reverse limit step). Re-aiming would turn
                # the plane away from the target every iteration (measured: a limb with an elbow hinge and
                # perturbed targets went from about 1 in 3 reached to nearly all).
                d = vec.sub(aims[i + 1], aims[i])
            L = lengths[i]
            dn = vec.norm(d)
            bad = lanes.not_(dn > L * _COINCIDENT)
            if lanes.any_(bad):
                d = lanes.pick(bad, vec.sub(prev[i + 1], prev[i]), d)
                dn = vec.norm(d)
            limit = None
            if kind is not None and kind[i] != FREE:
                if i == 0:
                    parent = self._problem(rows)[3] if one else self.parent_dirs[rows]
                else:
                    parent = vec.divided(vec.sub(joints[i], joints[i - 1]), lengths[i - 1])
                    parent = vec.divided(parent, vec.norm(parent))
                fallback = vec.sub(prev[i + 1], prev[i])
                fallback = vec.divided(fallback, vec.norm(fallback))
                u, bind = self.limiting.step(i, rows, parent, vec.divided(d, dn), fallback)
                binding = binding | bind
                cand = vec.add(anchor, vec.scaled(u, L))
                limit = (i, parent, fallback)
            else:
                cand = vec.add(anchor, vec.scaled(d, L / dn))
            if self.boxes is not None:
                cand, resp, fail = self._avoid(rows, anchor, cand, L, ref[i + 1], i + 1, i, limit)
                responded, failed = responded | resp, failed | fail
            if finished is not None and i >= pivot:
                cand = lanes.pick(finished, elbow if i == pivot else wrist, cand)
                kept = lanes.not_(finished)
                binding, responded, failed = binding & kept, responded & kept, failed & kept
            self._place(P, joints, i + 1, cand)
        return binding, responded, failed

    def _avoid(self, rows, anchor, cand, L, ref, joint, segment, limit):
        """The obstacle response (obstacles/response.py) for the joints at `cand`; limit: the backward pass's (joint,
        parent direction, fallback) or None. (positions, responded, failed). One problem's joint (rows an int) is
        tested on its floats, and where it penetrates a box, answered by the arrays' response as a batch of one (the
        paper's circle and the sphere are many samples, tested at once)."""
        one = rows.__class__ is int
        if one:
            if not self.obstacles.penetrates(rows, anchor, cand, joint, segment):
                return cand, False, False
            rows, anchor, cand, L, ref = (np.array([x]) for x in (rows, anchor, cand, L, ref))
            if limit is not None:
                limit = (limit[0], np.array([limit[1]]), np.array([limit[2]]))
        limit_fn = None
        if limit is not None:
            i, parent, fallback = limit

            def limit_fn(h, dirs):
                return self.limiting.step(i, rows[h], parent[h], dirs, fallback[h])[0]
        point, responded, failed = self.obstacles.avoid(rows, anchor, cand, L, ref, joint, segment, limit_fn)
        if one:
            return tuple(point[0].tolist()), bool(responded[0]), bool(failed[0])
        return point, responded, failed

    # -- solve ------------------------------------------------------------------------------------------

    def penetration_counts(self, P, rows=None):
        """(joints inside, segments crossing) per problem (b,) of P (b,n,3) = problems `rows` (default all),
        ignoring what each problem must ignore."""
        rows = np.arange(self.B) if rows is None else rows
        if self.boxes is None:
            z = np.zeros(P.shape[0], dtype=np.int64)
            return z, z.copy()
        return self.obstacles.penetration_counts(P, rows)

    def solve(self, start):
        B = self.B
        tol = self.settings.tolerance
        P = start.copy()
        total, inner = _reach_bounds(self.lengths)
        dist = norm(self.targets - self.base)
        beyond = dist > total
        reachable = ~beyond & (dist >= inner)
        iterations = np.zeros(B, dtype=np.int64)
        residual = np.zeros(B)
        stalled = np.zeros(B, dtype=bool)
        obstacle_active = np.zeros(B, dtype=bool)
        limit_binding = np.zeros(B, dtype=bool)

        rows = np.nonzero(beyond)[0]
        if rows.size:
            limit_binding[rows], obstacle_active[rows] = self.iteration.stretched(P, rows)
            iterations[rows] = 1
            residual[rows] = norm(P[rows, -1] - self.targets[rows])

        # A start pose already at its target is returned untouched (bit-exact, 0 iterations) unless it breaks a
        # limit or penetrates a box: then at least one iteration runs, so it is never returned unchecked.
        constrained = self.limits is not None or self.boxes is not None
        rows = np.nonzero(~beyond)[0]
        if rows.size:
            force = False
            if constrained:
                force = np.zeros(rows.size, dtype=bool)
                met = norm(P[rows, -1] - self.targets[rows]) <= tol
                force[met] = self.iteration.violations(P, rows[met])
            its, res, stl, bind, obst, pen = self.iteration.iterate(P, rows, force)
            iterations[rows], residual[rows], stalled[rows] = its, res, stl
            limit_binding[rows], obstacle_active[rows] = bind, obst
            # FABRIK's obstacle response is local: the chain can wrap around the wrong side of a box and stay
            # trapped there. A problem that is not reached gets a second start from the pose plain FABRIK
            # finds (no obstacles, no limits; the constrained iterations then push that pose out of the boxes
            # and into the limits), and keeps the better outcome: fewer penetrations, then the smaller residual.
            # Where plain FABRIK leaves the start as it is (e.g. a start already at its target), the second start
            # is the first one: its iterations would repeat the first attempt exactly, so it is skipped.
            retry = rows[(res > tol) & reachable[rows]] if self.boxes is not None else rows[:0]
            if retry.size:
                free = ChainModel(start[retry], self.targets[retry], self.settings, None, None, None)
                unobstructed = free.solve(start[retry])
                fresh = ~np.all(unobstructed.positions == start[retry], axis=(1, 2))
                retry, free_positions = retry[fresh], unobstructed.positions[fresh]
                free_iterations = unobstructed.iterations[fresh]
            if retry.size:
                Q = P.copy()
                Q[retry] = free_positions
                its2, res2, stl2, bind2, obst2, pen2 = self.iteration.iterate(Q, retry, True)
                old_pen = pen[np.searchsorted(rows, retry)]
                better = (pen2 < old_pen) | ((pen2 == old_pen) & (res2 < residual[retry]))
                iterations[retry] += free_iterations + its2
                keep = retry[better]
                P[keep], residual[keep], stalled[keep] = Q[keep], res2[better], stl2[better]
                limit_binding[keep], obstacle_active[keep] = bind2[better], obst2[better]

        inside, crossing = self.penetration_counts(P)
        # Plain Python values: indexing numpy arrays element by element costs more than the status logic.
        status, reason = statuses(zip((residual <= tol).tolist(), reachable.tolist(), dist.tolist(), total.tolist(),
                                      inner.tolist(), stalled.tolist(), iterations.tolist(),
                                      obstacle_active.tolist(), limit_binding.tolist()),
                                  self.obstacles, inside, crossing)
        return ChainBatchResult(P, iterations, residual, reachable, status, reason)

