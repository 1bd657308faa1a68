"""What a solve reports: each effector's residual, status and reason, and the AdjustBatchResult they are part of
(the bones, their rotations, how far the sub-bases went)."""

from __future__ import annotations

import numpy as np

from ..body.model import LIMB_OF_EFFECTOR
from ..maths import lanes
from ..maths import vectors as vec
from ..maths.geometry import norm
from .settings import UNCONSTRAINED, AdjustBatchResult


def batch_result(model, start_heads, start_tails, effectors, iterations, heads, tails, rotations, outcome):
    """The AdjustBatchResult of F frames solved from ``start_heads``/``start_tails`` (F,J,3) to ``heads``/``tails``
    with ``rotations``; ``outcome``: effector_outcome's (residuals, status, reasons)."""
    residuals, status, reasons = outcome
    chest = model.groups["trunk"][-1]
    sc_disp = norm(tails[:, chest] - start_tails[:, chest])
    root_disp = norm(heads[:, model.root] - start_heads[:, model.root])
    return AdjustBatchResult(heads, tails, rotations, effectors, residuals, status, reasons, iterations, sc_disp, root_disp)


def effector_outcome(model, effectors, targets, active, tol, heads, tails, solves):
    """(residuals, status, reasons) (F,E) of the effectors: each limb's end against its target (F,E,3) where
    ``active`` (F,E), within ``tol``, and why; ``solves``: {limb name: LimbSolve}. _effector on every frame and
    effector: a few frames one (frame, effector) at a time on Python floats and strings, more at once on (F,E)
    arrays (maths/lanes.py decides)."""
    names = [LIMB_OF_EFFECTOR[e] for e in effectors]
    F, E = active.shape
    ends = [model.limbs[name].end_point(heads, tails) for name in names]
    limbs = [solves[name] for name in names]
    on_sc = [model.limbs[name].hub == "sc" for name in names]
    trunk = solves["trunk"]
    if E and lanes.few(F):
        out = []
        for f in range(F):
            trunk_f = (bool(trunk.solved[f]), trunk.status[f], trunk.reason[f])
            out.append([_effector(ends[k][f].tolist(), goal, on, limb.status[f], limb.reason[f],
                                  on_sc[k], *trunk_f, tol)
                        for k, (goal, on, limb) in enumerate(zip(targets[f].tolist(), active[f].tolist(), limbs))])
        return tuple(np.array([[o[i] for o in row] for row in out]) for i in range(3))
    if E == 0:
        return np.zeros((F, 0)), np.zeros((F, 0), dtype=str), np.zeros((F, 0), dtype=str)
    column = (lambda a: np.asarray(a, dtype=object)[:, None])  # noqa: E731  the trunk's (F,) against (F,E)
    residuals, status, reasons = _effector(
        np.stack(ends, axis=1), targets, active, np.stack([ls.status for ls in limbs], axis=1),
        np.stack([ls.reason for ls in limbs], axis=1), np.array(on_sc), trunk.solved[:, None],
        column(trunk.status), column(trunk.reason), tol)
    return residuals, np.asarray(status).astype(str), np.asarray(reasons).astype(str)


def _effector(end, target, active, status, reason, on_sc, trunk_solved, trunk_status, trunk_reason, tol):
    """(residual, status, reason) of an effector whose limb ends at ``end`` for its target (NaN residual,
    UNCONSTRAINED where not ``active``), from its chain solve's ``status`` and ``reason``; ``on_sc``: the limb
    hangs from the SC, whose trunk solve (where ``trunk_solved``) ended with ``trunk_status`` and ``trunk_reason``.
    On one effector's floats and strings, or on arrays of them (vectors (...,3)), as maths/lanes.py has it."""
    res = vec.norm(vec.sub(end, target))
    met = active & (res <= tol)
    missed = active & lanes.not_(met)
    if lanes.any_(missed):
        moved_off = missed & (status == "reached")  # met by its chain, then moved (not with rigid propagation)
        if lanes.any_(moved_off):
            status = lanes.where(moved_off, "unreachable", status)
            reason = lanes.where(moved_off, "moved off its target after the chain solve", reason)
        by_trunk = missed & (status == "unreachable") & on_sc & trunk_solved
        if lanes.any_(by_trunk):
            by_trunk = by_trunk & ((trunk_status == "blocked") | (trunk_status == "limited"))
        if lanes.any_(by_trunk):
            status = lanes.where(by_trunk, trunk_status, status)
            reason = lanes.where(by_trunk, "the trunk could not bring the SC into reach: " + trunk_reason, reason)
    status = lanes.where(met, "reached", status)
    reason = lanes.where(met & (reason == ""), "reached", reason)
    return (lanes.where(active, res, np.nan), lanes.where(active, status, UNCONSTRAINED),
            lanes.where(active, reason, "no target on this frame"))
