"""A chain batch's joint limits during one solve (ChainLimits, owned by chain.model.ChainModel): each problem's hinge
axes and the parent directions they are given at, and the limit steps of FABRIK's passes, of the limit check and
of the two-segment finish's candidates. Every step is limits.joint_limits' one kernel: for one problem (``rows`` an
int) on its Python floats, for many (``rows`` an index array) on their arrays, a few rows at a time again on floats
(maths/lanes.py decides how few)."""

import numpy as np

from ..errors import SolverInputError
from ..limits.joint_limits import CONE, FREE, HINGE, carry, cone, hinge, limit
from ..maths import lanes
from ..maths import vectors as vec
from ..maths.geometry import norm


def _per_problem(a, b, m):
    """Per-joint vectors a (m,3) or (b,m,3) as (b,m,3); as they are when they are so already (a solver's own
    limits carry per-problem arrays), without numpy's broadcast_to cost on every chain solve."""
    return a if a.shape == (b, m, 3) else np.broadcast_to(a, (b, m, 3))


class ChainLimits:
    """The limits (JointLimits, some joint not FREE) of B chains of m+1 joints starting along start_dirs (B,m,3),
    joint 0's parent directions parent_dirs (B,3) or None."""

    def __init__(self, limits, start_dirs, parent_dirs):
        B, m = start_dirs.shape[0], start_dirs.shape[1]
        self.limits = limits
        self.kind = limits.kind.tolist()
        self.parent_dirs = parent_dirs
        axes = limits.hinge_axis
        if axes.ndim == 3 and axes.shape[0] != B:
            raise SolverInputError(f"per-problem hinge axes have batch size {axes.shape[0]}, expected {B}")
        self.hinge_axes = _per_problem(axes, B, m)
        # Where each hinge axis is given: its parent direction at the start pose, or the caller's.
        ref = limits.hinge_reference
        if ref is None:
            self.hinge_refs = np.concatenate([start_dirs[:, :1], start_dirs[:, :-1]], axis=1)
        else:
            if ref.ndim == 3 and ref.shape[0] != B:
                raise SolverInputError(f"per-problem hinge references have batch size {ref.shape[0]}, expected {B}")
            ref = _per_problem(ref, B, m)
            self.hinge_refs = ref / np.maximum(norm(ref), 1e-300)[..., None]
        self._floats = None

    def _axis(self, r, i):
        """Problem r's hinge axis of joint i and the parent direction it is given at, as lists of floats."""
        if self._floats is None:
            self._floats = (self.hinge_axes.tolist(), self.hinge_refs.tolist())
        return self._floats[0][r][i], self._floats[1][r][i]

    def step(self, i, rows, parent, dirs, fallback, reverse=False):
        """Joint i's limit on the unit directions `dirs` of segment i: (directions, binding). One problem (rows an
        int): 3-vectors of floats; many: arrays (b,3), or (b,c,3) with parent and fallback (b,3). `reverse`: the
        forward pass's counterpart (FABRIK 2011 limits both passes): dirs the proposed parent directions of
        segment i-1, `parent` segment i's placed direction; a cone is symmetric, a hinge's range mirrored about
        the axis carried by the proposed direction. It only steers what the backward pass starts from: that
        pass enforces the limits exactly."""
        axis = None
        if rows.__class__ is int:
            if self.kind[i] == HINGE:
                axis, ref = self._axis(rows, i)
                if reverse or i > 0:  # carried by the proposed parent direction, or by the parent
                    axis = carry(axis, ref, dirs if reverse else parent)
            return limit(self.limits, i, parent, dirs, fallback, axis, reverse)
        if dirs.ndim == 2 and lanes.few(len(rows)):
            out = [self.step(i, r, p, v, fb, reverse) for r, p, v, fb
                   in zip(rows.tolist(), parent.tolist(), dirs.tolist(), fallback.tolist())]
            return (np.array([o[0] for o in out], dtype=np.float64).reshape(dirs.shape),
                    np.array([o[1] for o in out], dtype=bool))
        expand = (lambda v: v[:, None] if dirs.ndim == 3 else v)
        if self.kind[i] == HINGE:
            axis = self.hinge_axes[rows, i]
            if reverse or i > 0:
                axis = carry(axis, self.hinge_refs[rows, i], dirs if reverse else parent)
            axis = expand(axis)
        u, binding = limit(self.limits, i, expand(parent), dirs, expand(fallback), axis, reverse)
        return np.broadcast_to(u, dirs.shape), np.broadcast_to(binding, dirs.shape[:-1])

    def broken(self, rows, chain, lengths):
        """Whether a pose breaks a limit (beyond rounding): one problem's chain (a list of joints, lengths a list)
        or many problems' (b,n,3) (lengths (b,n-1)), segment directions measured as the passes measure them."""
        if rows.__class__ is int:
            dirs = [vec.divided(vec.sub(b, a), length) for a, b, length in zip(chain, chain[1:], lengths)]
            dirs = [vec.divided(d, vec.norm(d)) for d in dirs]
            parent = None if self.parent_dirs is None else self.parent_dirs[rows].tolist()
        else:
            dirs = (chain[:, 1:] - chain[:, :-1]) / lengths[..., None]
            dirs = dirs / norm(dirs)[..., None]
            dirs = [dirs[:, i] for i in range(dirs.shape[1])]
            parent = None if self.parent_dirs is None else self.parent_dirs[rows]
        bad = False
        for i, kind in enumerate(self.kind):
            if kind != FREE:
                bad = bad | self.step(i, rows, parent if i == 0 else dirs[i - 1], dirs[i], dirs[i])[1]
                if rows.__class__ is int and bad:
                    return True
        return bad

    def finish_holds(self, rows, pose, u, first, v):
        """Whether two-segment finish candidates keep the limits of the pivot joint j = n-3 (toward the unit u,
        the first candidate's `first` its fallback) and of the middle joint (toward the target along the unit v).
        One problem: pose its chain (a list of joints), u, first, v 3-vectors, a bool; many: pose (h,n,3), u and
        v (h,K,3), first (h,3), (h,K) bools."""
        j, k = len(self.kind) - 2, len(self.kind) - 1
        one = rows.__class__ is int
        ok = True if one else np.ones(u.shape[:2], dtype=bool)
        if self.kind[j] != FREE:
            if j == 0:
                parent = self.parent_dirs[rows].tolist() if one else self.parent_dirs[rows]
            else:
                parent = vec.sub(pose[j], pose[j - 1]) if one else pose[:, j] - pose[:, j - 1]
                parent = vec.divided(parent, vec.norm(parent))
            ok = lanes.not_(self.step(j, rows, parent, u, first)[1])
            if not lanes.any_(ok):
                return ok
        if self.kind[k] == CONE:
            ok = ok & lanes.not_(cone(u, v, float(self.limits.cone_angle[k]), v)[1])
        elif self.kind[k] == HINGE:
            if one:
                axis, ref = self._axis(rows, k)
            else:
                axis, ref = self.hinge_axes[rows, k][:, None], self.hinge_refs[rows, k][:, None]
            lo, hi, twist = (float(x[k]) for x in (self.limits.hinge_min, self.limits.hinge_max, self.limits.hinge_twist))
            ok = ok & lanes.not_(hinge(u, v, carry(axis, ref, u), lo, hi, v, twist)[1])
        return ok
