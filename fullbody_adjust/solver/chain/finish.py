"""Two-segment finish of the batch chain solver's backward pass (beyond FABRIK; see chain/fabrik.py): the last two
segments are placed analytically where a swivel position of the middle joint meets the target with every limit
and obstacle satisfied (TwoBoneFinish, owned by ChainModel). Its candidates are many samples: one problem's too are
made and tested on arrays, as a batch of one."""

import math

import numpy as np

from ..maths import lanes
from ..maths import vectors as g
from ..maths.geometry import any_set, cross, dot, norm, outward_angles, unit_or_perpendicular

# Two-segment finish (TwoBoneFinish._two_bone_finish): swivel angles of the middle joint around the pivot ->
# target line, from FABRIK's proposal outward (0, +d, -d, +2d, ...), and the least hinge twist range that
# leaves an interval of them to pick from (a twist-free hinge fits one swivel angle, never a sample).
_SWIVEL_ANGLES = outward_angles(48)
_SWIVEL_COS, _SWIVEL_SIN = np.cos(_SWIVEL_ANGLES), np.sin(_SWIVEL_ANGLES)
_MIN_FINISH_TWIST = math.radians(5)


class TwoBoneFinish:
    """The two-segment finish of a chain batch's backward pass (owned by chain.model.ChainModel, the `chain` whose
    lengths, targets, limits and obstacles it reads)."""

    def __init__(self, chain):
        self.chain = chain

    def place(self, rows, P, aims):
        """The finish of one problem (rows an int; P, aims its lists of joints) or many (arrays): (finished, middle,
        end). Its candidates are many samples: one problem's are made and tested on arrays too, as a batch of one."""
        if rows.__class__ is not int:
            return self._two_bone_finish(P, rows, aims)
        done, middle, end = self._two_bone_finish(np.array([P]), np.array([rows]), np.array([aims]))
        return bool(done[0]), tuple(middle[0].tolist()), tuple(end[0].tolist())

    def _two_bone_finish(self, P, rows, aims):
        """Analytic placement of the last two segments in the backward pass, once their pivot joint n-3 is
        placed, for a limited chain whose joint n-2 is free, a cone, or a hinge with a twist range
        (_finishes): FABRIK creeps toward a target near full stretch, and a hinge lets it reach only by
        turning the bend plane, which its passes do not seek. With pivot S, target T and lengths a, c, the
        middle joint lies on the circle
        where the spheres (S, a) and (T, c) meet; of _SWIVEL_ANGLES around it (from the forward pass's middle
        joint, the one FABRIK aims at, outward) the first is taken where the pivot's limit, the hinge (bend
        and twist) and the obstacles all hold exactly. Returns (finished (b,), middle (b,3), end (b,3)); rows
        with no such point (target out of the two segments' range, limits or boxes) are left to FABRIK."""
        j = self.chain.n - 3
        b = len(rows)
        finished = np.zeros(b, dtype=bool)
        middle = np.zeros((b, 3))
        end = np.zeros((b, 3))
        lengths = self.chain.lengths[rows]
        a, c = lengths[:, j], lengths[:, j + 1]
        S = P[:, j]
        to_t = self.chain.targets[rows] - S
        d = norm(to_t)
        h = np.nonzero((d > np.abs(a - c) * (1.0 + 1e-9)) & (d < (a + c) * (1.0 - 1e-9)))[0]
        if h.size == 0:
            return finished, middle, end
        a, c, d, S, T = a[h], c[h], d[h], S[h], self.chain.targets[rows[h]]
        e = to_t[h] / d[:, None]
        along = (a * a + d * d - c * c) / (2.0 * d)
        rho = np.sqrt(np.maximum(a * a - along * along, 0.0))
        centre = S + along[:, None] * e
        w = aims[h, j + 1] - centre
        w = w - dot(w, e)[:, None] * e
        wn = norm(w)
        ok = wn > 1e-12 * a
        e1 = unit_or_perpendicular(w, wn, ok, e)
        e2 = cross(e, e1)
        ring = _SWIVEL_COS[None, :, None] * e1[:, None] + _SWIVEL_SIN[None, :, None] * e2[:, None]
        E = centre[:, None] + rho[:, None, None] * ring  # (h,K,3)
        v = T[:, None] - E
        v = v / norm(v)[..., None]
        k = j + 1
        wrist = E + c[:, None, None] * v
        ok = np.ones(E.shape[:2], dtype=bool)
        # The checks are ANDed: once no candidate is left the others are skipped. The boxes come first: where a
        # finish fails among obstacles, the lower segment's box test is what fails it (every failing finish of
        # bench/solver_speed.py's obstacle case and of three jittered copies of it), and it costs less than
        # the limits.
        if self.chain.boxes is not None:
            boxes = self.chain.boxes.select(rows[h])
            for seg, (p0, p1) in ((j, (S[:, None], E)), (k, (E, wrist))):
                if not any_set(ok):
                    break
                ign_joint, ign_seg = self.chain.obstacles.ignored(rows[h], seg + 1, seg)
                inside, crossing = self.chain.obstacles.violations(
                    boxes, np.broadcast_to(p0, p1.shape), p1,
                    None if ign_joint is None else ign_joint[:, None], None if ign_seg is None else ign_seg[:, None])
                ok &= ~(inside.any(axis=-1) | crossing.any(axis=-1))
        if any_set(ok):
            ok = self._first_clear_holds(rows[h], P[h], E, S, a, v, ok)
        pick = np.argmax(ok, axis=1)
        found = ok[np.arange(h.size), pick]
        finished[h] = found
        middle[h] = E[np.arange(h.size), pick]
        end[h] = wrist[np.arange(h.size), pick]
        return finished, middle, end

    def _first_clear_holds(self, rows, P, E, S, a, v, clear):
        """clear & _limits_hold(...) (h,K), as far as the pick needs it: a few chains' first candidate clear of the
        boxes is checked in plain floats, and where it keeps the limits it is the only candidate left; the other
        chains get every candidate checked in numpy."""
        if not lanes.few(len(rows)):
            return clear & self._limits_hold(rows, P, E, S, a, v)
        ok = np.zeros_like(clear)
        rest = []
        for q, (r, row) in enumerate(zip(rows.tolist(), clear)):
            c = int(np.argmax(row))
            if not row[c]:
                continue  # no candidate is clear of the boxes
            u = g.divided(g.sub(E[q, c].tolist(), S[q].tolist()), float(a[q]))
            first = g.divided(g.sub(E[q, 0].tolist(), S[q].tolist()), float(a[q]))
            try:
                holds = self.chain.limiting.finish_holds(r, P[q].tolist(), g.divided(u, g.norm(u)),
                                                   g.divided(first, g.norm(first)), v[q, c].tolist())
            except ZeroDivisionError:  # where numpy would divide by zero: numpy decides
                holds = False
            if holds:
                ok[q, c] = True
            else:
                rest.append(q)
        if rest:
            rest = np.array(rest)
            ok[rest] = clear[rest] & self._limits_hold(rows[rest], P[rest], E[rest], S[rest], a[rest], v[rest])
        return ok

    def _limits_hold(self, rows, P, E, S, a, v):
        """(h,K) bool: the finish candidates E (middle joints, from the pivots S, segment length a; v toward the
        target) of problems `rows` (P their poses) keep the limits (ChainLimits.finish_holds)."""
        u = (E - S[:, None]) / a[:, None, None]
        u = u / norm(u)[..., None]
        return self.chain.limiting.finish_holds(rows, P, u, u[:, 0], v)
