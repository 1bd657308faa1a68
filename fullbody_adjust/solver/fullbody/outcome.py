"""What a solve reports: each effector's residual, status and reason, and the AdjustBatchResult they are part of
(the bones, their rotations, which groups moved, how far the sub-bases went)."""

from __future__ import annotations

import numpy as np

from ..body.model import LIMB_OF_EFFECTOR
from ..maths import vectors as vec
from ..maths.geometry import norm
from ..vocabulary import GROUPS
from .prepared import group_bones
from .settings import UNCONSTRAINED, AdjustBatchResult


def batch_result(model, start_heads, start_tails, effectors, iterations, heads, tails, rotations, outcome):
    """The AdjustBatchResult of F frames solved from ``start_heads``/``start_tails`` (F,J,3) to ``heads``/``tails``
    with ``rotations``; ``outcome``: effector_outcome's (residuals, status, reasons)."""
    residuals, status, reasons = outcome
    F = heads.shape[0]
    moved = np.zeros((F, len(GROUPS)), dtype=bool)
    bone_moved = ((heads != start_heads) | (tails != start_tails)).any(axis=2)  # (F,J)
    columns, bones, starts = group_bones(model)
    if columns.size:
        moved[:, columns] = np.logical_or.reduceat(bone_moved[:, bones], starts, axis=1)
    chest = model.groups["trunk"][-1]
    sc_disp = norm(tails[:, chest] - start_tails[:, chest])
    root_disp = norm(heads[:, model.root] - start_heads[:, model.root])
    return AdjustBatchResult(heads, tails, rotations, effectors, residuals, status, reasons, moved, GROUPS,
                             iterations, sc_disp, root_disp)


def effector_outcome(model, effectors, targets, active, tol, heads, tails, solves):
    """(residuals, status, reasons) (F,E) of the effectors: each limb's end against its target (F,E,3) where
    ``active`` (F,E), within ``tol``, and why; ``solves``: {limb name: LimbSolve}."""
    outcome = _outcome_one_frame if active.shape[0] == 1 else _outcome_frames
    return outcome(model, effectors, targets, active, tol, heads, tails, solves)


def _outcome_one_frame(model, effectors, targets, active, tol, heads, tails, solves):
    """effector_outcome of one frame, effector by effector in plain floats and strings (the same distances;
    numpy's per-call cost on five values was most of it)."""
    trunk = solves["trunk"]
    trunk_stuck = bool(trunk.solved[0]) and trunk.status[0] in ("blocked", "limited")
    residuals, status, reasons = [], [], []
    for k, e in enumerate(effectors):
        name = LIMB_OF_EFFECTOR[e]
        if not active[0, k]:
            residuals.append(np.nan)
            status.append(UNCONSTRAINED)
            reasons.append("no target on this frame")
            continue
        limb = model.limbs[name]
        res = vec.norm(vec.sub(limb.end_point(heads[0], tails[0]).tolist(), targets[0, k].tolist()))
        st, why = solves[name].status[0], solves[name].reason[0]
        if res <= tol:
            st, why = "reached", why or "reached"
        else:
            if st == "reached":  # met by its chain, then moved (cannot happen with rigid propagation)
                st, why = "unreachable", "moved off its target after the chain solve"
            if st == "unreachable" and limb.hub == "sc" and trunk_stuck:
                st, why = trunk.status[0], f"the trunk could not bring the SC into reach: {trunk.reason[0]}"
        residuals.append(res)
        status.append(st)
        reasons.append(why)
    return np.array([residuals]), np.array([status], dtype=str), np.array([reasons], dtype=str)


def _outcome_frames(model, effectors, targets, act, tol, heads, tails, solves):
    """effector_outcome of F frames, every effector at once (F,E)."""
    names = [LIMB_OF_EFFECTOR[e] for e in effectors]
    pos = np.stack([model.limbs[name].end_point(heads, tails) for name in names], axis=1) if names else \
        np.zeros((act.shape[0], 0, 3))
    res = norm(pos - np.where(act[..., None], targets, 0.0))
    residuals = np.where(act, res, np.nan)
    met = act & (res <= tol)
    st = np.stack([solves[name].status for name in names], axis=1).astype(object)
    why = np.stack([solves[name].reason for name in names], axis=1).astype(object)
    # Met by its chain, then moved (cannot happen with rigid propagation).
    moved_off = act & ~met & (st == "reached")
    st[moved_off] = "unreachable"
    why[moved_off] = "moved off its target after the chain solve"
    trunk = solves["trunk"]
    t_st = np.asarray(trunk.status)
    trunk_stuck = np.asarray(trunk.solved) & ((t_st == "blocked") | (t_st == "limited"))
    on_sc = np.array([model.limbs[name].hub == "sc" for name in names])
    by_trunk = act & ~met & (st == "unreachable") & on_sc & trunk_stuck[:, None]
    for f, k in zip(*np.nonzero(by_trunk)):
        st[f, k], why[f, k] = trunk.status[f], f"the trunk could not bring the SC into reach: {trunk.reason[f]}"
    st[met] = "reached"
    why[met & (why == "")] = "reached"
    status = np.where(act, st, UNCONSTRAINED)
    reasons = np.where(act, why, "no target on this frame")
    return residuals, status.astype(str), reasons.astype(str)
