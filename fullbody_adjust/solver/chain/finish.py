"""Two-segment finish of the batch chain solver's backward pass (beyond FABRIK; see chain/fabrik.py): the last two
segments are placed analytically where a swivel position of the middle joint meets the target with every limit
and obstacle satisfied (TwoBoneFinish._two_bone_finish, mixed into ChainModel)."""

import math

import numpy as np

from ..maths import lanes
from ..maths import vectors as g
from ..maths.geometry import any_set, cross, dot, norm, outward_angles, unit_or_perpendicular
from ..obstacles.boxes import penetrates_one

# Two-segment finish (ChainModel._two_bone_finish): swivel angles of the middle joint around the pivot ->
# target line, from FABRIK's proposal outward (0, +d, -d, +2d, ...), and the least hinge twist range that
# leaves an interval of them to pick from (a twist-free hinge fits one swivel angle, never a sample).
_SWIVEL_ANGLES = outward_angles(48)
_SWIVEL_COS, _SWIVEL_SIN = np.cos(_SWIVEL_ANGLES), np.sin(_SWIVEL_ANGLES)
_SWIVEL_COS_LIST, _SWIVEL_SIN_LIST = _SWIVEL_COS.tolist(), _SWIVEL_SIN.tolist()
_MIN_FINISH_TWIST = math.radians(5)


class TwoBoneFinish:
    """The two-segment finish of a chain batch's backward pass (owned by chain.model.ChainModel, the `chain` whose
    lengths, targets, limits and obstacles it reads)."""

    def __init__(self, chain):
        self.chain = chain

    def place(self, rows, P, aims):
        """The finish of one problem (rows an int; P, aims its lists of joints) or many (arrays): (finished, middle,
        end)."""
        if rows.__class__ is not int:
            return self._two_bone_finish(P, rows, aims)
        one = self._two_bone_finish_one(rows, P, aims)
        if one is None:  # the finish on arrays, of the one chain
            done, elbow, wrist = self._two_bone_finish(np.array([P]), np.array([rows]), np.array([aims]))
            one = bool(done[0]), tuple(elbow[0].tolist()), tuple(wrist[0].tolist())
        return one

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

    def _two_bone_finish_one(self, r, P, aims):
        """_two_bone_finish of problem r alone, in plain floats (P, aims: its joints as lists): (finished, middle,
        end), or None where numpy decides (the first candidate clear of the boxes breaks a limit, or a division by
        zero). The candidates are made and tested against the boxes in order, up to the first clear one: numpy
        made and tested all 48 first, most of a finish's cost where the boxes leave an early one clear."""
        if self.chain.boxes is not None and self.chain.boxes.axes is not None:
            return None  # oriented boxes: numpy's tests
        j = self.chain.n - 3
        none = (0.0, 0.0, 0.0)
        lengths = self.chain.lengths[r].tolist()
        a, c = lengths[j], lengths[j + 1]
        S = tuple(P[j])
        T = self.chain.targets[r].tolist()
        to_t = g.sub(T, S)
        d = g.norm(to_t)
        if not (d > abs(a - c) * (1.0 + 1e-9) and d < (a + c) * (1.0 - 1e-9)):
            return False, none, none
        try:
            e = g.divided(to_t, d)
            along = (a * a + d * d - c * c) / (2.0 * d)
            rho = math.sqrt(max(a * a - along * along, 0.0))
            centre = g.add(S, g.scaled(e, along))
            w = g.sub(aims[j + 1], centre)
            w = g.sub(w, g.scaled(e, g.dot(w, e)))
            wn = g.norm(w)
            e1 = g.divided(w, wn) if wn > 1e-12 * a else g.any_perpendicular(e)
            e2 = g.cross(e, e1)
            boxes = None if self.chain.boxes is None else self.chain.obstacles.boxes_of(r)
            if boxes is not None:  # what the two segments (and the joints at their ends) ignore, as _ignored says
                lo, hi = boxes[0], boxes[1]
                skip_middle, skip_pivot_segment = self.chain.obstacles.ignored_of(boxes, j + 1, j)
                skip_end, skip_end_segment = self.chain.obstacles.ignored_of(boxes, j + 2, j + 1)
            first = None
            for cos_k, sin_k in zip(_SWIVEL_COS_LIST, _SWIVEL_SIN_LIST):
                ring = (cos_k * e1[0] + sin_k * e2[0], cos_k * e1[1] + sin_k * e2[1], cos_k * e1[2] + sin_k * e2[2])
                middle = (centre[0] + rho * ring[0], centre[1] + rho * ring[1], centre[2] + rho * ring[2])
                v = g.sub(T, middle)
                v = g.divided(v, g.norm(v))
                end = (middle[0] + c * v[0], middle[1] + c * v[1], middle[2] + c * v[2])
                if first is None:
                    first = g.divided(g.sub(middle, S), a)  # the pivot limit's fallback: the first candidate's
                if boxes is not None and (penetrates_one(lo, hi, S, middle, skip_middle, skip_pivot_segment)
                                          or penetrates_one(lo, hi, middle, end, skip_end, skip_end_segment)):
                    continue
                u = g.divided(g.sub(middle, S), a)
                holds = self.chain.limiting.finish_holds(r, [list(joint) for joint in P], g.divided(u, g.norm(u)),
                                                   g.divided(first, g.norm(first)), list(v))
                return (True, middle, end) if holds else None
        except ZeroDivisionError:
            return None
        return False, none, none  # no candidate clear of the boxes

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

    # -- solve -------------------------------------------------------------------------------------------------
