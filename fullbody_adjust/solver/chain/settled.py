"""The chain solves that need no iteration, for a few chains with limits and without obstacles, in plain floats:
a target beyond reach (one stretched backward pass) and a start already at its target within its limits (returned
untouched). One frame's solve makes several such calls (a trunk or an arm stretched toward a far target, limbs a
warm start already placed), and for them ChainModel's bookkeeping in numpy cost more than the work
(SettledChains._solve_settled, mixed into ChainModel). The operations are the numpy path's in its order, the limits
those of limits/limits_plain.py, so each call returns the numpy path's bits (tests/solver/test_chain_settled.py)."""

import numpy as np

from ..maths import vectors as g
from .settings import ChainBatchResult, _final_status
from ..limits.joint_limits import FREE


class SettledChains:
    """ChainModel.solve for problems that each either stretch toward a target beyond reach or start at their
    target within their limits; it uses the model's lengths, targets, limits and parent directions, and its
    plain limit steps."""

    def _solve_settled(self, start):
        """ChainModel.solve(start) in plain floats, or None when some problem needs FABRIK's iterations (a target
        within reach and not met, a limit broken at the start) or a step numpy would divide by zero in."""
        tol = self.settings.tolerance
        limited = [] if self.limits is None else np.nonzero(self.limits.kind != FREE)[0].tolist()
        problems = []
        for chain, lengths, target, base in zip(start.tolist(), self.lengths.tolist(), self.targets.tolist(),
                                                self.base.tolist()):
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
                    self.backward(stretched, r, [target] * self.n, chain, chain, stretch=True)
                    chain = stretched
                    iterations = 1
                elif limited and self.limiting.broken(r, chain, lengths):
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
