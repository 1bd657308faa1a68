"""A few limited chains' FABRIK iterations without obstacles in plain floats (PlainIterations._iterate_plain, mixed
into ChainModel): ChainModel._iterate's operations in its order, one chain at a time, so the same bits. Where the
limits hold a chain short it iterates until its patience runs out, each numpy iteration paying numpy's per-call cost
on every joint's 3-vectors: a rig's own IK locks made one Adjust Pose run some 300 of them. The two-segment finish
and the nudge of a stalled chain stay numpy's (on the one chain); a division by zero hands the whole call back to
the numpy path."""

import numpy as np

from . import geometry_plain as g
from .chain_types import _COINCIDENT, _NUDGES, _PATIENCE, _STALL
from .limits import FREE, HINGE


class PlainIterations:
    """ChainModel's plain-float twin of _iterate for chains with limits and no boxes; it uses the model's targets,
    base, lengths, limits, the plain limit step (_plain_limit_one), the two-segment finish and the nudge
    directions."""

    def _iterate_plain(self, P, rows, force):
        """_iterate(P, rows, force) for limited chains without boxes, or None (nothing written) where plain floats
        cannot take a chain (numpy would divide by zero)."""
        force = np.broadcast_to(np.asarray(force, dtype=bool), rows.shape).tolist()
        solved = []
        try:
            for r, forced in zip(rows.tolist(), force):
                solved.append(self._iterate_one(r, P[r].tolist(), forced))
        except ZeroDivisionError:
            return None
        b = rows.size
        for r, one in zip(rows.tolist(), solved):
            P[r] = one[0]
        iterations, residual, stalled, binding = (np.array([one[k] for one in solved]) for k in range(1, 5))
        return (iterations.astype(np.int64), residual.astype(np.float64), stalled.astype(bool),
                binding.astype(bool), np.zeros(b, dtype=bool), np.zeros(b, dtype=np.int64))

    def _iterate_one(self, r, chain, forced):
        """(pose, iterations, residual, stalled, limit binding) of problem r from its pose ``chain`` (lists)."""
        s = self.settings
        tol = s.tolerance
        stall = tol * _STALL
        target = self.targets[r].tolist()
        lengths = self.lengths[r].tolist()
        residual = g.norm(g.sub(chain[-1], target))
        if not (residual > tol or forced):
            return chain, 0, residual, False, False
        iterations = nudges = best_iter = 0
        best, best_res = chain, np.inf
        while True:
            prev = chain
            placed = list(prev)
            self._forward_one(r, placed, prev, target, lengths)
            binding = self._backward_one(r, placed, list(placed), prev, lengths)
            iterations += 1
            res = g.norm(g.sub(placed[-1], target))
            moved = g.norm(g.sub(placed[-1], prev[-1]))
            stalled = res > tol and moved < stall
            chain = placed
            if stalled and nudges < _NUDGES and iterations < s.max_iterations and not binding:
                chain = self._nudged_one(r, placed, nudges)
                nudges += 1
                stalled = False
            # No boxes: every iterate has 0 penetrations, fewer than _iterate's start count, so the best is the
            # first iterate (whatever its residual), then each nearer one.
            first = iterations == 1
            if first or res < best_res - stall:  # (against the best before this iterate)
                best_iter = iterations
            if first or res < best_res:
                best, best_res = placed, res
            stalled = stalled or (res > tol and iterations - best_iter >= _PATIENCE)
            if res <= tol or stalled or iterations >= s.max_iterations:
                return best, iterations, best_res, stalled, binding

    def _forward_one(self, r, P, prev, target, lengths):
        """forward() of problem r in place on its pose P (a list of joints), without boxes."""
        limits = self.limits
        n = self.n
        P[-1] = target
        for i in range(n - 2, -1, -1):
            anchor = P[i + 1]
            d = g.sub(P[i], anchor)
            L = lengths[i]
            dn = g.norm(d)
            if not dn > L * _COINCIDENT:
                d = g.sub(prev[i], prev[i + 1])
                dn = g.norm(d)
            if i < n - 2 and limits.kind[i + 1] != FREE:
                child = g.divided(g.sub(P[i + 2], anchor), lengths[i + 1])
                child = g.divided(child, g.norm(child))
                fallback = g.sub(prev[i + 1], prev[i])
                fallback = g.divided(fallback, g.norm(fallback))
                u = self._plain_limit_one(i + 1, r, child, (-d[0] / dn, -d[1] / dn, -d[2] / dn), fallback,
                                          reverse=True)[0]
                P[i] = (anchor[0] - u[0] * L, anchor[1] - u[1] * L, anchor[2] - u[2] * L)
            else:
                k = L / dn
                P[i] = (anchor[0] + d[0] * k, anchor[1] + d[1] * k, anchor[2] + d[2] * k)

    def _backward_one(self, r, P, aims, prev, lengths):
        """backward() of problem r in place on its pose P, aiming at ``aims`` (the forward pass's joints), without
        boxes, root or stretch; returns whether a limit bound."""
        limits = self.limits
        n = self.n
        P[0] = tuple(self.base[r].tolist())
        binding = False
        pivot = n - 3 if self._finishes else -1
        finished = False
        for i in range(n - 1):
            if i == pivot:
                done, elbow, wrist = self._two_bone_finish(np.array([P]), np.array([r]), np.array([aims]))
                finished = bool(done[0])
                elbow, wrist = tuple(elbow[0].tolist()), tuple(wrist[0].tolist())
            anchor = P[i]
            d = g.sub(aims[i + 1], anchor)
            if i + 1 < n - 1 and limits.kind[i + 1] == HINGE:
                d = g.sub(aims[i + 1], aims[i])  # as backward(): the hinge's parent keeps its forward direction
            L = lengths[i]
            dn = g.norm(d)
            if not dn > L * _COINCIDENT:
                d = g.sub(prev[i + 1], prev[i])
                dn = g.norm(d)
            if limits.kind[i] != FREE:
                if i == 0:
                    parent = self.parent_dirs[r].tolist()
                else:
                    parent = g.divided(g.sub(P[i], P[i - 1]), lengths[i - 1])
                    parent = g.divided(parent, g.norm(parent))
                fallback = g.sub(prev[i + 1], prev[i])
                fallback = g.divided(fallback, g.norm(fallback))
                u, bind = self._plain_limit_one(i, r, parent, g.divided(d, dn), fallback)
                binding = binding or bool(bind)
                cand = (anchor[0] + u[0] * L, anchor[1] + u[1] * L, anchor[2] + u[2] * L)
            else:
                k = L / dn
                cand = (anchor[0] + d[0] * k, anchor[1] + d[1] * k, anchor[2] + d[2] * k)
            if finished and i >= pivot:
                cand = elbow if i == pivot else wrist
                binding = False
            P[i + 1] = cand
        return binding

    def _nudged_one(self, r, P, nudges):
        """Problem r's pose P after its nudges-th nudge: ChainModel._nudge itself, on problem r's row of a batch."""
        batch = np.zeros((self.B, self.n, 3))
        batch[r] = P
        self._nudge(batch, np.array([r]), np.array([nudges]), np.array([0]))
        return [tuple(joint) for joint in batch[r].tolist()]
