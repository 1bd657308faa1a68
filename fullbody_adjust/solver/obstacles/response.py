"""The paper's obstacle response (§4.1) for the batch chain solver: a joint that lands inside a box, or whose
segment crosses one, is moved to the nearest clear point (ObstacleResponse.avoid, owned by ChainModel). A few
problems' joints are first tested on their floats (boxes.hits); the response itself tests the paper's circle and the
sphere's samples at once on arrays, for one problem as for many."""

import numpy as np

from ..maths import lanes
from ..maths.geometry import all_set, any_set, cross, dot, norm, outward_angles, unit_or_perpendicular
from ..errors import SolverInputError
from .boxes import hits, points_inside, segments_cross

# Obstacle response candidates (see _avoid for which one is taken).
# The paper's circle (sphere(anchor, D) ∩ sphere(pos_i, dis)): every point is at distance dis from pos_i, so
# "nearest the unconstrained position" does not single one out. We take the point nearest the joint's
# position at the start of the iteration (continuity: the joint does not flip around the box between
# iterations or frames), then the rest of the circle by increasing angle from that point.
_CIRCLE_SAMPLES = 24
_CIRCLE_ANGLES = outward_angles(_CIRCLE_SAMPLES)
# Beyond the paper: when the circle does not exist (the box is larger than twice the segment: dis > 2D) or
# none of its points is clear (another box, or the segment still crosses), directions on the whole sphere
# of radius D around the anchor, by increasing angle from the unconstrained direction (the smallest change
# to what FABRIK asked for), azimuths ordered from the reference side.
_SPHERE_POLAR = np.radians([5, 10, 15, 20, 30, 40, 50, 60, 75, 90, 105, 120, 135, 150, 165, 180])
# Their cosines and sines, computed once: the coefficients of the ring axes e1, e2 (circle) and of the axis,
# e1, e2 (sphere: every polar angle with every azimuth, polar-major), and each candidate's place in the
# preference order as a fraction below 1.
_CIRCLE_COS, _CIRCLE_SIN = np.cos(_CIRCLE_ANGLES), np.sin(_CIRCLE_ANGLES)
_POLAR = np.repeat(_SPHERE_POLAR, _CIRCLE_SAMPLES)
_AZIMUTH = np.tile(_CIRCLE_ANGLES, _SPHERE_POLAR.size)
_SPHERE_AXIS, _SPHERE_E1, _SPHERE_E2 = (
    np.cos(_POLAR), np.sin(_POLAR) * np.cos(_AZIMUTH), np.sin(_POLAR) * np.sin(_AZIMUTH))
_CANDIDATES = _CIRCLE_SAMPLES * (1 + _SPHERE_POLAR.size)
_ORDER = np.arange(_CANDIDATES) / _CANDIDATES
# Up to this many axis-aligned boxes, a few problems' joints are tested on their floats, box by box (beyond a few,
# numpy's one test of all of them costs less).
_FEW_BOXES = 16


