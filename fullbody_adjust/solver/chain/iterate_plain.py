"""A few constrained chains' FABRIK iterations in plain floats (PlainIterations._iterate_plain, mixed into
ChainModel): ChainModel._iterate's operations in its order, one chain at a time, so the same bits. Where the limits
hold a chain short it iterates until its patience runs out, each numpy iteration paying numpy's per-call cost on
every joint's 3-vectors: a rig's own IK locks made one Adjust Pose run some 300 of them; among obstacles, the joints
the boxes leave alone were most of an iteration's cost. The two-segment finish and the paper's circle for a joint
inside a box are plain where they find their answer (TwoBoneFinish._two_bone_finish_one, _circle_point_one); the
rest of the obstacle response and the nudge of a stalled chain stay numpy's (on the one chain); a division by zero
hands the whole call back to the numpy path. Oriented boxes are left to numpy."""

import math

import numpy as np

from ..maths import vectors as g
from ..obstacles.response import _CIRCLE_COS, _CIRCLE_SIN
from .settings import _NUDGES, _PATIENCE, _STALL
from ..obstacles.boxes import count_penetrations_one, first_box_holding, penetrates_one

_CIRCLE_COS_LIST, _CIRCLE_SIN_LIST = _CIRCLE_COS.tolist(), _CIRCLE_SIN.tolist()

_NO_PENETRATION_YET = np.iinfo(np.int64).max  # _iterate's best penetration count before the first iterate


class PlainIterations:
    """ChainModel's plain-float twin of _iterate for chains with limits or axis-aligned boxes; it uses the model's
    targets, base, lengths, limits, the plain limit step (_plain_limit_one), boxes and what each chain ignores, the
    obstacle response (_avoid), the two-segment finish and the nudge directions."""

    def _iterate_plain(self, P, rows, force):
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
        s = self.settings
        tol = s.tolerance
        stall = tol * _STALL
        target = self.targets[r].tolist()
        boxes = None if self.boxes is None else self.obstacles.boxes_of(r)
        residual = g.norm(g.sub(chain[-1], target))
        if not (residual > tol or forced):
            return chain, 0, residual, False, False, False, self._penetrations_one(chain, boxes)
        iterations = nudges = best_iter = 0
        best, best_res, best_pen = chain, np.inf, _NO_PENETRATION_YET
        while True:
            prev = chain
            placed = list(prev)
            responded = self.forward(placed, r, prev, prev)[0]
            binding, responded_back, _ = self.backward(placed, r, list(placed), prev, prev)
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
            pen = self._penetrations_one(placed, boxes)  # of the iterate, not of the nudged pose
            if pen < best_pen or res < best_res - stall:  # (against the best before this iterate)
                best_iter = iterations
            if pen < best_pen or (pen == best_pen and res < best_res):
                best, best_res, best_pen = placed, res, pen
            stalled = stalled or (res > tol and iterations - best_iter >= _PATIENCE)
            if res <= tol or stalled or iterations >= s.max_iterations:
                return best, iterations, best_res, stalled, binding, responded, best_pen

    def _penetrations_one(self, chain, boxes):
        """penetration_counts of one chain, joints and segments added (0 without boxes)."""
        if boxes is None:
            return 0
        inside, crossing = count_penetrations_one(chain, *boxes)
        return inside + crossing

    def _avoid_one(self, r, anchor, cand, L, ref, joint, segment, boxes, limit):
        """_avoid for problem r's one joint: (position, responded). The plain test first (the joint and its
        segment clear of every box it does not ignore: the position as it is), then the paper's circle in plain
        floats (_circle_point_one); numpy's whole response where that finds no clear point. ``limit``: (joint,
        parent direction, fallback) of the backward pass's limit on the joint's direction, or None."""
        lo, hi = boxes[0], boxes[1]
        skip_point, skip_segment = self.obstacles.ignored_of(boxes, joint, segment)
        if not penetrates_one(lo, hi, anchor, cand, skip_point, skip_segment):
            return cand, False
        point = self._circle_point_one(r, anchor, cand, L, ref, lo, hi, skip_point, skip_segment, limit)
        if point is not None:
            return point, True
        limit_fn = None
        if limit is not None:
            i, parent, fallback = limit

            def limit_fn(h, dirs):  # backward()'s, on this one row
                return self.limiting.step(i, np.array([r])[h], np.array([parent])[h], dirs, np.array([fallback])[h])[0]
        out, responded, _ = self.obstacles.avoid(np.array([r]), np.array([anchor]), np.array([cand]), np.array([L]),
                                        np.array([ref]), joint, segment, limit_fn)
        return tuple(out[0].tolist()), bool(responded[0])

    def _circle_point_one(self, r, a, p, L, ref, lo, hi, skip_point, skip_segment, limit):
        """_avoid's answer for a joint at p inside a box when the paper's circle has a point clear of every box (the
        first, in _CIRCLE_ANGLES' order), in plain floats; None otherwise (numpy's whole response decides)."""
        k = first_box_holding(lo, hi, p, skip_point)
        if k < 0:
            return None  # only the segment crosses a box: every candidate is weighed (numpy)
        corners = (self.obstacles.corners[r, k] if self.boxes.batched else self.obstacles.corners[k]).tolist()
        dis = max(g.norm(g.sub(corner, p)) for corner in corners) + self.settings.margin
        axis = g.sub(p, a)
        dd = g.norm(axis)
        nvec = g.divided(axis, dd)
        along = (dd * dd + L * L - dis * dis) / (2.0 * dd)
        rho2 = L * L - along * along
        if not rho2 > 0.0:
            return None  # no circle
        rho = math.sqrt(rho2)
        center = g.add(a, g.scaled(nvec, along))
        w = g.sub(ref, center)
        w = g.sub(w, g.scaled(nvec, g.dot(w, nvec)))
        wn = g.norm(w)
        e1 = g.divided(w, wn) if wn > 1e-12 * L else g.any_perpendicular(nvec)
        e2 = g.cross(nvec, e1)
        for cos_k, sin_k in zip(_CIRCLE_COS_LIST, _CIRCLE_SIN_LIST):
            ring = (cos_k * e1[0] + sin_k * e2[0], cos_k * e1[1] + sin_k * e2[1], cos_k * e1[2] + sin_k * e2[2])
            point = (center[0] + rho * ring[0], center[1] + rho * ring[1], center[2] + rho * ring[2])
            d = ((point[0] - a[0]) / L, (point[1] - a[1]) / L, (point[2] - a[2]) / L)
            d = g.divided(d, g.norm(d))
            if limit is not None:
                d = self.limiting.step(limit[0], r, limit[1], d, limit[2])[0]
            q = (a[0] + L * d[0], a[1] + L * d[1], a[2] + L * d[2])
            if not penetrates_one(lo, hi, a, q, skip_point, skip_segment):
                return q
        return None

    def _nudged_one(self, r, P, nudges):
        """Problem r's pose P after its nudges-th nudge: ChainModel._nudge itself, on problem r's row of a batch."""
        batch = np.zeros((self.B, self.n, 3))
        batch[r] = P
        self._nudge(batch, np.array([r]), np.array([nudges]), np.array([0]))
        return [tuple(joint) for joint in batch[r].tolist()]
