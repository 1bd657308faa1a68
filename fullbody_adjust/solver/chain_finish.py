"""Two-segment finish of the batch chain solver's backward pass (beyond FABRIK; see chain.py): the last two
segments are placed analytically where a swivel position of the middle joint meets the target with every limit
and obstacle satisfied (TwoBoneFinish._two_bone_finish, mixed into ChainModel)."""

import math

import numpy as np

from .geometry import any_set, cross, dot, norm, outward_angles, unit_or_perpendicular
from .limits import CONE, FREE, HINGE, apply_cone, apply_hinge, carry_axis

# Two-segment finish (ChainModel._two_bone_finish): swivel angles of the middle joint around the pivot ->
# target line, from FABRIK's proposal outward (0, +d, -d, +2d, ...), and the least hinge twist range that
# leaves an interval of them to pick from (a twist-free hinge fits one swivel angle, never a sample).
_SWIVEL_ANGLES = outward_angles(48)
_SWIVEL_COS, _SWIVEL_SIN = np.cos(_SWIVEL_ANGLES), np.sin(_SWIVEL_ANGLES)
_MIN_FINISH_TWIST = math.radians(5)


class TwoBoneFinish:
    """ChainModel's two-segment finish; it uses the model's lengths, targets, limits, hinge axes and references,
    parent directions and obstacle checks."""

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
        j = self.n - 3
        b = len(rows)
        finished = np.zeros(b, dtype=bool)
        middle = np.zeros((b, 3))
        end = np.zeros((b, 3))
        lengths = self.lengths[rows]
        a, c = lengths[:, j], lengths[:, j + 1]
        S = P[:, j]
        to_t = self.targets[rows] - S
        d = norm(to_t)
        h = np.nonzero((d > np.abs(a - c) * (1.0 + 1e-9)) & (d < (a + c) * (1.0 - 1e-9)))[0]
        if h.size == 0:
            return finished, middle, end
        a, c, d, S, T = a[h], c[h], d[h], S[h], self.targets[rows[h]]
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
        if self.boxes is not None:
            boxes = self.boxes.select(rows[h])
            for seg, (p0, p1) in ((j, (S[:, None], E)), (k, (E, wrist))):
                if not any_set(ok):
                    break
                ign_joint, ign_seg = self._ignored(rows[h], seg + 1, seg)
                inside, crossing = self._violations(
                    boxes, np.broadcast_to(p0, p1.shape), p1,
                    None if ign_joint is None else ign_joint[:, None], None if ign_seg is None else ign_seg[:, None])
                ok &= ~(inside.any(axis=-1) | crossing.any(axis=-1))
        if any_set(ok):
            ok &= self._limits_hold(rows[h], P[h], E, S, a, v)
        pick = np.argmax(ok, axis=1)
        found = ok[np.arange(h.size), pick]
        finished[h] = found
        middle[h] = E[np.arange(h.size), pick]
        end[h] = wrist[np.arange(h.size), pick]
        return finished, middle, end

    def _limits_hold(self, rows, P, E, S, a, v):
        """(h,K) bool: the pivot joint n-3 (toward the middle joints E from the pivot S, segment length a) and the
        middle joint n-2 (toward the target along the unit v) keep their limits, for the finish candidates of
        problems `rows` (P their poses)."""
        j, k = self.n - 3, self.n - 2
        u = (E - S[:, None]) / a[:, None, None]
        u = u / norm(u)[..., None]
        ok = np.ones(E.shape[:2], dtype=bool)
        if self.limits.kind[j] != FREE:
            if j == 0:
                parent = self.parent_dirs[rows]
            else:
                parent = P[:, j] - P[:, j - 1]
                parent = parent / norm(parent)[:, None]
            ok &= ~self._limit(j, rows, parent, u, u[:, 0])[1]
        if any_set(ok) and self.limits.kind[k] == CONE:
            ok &= ~apply_cone(u, v, self.limits.cone_angle[k], v)[1]
        elif any_set(ok) and self.limits.kind[k] == HINGE:
            axis = carry_axis(self.hinge_axes[rows, k][:, None], self.hinge_refs[rows, k][:, None], u)
            ok &= ~apply_hinge(u, v, axis, self.limits.hinge_min[k], self.limits.hinge_max[k], v,
                               self.limits.hinge_twist[k])[1]
        return ok

    # -- solve -------------------------------------------------------------------------------------------------
