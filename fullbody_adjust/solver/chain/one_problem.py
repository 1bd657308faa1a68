"""One problem's solve on Python floats (OneProblem, owned by chain.model.ChainModel): what ChainModel does on
arrays for many problems, for a few of them one at a time, where numpy's per-call cost on 3-vectors was most of the
work (a rig's own IK locks made one Adjust Pose run some 300 limited iterations; one frame's solve stretches a trunk
or an arm toward a far target several times, or finds a warm start already placed). The calculations are not
repeated here: FABRIK's passes (ChainModel.forward/backward), the limits (ChainLimits), the two-segment finish and
the obstacle response are the ones the arrays take, called on the problem's floats. What is here is the per-problem
bookkeeping of the iteration loop and of the settled shortcut (a target beyond reach: one stretched pass; a start
at its target within its limits: returned untouched), and the paper's circle tried point by point up to the first
clear one (the arrays test all of it). A division by zero in the loop hands the call back to the arrays; oriented
boxes are left to them."""

import numpy as np

from ..maths import vectors as g
from .settings import _NUDGES, _PATIENCE, _STALL, ChainBatchResult, _final_status
from ..limits.joint_limits import FREE

_NO_PENETRATION_YET = np.iinfo(np.int64).max  # _iterate's best penetration count before the first iterate


class OneProblem:
    """The `chain` (ChainModel) solved one problem at a time on floats."""

    def __init__(self, chain):
        self.chain = chain

    def iterate(self, P, rows, force):
        """_iterate(P, rows, force) for limited or obstructed chains (boxes axis-aligned), or None (nothing written)
        where plain floats cannot take a chain (numpy would divide by zero)."""
        force = np.broadcast_to(np.asarray(force, dtype=bool), rows.shape).tolist()
        solved = []
        try:
            for r, forced in zip(rows.tolist(), force):
                solved.append(self._iterate_one(r, P[r].tolist(), forced))
        except ZeroDivisionError:
            return None
        for r, one in zip(rows.tolist(), solved):
            P[r] = one[0]
        iterations, residual, stalled, binding, responded, pen = (np.array([one[k] for one in solved])
                                                                  for k in range(1, 7))
        return (iterations.astype(np.int64), residual.astype(np.float64), stalled.astype(bool),
                binding.astype(bool), responded.astype(bool), pen.astype(np.int64))

    def _iterate_one(self, r, chain, forced):
        """(pose, iterations, residual, stalled, limit binding, obstacle responded, penetrations) of problem r from
        its pose ``chain`` (lists): the best iterate, with the binding and response of the last one as _iterate
        reports them."""
        s = self.chain.settings
        tol = s.tolerance
        stall = tol * _STALL
        target = self.chain.targets[r].tolist()
        residual = g.norm(g.sub(chain[-1], target))
        if not (residual > tol or forced):
            return chain, 0, residual, False, False, False, self._penetrations_one(chain, r)
        iterations = nudges = best_iter = 0
        best, best_res, best_pen = chain, np.inf, _NO_PENETRATION_YET
        while True:
            prev = chain
            placed = list(prev)
            responded = self.chain.forward(placed, r, prev, prev)[0]
            binding, responded_back, _ = self.chain.backward(placed, r, list(placed), prev, prev)
            responded = responded or responded_back
            iterations += 1
            res = g.norm(g.sub(placed[-1], target))
            moved = g.norm(g.sub(placed[-1], prev[-1]))
            stalled = res > tol and moved < stall
            chain = placed
            if stalled and nudges < _NUDGES and iterations < s.max_iterations and not binding and not responded:
                chain = self._nudged_one(r, placed, nudges)
                nudges += 1
                stalled = False
            pen = self._penetrations_one(placed, r)  # of the iterate, not of the nudged pose
            if pen < best_pen or res < best_res - stall:  # (against the best before this iterate)
                best_iter = iterations
            if pen < best_pen or (pen == best_pen and res < best_res):
                best, best_res, best_pen = placed, res, pen
            stalled = stalled or (res > tol and iterations - best_iter >= _PATIENCE)
            if res <= tol or stalled or iterations >= s.max_iterations:
                return best, iterations, best_res, stalled, binding, responded, best_pen

    def _penetrations_one(self, chain, r):
        """penetration_counts of one chain, joints and segments added (0 without boxes)."""
        if self.chain.boxes is None:
            return 0
        inside, crossing = self.chain.obstacles.penetration_counts(chain, r)
        return inside + crossing

    def _nudged_one(self, r, P, nudges):
        """Problem r's pose P after its nudges-th nudge: ChainModel._nudge itself, on problem r's row of a batch."""
        batch = np.zeros((self.chain.B, self.chain.n, 3))
        batch[r] = P
        self.chain._nudge(batch, np.array([r]), np.array([nudges]), np.array([0]))
        return [tuple(joint) for joint in batch[r].tolist()]

    def settled(self, start):
        """ChainModel.solve(start) in plain floats, or None when some problem needs FABRIK's iterations (a target
        within reach and not met, a limit broken at the start) or a step numpy would divide by zero in."""
        tol = self.chain.settings.tolerance
        limited = [] if self.chain.limits is None else np.nonzero(self.chain.limits.kind != FREE)[0].tolist()
        problems = []
        for chain, lengths, target, base in zip(start.tolist(), self.chain.lengths.tolist(), self.chain.targets.tolist(),
                                                self.chain.base.tolist()):
            total = lengths[0]  # summed left to right, as _reach_bounds does
            for length in lengths[1:]:
                total = total + length
            dist = g.norm(g.sub(target, base))
            if not dist > total and not g.norm(g.sub(chain[-1], target)) <= tol:
                return None  # FABRIK's iterations: known before any limit is looked at
            problems.append((chain, lengths, target, base, total, dist))
        rows = []
        try:
            for r, (chain, lengths, target, base, total, dist) in enumerate(problems):
                if dist > total:
                    stretched = list(chain)  # every joint aimed at the target, limited where its joint is
                    self.chain.backward(stretched, r, [target] * self.chain.n, chain, chain, stretch=True)
                    chain = stretched
                    iterations = 1
                elif limited and self.chain.limiting.broken(r, chain, lengths):
                    return None
                else:
                    iterations = 0
                residual = g.norm(g.sub(chain[-1], target))
                inner = max(2.0 * max(lengths) - total, 0.0)
                reachable = not dist > total and dist >= inner
                # Whether a limit bound matters to a status only within reach: False for both kinds here.
                rows.append((chain, iterations, residual, reachable,
                             _final_status(residual <= tol, reachable, dist, total, inner, False, iterations, False,
                                           False)))
        except ZeroDivisionError:
            return None
        return ChainBatchResult(np.array([row[0] for row in rows], dtype=np.float64),
                                np.array([row[1] for row in rows], dtype=np.int64),
                                np.array([row[2] for row in rows], dtype=np.float64),
                                np.array([row[3] for row in rows], dtype=bool),
                                np.array([row[4][0] for row in rows], dtype=str),
                                np.array([row[4][1] for row in rows], dtype=str))
