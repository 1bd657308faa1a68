"""The settled shortcut of a few problems' solve on Python floats (OneProblem, owned by chain.model.ChainModel): where
no problem needs FABRIK's iterations (a target beyond reach: one stretched pass; a start at its target within its
limits: returned untouched), ChainModel.solve's answer without its arrays. The stretched pass and the limit check
are the model's own (ChainModel.backward, ChainLimits.broken) on the problem's floats. A division by zero hands the
call back to the arrays."""

import numpy as np

from ..maths import vectors as g
from .settings import ChainBatchResult, _final_status
from ..limits.joint_limits import FREE


class OneProblem:
    """The `chain` (ChainModel) solved one problem at a time on floats."""

    def __init__(self, chain):
        self.chain = chain

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
