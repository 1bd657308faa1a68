"""What a chain solve does with each problem (Iteration, owned by chain.model.ChainModel), written once for one
problem on its Python floats (rows an int, its pose a list of joints) and for many on arrays (rows an index array,
poses (b,n,3)); maths/lanes.py (by_rows) decides which: a few problems one at a time, where numpy's per-call cost on
3-vectors is most of the work (a rig's own IK locks made one Adjust Pose run some 300 limited iterations). The
stages: the stretched pass toward a target beyond reach, the check of a start already at its target (a limit
broken or a box penetrated), and FABRIK's iteration loop with its stall, nudge and best-iterate bookkeeping."""

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec
from .settings import _NUDGE, _NUDGES, _GAIN, _PATIENCE, _PROGRESS, _STALL, _WINDOW

_NO_PENETRATION_YET = np.iinfo(np.int64).max  # the best penetration count before the first iterate


def _chosen(cond, a, b):
    """Pose a where cond, else b: one problem's (lists of joints, cond a bool) or many's ((b,n,3), cond (b,))."""
    if cond.__class__ is np.ndarray:
        return np.where(cond[:, None, None], a, b)
    return a if cond else b


class Iteration:
    """The stages of a `chain` (ChainModel) solve on some of its problems."""

    def __init__(self, chain):
        self.chain = chain
        # Oriented boxes, or many of them, are tested on arrays: their problems too.
        self.floats = chain.boxes is None or chain.obstacles.floats

    def stretched(self, P, rows):
        """One stretched pass (every joint aimed at its target) in place on P (B,n,3) of problems `rows` (targets
        beyond reach): (limit binding, obstacle responded) per problem."""
        return lanes.by_rows(self._stretched, P, rows, kinds=(bool, bool), floats=self.floats)

    def _stretched(self, pose, rows):
        one = rows.__class__ is int
        placed = list(pose) if one else pose.copy()
        aims = [self.chain._problem(rows)[1]] * self.chain.n if one else \
            np.broadcast_to(self.chain.targets[rows][:, None, :], pose.shape)
        binding, responded, _ = self.chain.backward(placed, rows, aims, pose, pose, stretch=True)
        return placed, binding, responded

    def violations(self, P, rows):
        """(b,) problems `rows` whose pose P (B,n,3) breaks a joint limit (beyond rounding) or penetrates a box it
        does not ignore."""
        return lanes.by_rows(self._violations, P, rows, kinds=(bool,), floats=self.floats)[0]

    def _violations(self, pose, rows):
        one = rows.__class__ is int
        bad = False if one else np.zeros(rows.size, dtype=bool)
        if self.chain.limits is not None:
            bad = bad | self.chain.limiting.broken(rows, pose, self.chain._problem(rows)[0] if one
                                                   else self.chain.lengths[rows])
        if self.chain.boxes is not None:
            bad = bad | (self.penetrations(pose, rows) > 0)
        return pose, bad

    def iterate(self, P, rows, force):
        """FABRIK iterations on problems `rows`, in place on P (B,n,3). Rows whose end is already within
        tolerance only iterate if `force` (bool or per row (b,)). Returns per-row (iterations, residual,
        stalled, limit binding, obstacle responses in the returned iterate, penetrations of the returned
        iterate)."""
        return lanes.by_rows(self._loop, P, rows, force, kinds=(np.int64, np.float64, bool, bool, bool, np.int64),
                             floats=self.floats)

    def penetrations(self, pose, rows):
        """Joints inside and segments crossing a box, added, of one problem's pose (an int) or many's ((b,))."""
        if self.chain.boxes is None:
            return 0 if rows.__class__ is int else np.zeros(rows.size, dtype=np.int64)
        inside, crossing = self.chain.obstacles.penetration_counts(pose, rows)
        return inside + crossing

    def _loop(self, pose, rows, force):
        """The iteration loop of one problem (rows an int, pose its list of joints, force a bool) or many (rows an
        index array, pose (b,n,3), force (b,)): each problem leaves it when it is within tolerance, stalls or reaches
        the iteration cap; with limits or boxes it returns its best iterate (fewest penetrations, then the smallest
        residual). (pose, iterations, residual, stalled, limit binding and obstacle responses of the last iterate,
        penetrations of the returned one), per problem."""
        s = self.chain.settings
        tol, cap, stall = s.tolerance, s.max_iterations, s.tolerance * _STALL
        one = rows.__class__ is int
        constrained = self.chain.limits is not None or self.chain.boxes is not None
        target = self.chain._problem(rows)[1] if one else self.chain.targets[rows]
        residual = vec.norm(vec.sub(pose[-1] if one else pose[:, -1], target))
        go = (residual > tol) | force
        if one and not go:
            return pose, 0, residual, False, False, False, self.penetrations(pose, rows)
        if one:
            lane = active = rows
            zero = 0
        else:
            no = np.zeros(rows.size, dtype=bool)
            out = [pose, np.zeros(rows.size, dtype=np.int64), residual, no, no.copy(), no.copy(),
                   self.penetrations(pose, rows) if constrained else np.zeros(rows.size, dtype=np.int64)]
            lane = np.nonzero(go)[0]  # the problems still iterating, as positions in rows
            if lane.size == 0:
                return tuple(out)
            active, pose, target, residual = rows[lane], pose[lane], target[lane], residual[lane]
            zero = np.zeros(lane.size, dtype=np.int64)
        iterations = nudges = marked = zero
        best, best_res, best_pen = pose, zero + np.inf, zero + (_NO_PENETRATION_YET if constrained else 0)
        mark = residual  # the best residual when progress was last marked (at first the start's)
        check = residual  # the best residual at the last window's end (_WINDOW; at first the start's)
        count = 0  # iterations so far: the same in every lane (they all start together)
        while True:
            prev = pose
            placed = list(prev) if one else prev.copy()
            responded = self.chain.forward(placed, active, prev, prev)[0]
            aims = list(placed) if one else placed.copy()
            binding, responded_back, _ = self.chain.backward(placed, active, aims, prev, prev)
            responded = responded | responded_back
            iterations = iterations + 1
            end, moved_from = (placed[-1], prev[-1]) if one else (placed[:, -1], prev[:, -1])
            res = vec.norm(vec.sub(end, target))
            stalled = (res > tol) & (vec.norm(vec.sub(end, moved_from)) < stall)
            pose = placed
            free = stalled & (nudges < _NUDGES) & (iterations < cap) & lanes.not_(binding | responded)
            if lanes.any_(free):
                pose = _chosen(free, self.nudged(placed, active, nudges), placed)
                nudges = nudges + free
                check = lanes.where(free, np.inf, check)  # a nudged chain's rate starts over
                stalled = stalled & lanes.not_(free)
            # Progress: the kept iterate has fewer penetrations, or its residual's excess over the tolerance shrank
            # by _PROGRESS of what it was at the last mark (at least by `stall`).
            gained = mark - res > lanes.maximum((mark - tol) * _PROGRESS, stall)
            if constrained:
                pen = self.penetrations(placed, active)  # of the iterate, not of the nudged pose
                better = (pen < best_pen) | ((pen == best_pen) & (res < best_res))
                improved = (pen < best_pen) | ((pen == best_pen) & gained)  # against the best before this iterate
                best = _chosen(better, placed, best)
                best_res, best_pen = lanes.where(better, res, best_res), lanes.where(better, pen, best_pen)
            else:
                best, best_res, improved = placed, res, gained
            mark, marked = lanes.where(improved, res, mark), lanes.where(improved, iterations, marked)
            stalled = stalled | ((res > tol) & (iterations - marked >= _PATIENCE))
            count += 1
            if constrained and count % _WINDOW == 0:
                stalled = stalled | self._hopeless(best_res, check, best_pen, cap - count)
            if count == 1 or count % _WINDOW == 0:  # the windows measure from the first iterate
                # A window that starts with penetrations is not judged (inf: a rate of 0, some prospect left).
                check = lanes.where(best_pen == 0, best_res, np.inf)
            done = (res <= tol) | stalled | (iterations >= cap)
            if one:
                if done:
                    return best, iterations, best_res, stalled, binding, responded, best_pen
                continue
            if not lanes.any_(done):
                continue
            for o, v in zip(out, (best, iterations, best_res, stalled, binding, responded, best_pen)):
                o[lane[done]] = v[done]
            keep = ~done
            if not lanes.any_(keep):
                return tuple(out)
            (lane, active, target, pose, iterations, nudges, best, best_res, best_pen, mark, marked, check) = (
                x[keep] for x in (lane, active, target, pose, iterations, nudges, best, best_res, best_pen, mark, marked,
                                  check))

    def _hopeless(self, best_res, check, best_pen, left):
        """Whether a problem's best iterate, at the end of a _WINDOW of iterations (the first measured from the first
        iterate) in which its best residual went from `check` to `best_res` with no penetration left, has no worthwhile
        prospect in the `left` iterations still allowed: shrinking at that window's rate it would still miss the
        tolerance and gain less than _GAIN of its residual (a sufficient-decrease test: a limited arm near the edge
        of its reach creeps by a fraction of a per cent an iteration until the cap). A window with no gain at all is
        left to _PATIENCE: a chain started outside its limits can swing away from its target for ten iterations and
        then converge (tests/solver/test_start_range.py). The rate is taken per whole window and multiplied out, so
        one problem and many decide alike to the last bit."""
        tol = self.chain.settings.tolerance
        ratio = lanes.minimum(lanes.divide(best_res, check), 1.0)  # no gain (or a start at 0): not judged
        projected = best_res
        for _ in range(-(-left // _WINDOW)):
            projected = projected * ratio
        return (ratio < 1.0) & (projected > tol) & (projected > best_res * (1.0 - _GAIN)) & (best_pen == 0)

    def nudged(self, pose, rows, nudges):
        """The pose (as the passes take it) with its interior joints pushed sideways (see _NUDGES), by each problem's
        nudge `nudges` (0 or 1): perpendicular to its base -> target line (to its first segment where the target is
        at the base), then perpendicular to both; joint i moves by _NUDGE of segment i-1."""
        lengths, joints = self.chain._columns(rows, pose)
        one = joints is pose
        if one:
            _lengths, target, base, _parent = self.chain._problem(rows)
        else:
            target, base = self.chain.targets[rows], self.chain.base[rows]
        v = vec.sub(target, base)
        v = lanes.pick(lanes.not_(vec.norm(v) > 0.0), vec.sub(joints[1], base), v)
        v = vec.divided(v, vec.norm(v))
        u = vec.any_perpendicular(v)
        if lanes.any_(nudges == 1):
            q = vec.cross(v, u)
            u = lanes.pick(nudges == 1, vec.divided(q, vec.norm(q)), u)
        moved = [joints[0]] + [vec.add(joints[i], vec.scaled(u, lengths[i - 1] * _NUDGE))
                               for i in range(1, self.chain.n - 1)] + [joints[-1]]
        return moved if one else np.stack(moved, axis=1)