class ObstacleResponse:
    """The obstacles of a chain batch during one solve (owned by chain.model.ChainModel): the boxes (Boxes, some),
    their corners, and the boxes each problem ignores (those containing its target for the end joint and last
    segment, those containing its base for segment 0: unavoidable, reported in the reason), of B chains of n joints
    toward `targets` (B,3) from `base` (B,3); `margin` the clearance of the paper's circle."""

    def __init__(self, boxes, targets, base, n, margin):
        B = targets.shape[0]
        if boxes.batched and boxes.mins.shape[0] != B:
            raise SolverInputError(f"per-problem boxes have batch size {boxes.mins.shape[0]}, expected {B}")
        self.boxes = boxes
        self.n = n
        self.margin = margin
        self.ignore_end = points_inside(targets, boxes)  # (B,K)
        self.ignore_base = points_inside(base, boxes)
        self.corners = boxes.corners()
        self._floats = {}
        # Whether a few problems' tests may run on their floats (maths/lanes.py decides how few).
        self.floats = boxes.axes is None and len(boxes) <= _FEW_BOXES

    def _lists(self, r):
        """Problem r's box mins and maxs as lists of 3-lists (one problem's tests, on its floats)."""
        if r not in self._floats:
            mins, maxs = self.boxes.mins, self.boxes.maxs
            self._floats[r] = (mins[r], maxs[r]) if self.boxes.batched else (mins, maxs)
            self._floats[r] = tuple(x.tolist() for x in self._floats[r])
        return self._floats[r]

    def ignored(self, rows, joint, segment):
        """(b,K) boxes ignored for `joint` and (b,K) for `segment` (None: nothing ignored); one problem's (rows an
        int): (K,)."""
        last = self.n - 1
        ign_joint = self.ignore_end[rows] if joint == last else None
        ign_seg = None
        if segment == last - 1:
            ign_seg = self.ignore_end[rows]
        if segment == 0:
            ign_seg = self.ignore_base[rows] if ign_seg is None else (ign_seg | self.ignore_base[rows])
        return ign_joint, ign_seg

    def violations(self, boxes, anchor, points, ign_joint, ign_seg):
        inside = points_inside(points, boxes)
        crossing = segments_cross(anchor, points, boxes)
        if ign_joint is not None:
            inside &= ~ign_joint
        if ign_seg is not None:
            crossing &= ~ign_seg
        return inside, crossing

    def avoid(self, rows, anchor, cand, lengths, ref, joint, segment, limit_fn):
        """Paper §4.1.2 collision response for joints placed at `cand` (b,3) from `anchor` (b,3) at distance
        `lengths` (b,): if a joint is inside a box or its segment crosses one, move it as described at
        _CIRCLE_ANGLES / _SPHERE_POLAR. Returns (positions, responded (b,), failed (b,))."""
        b = cand.shape[0]
        if self.floats and lanes.few(b) and not any(self.penetrates(r, a, p, joint, segment) for r, a, p
                                                    in zip(rows.tolist(), anchor.tolist(), cand.tolist())):
            return cand, np.zeros(b, dtype=bool), np.zeros(b, dtype=bool)  # the common case: every joint clear
        boxes = self.boxes.select(rows)
        ign_joint, ign_seg = self.ignored(rows, joint, segment)
        inside, crossing = self.violations(boxes, anchor, cand, ign_joint, ign_seg)
        hit = inside.any(axis=1) | crossing.any(axis=1)
        if not any_set(hit):
            return cand, hit, np.zeros(b, dtype=bool)
        h = np.nonzero(hit)[0]
        a, p, L, r = anchor[h], cand[h], lengths[h], ref[h]
        # The colliding box: one containing the joint, else the first one the segment crosses.
        k = np.where(inside[h].any(axis=1), np.argmax(inside[h], axis=1), np.argmax(crossing[h], axis=1))
        corners = self.corners[rows[h], k] if self.boxes.batched else self.corners[k]  # (h,8,3)
        dis = norm(corners - p[:, None, :]).max(axis=1) + self.margin
        # Circle of sphere(a, L) ∩ sphere(p, dis); |p - a| = L up to rounding.
        axis_vec = p - a
        dd = norm(axis_vec)
        nvec = axis_vec / dd[:, None]
        along = (dd * dd + L * L - dis * dis) / (2.0 * dd)
        rho2 = L * L - along * along
        has_circle = rho2 > 0.0
        rho = np.sqrt(np.maximum(rho2, 0.0))
        center = a + along[:, None] * nvec
        # In-plane basis: e1 toward the reference (the joint's position at the start of the iteration).
        w = r - center
        w = w - dot(w, nvec)[:, None] * nvec
        wn = norm(w)
        ok = wn > 1e-12 * L
        e1 = unit_or_perpendicular(w, wn, ok, nvec)
        e2 = cross(nvec, e1)
        ring = _CIRCLE_COS[None, :, None] * e1[:, None, :] + _CIRCLE_SIN[None, :, None] * e2[:, None, :]  # (h,24,3)
        circle_pts = center[:, None, :] + rho[:, None, None] * ring
        circle_dirs = (circle_pts - a[:, None, :]) / L[:, None, None]
        sub = boxes.select(h)
        ij = None if ign_joint is None else ign_joint[h][:, None, :]
        iseg = None if ign_seg is None else ign_seg[h][:, None, :]
        if all_set(inside[h].any(axis=1) & has_circle):
            # A joint inside a box takes the first clear point of the paper's circle when the circle has one: every
            # circle point comes before every sphere sample in the preference order (below), so those need no test.
            pts, score = self._scored(h, a, L, circle_dirs, sub, ij, iseg, limit_fn)
            clear = score == 0
            if all_set(clear.any(axis=1)):
                out = cand.copy()
                out[h] = pts[np.arange(h.size), np.argmax(clear, axis=1)]
                return out, hit, np.zeros(b, dtype=bool)
        sphere_dirs = (_SPHERE_AXIS[None, :, None] * nvec[:, None, :]
                       + _SPHERE_E1[None, :, None] * e1[:, None, :]
                       + _SPHERE_E2[None, :, None] * e2[:, None, :])
        pts, score = self._scored(h, a, L, np.concatenate([circle_dirs, sphere_dirs], axis=1), sub, ij, iseg,
                                  limit_fn)
        # Least penetration = fewest boxes entered or crossed; a missing circle is never a candidate.
        score[:, :_CIRCLE_SAMPLES] = np.where(has_circle[:, None], score[:, :_CIRCLE_SAMPLES], np.iinfo(np.int64).max)
        # Which candidate: first the fewest boxes entered or crossed ("least penetration"), then
        # - a joint inside a box (the paper's case): preference order, i.e. the paper's circle from its point
        #   nearest the reference, then the sphere samples;
        # - only the segment crossing a box (beyond the paper): the candidate nearest the unconstrained
        #   position, circle and sphere alike: every circle point is `dis` away, a needlessly large jump for
        #   a segment that only grazes a box, and the smallest correction keeps FABRIK converging.
        never = score == np.iinfo(np.int64).max
        order = np.broadcast_to(_ORDER, score.shape)
        deviation = norm(pts - p[:, None, :]) / (2.0 * L[:, None])  # < 1: never outweighs a penetration
        tiebreak = np.where(inside[h].any(axis=1)[:, None], order, deviation)
        key = np.where(never, np.inf, score + 0.5 * tiebreak)
        pick = np.argmin(key, axis=1)
        out = cand.copy()
        out[h] = pts[np.arange(h.size), pick]
        failed = np.zeros(b, dtype=bool)
        failed[h] = score[np.arange(h.size), pick] > 0
        return out, hit, failed

    def _scored(self, h, anchors, lengths, dirs, boxes, ign_joint, ign_seg, limit_fn):
        """Candidate points at `lengths` (h,) from `anchors` (h,3) along `dirs` (h,c,3) (normalised, then
        limited) and how many boxes each enters or its segment crosses: (points (h,c,3), score (h,c))."""
        dirs = dirs / norm(dirs)[..., None]
        if limit_fn is not None:
            dirs = limit_fn(h, dirs)
        pts = anchors[:, None, :] + lengths[:, None, None] * dirs
        c_in, c_cross = self.violations(boxes, anchors[:, None, :], pts, ign_joint, ign_seg)
        return pts, c_in.sum(axis=-1) + c_cross.sum(axis=-1)

    def penetrates(self, r, anchor, point, joint, segment):
        """Whether problem r's `joint` at `point` (floats) lies in, or its `segment` from `anchor` meets, a box it does
        not ignore: the question avoid answers first, for one problem on its floats."""
        inside, crossing = self._hits(r, anchor, point, joint, segment)
        return inside or crossing

    def _hits(self, r, anchor, point, joint, segment):
        ign_joint, ign_seg = self.ignored(r, joint, segment)
        return hits(*self._lists(r), anchor, point, None if ign_joint is None else ign_joint.tolist(),
                    None if ign_seg is None else ign_seg.tolist())

    def penetration_counts(self, P, rows):
        """(joints inside, segments crossing) per problem (b,) of P (b,n,3) = problems `rows`, ignoring what each
        problem must ignore; of one problem (rows an int, P its list of joints): two ints, its joints and segments
        tested on their floats box by box."""
        if rows.__class__ is int:
            counts = [self._hits(rows, P[i], P[i + 1], i + 1, i) for i in range(self.n - 1)]
            return sum(c[0] for c in counts), sum(c[1] for c in counts)
        if self.floats and lanes.few(len(rows)):
            counts = [self.penetration_counts(joints, r) for r, joints in zip(rows.tolist(), P.tolist())]
            return np.array(counts, dtype=np.int64).reshape(-1, 2).T
        boxes = self.boxes.select(rows)
        inside = points_inside(P[:, 1:], boxes)  # (b,n-1,K): joint 0 is fixed, reported separately
        inside[:, -1] &= ~self.ignore_end[rows]
        crossing = segments_cross(P[:, :-1], P[:, 1:], boxes)  # (b,n-1,K)
        crossing[:, -1] &= ~self.ignore_end[rows]
        crossing[:, 0] &= ~self.ignore_base[rows]
        return inside.any(axis=-1).sum(axis=-1), crossing.any(axis=-1).sum(axis=-1)
