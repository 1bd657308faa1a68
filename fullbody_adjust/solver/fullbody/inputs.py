"""adjust_frames' input checked: heads, tails, targets, effectors, priorities and obstacles of F frames, a caller's
joint limits, and the end goals (end bones' turns and poles). Every bad input is one SolverInputError line."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..body.model import LIMB_OF_EFFECTOR
from ..errors import SolverInputError
from ..limits.human import LimbLimits
from ..limits.joint_limits import FREE
from ..maths.geometry import all_set, any_set
from ..obstacles.boxes import Boxes


class Inputs(NamedTuple):
    """The checked input of one solve: F frames of J bones and E effectors."""

    heads: np.ndarray  # (F,J,3)
    tails: np.ndarray  # (F,J,3)
    effectors: tuple  # (E,) names
    targets: np.ndarray  # (F,E,3), a NaN row: no target
    active: np.ndarray  # (F,E) bool: a target on that frame
    priorities: np.ndarray  # (E,)
    obstacles: Boxes | None  # None when there are none


def checked_inputs(model, heads, tails, targets, effectors, priorities, obstacles) -> Inputs:
    """The input of adjust_frames for ``model`` as arrays, or SolverInputError (one line) for the first that does
    not fit."""
    j = len(model.names)
    H0 = frames_array(heads, "heads", (j, 3))
    T0 = frames_array(tails, "tails", (j, 3))
    F = H0.shape[0]
    if T0.shape[0] != F:
        raise SolverInputError(f"heads have {F} frames but tails {T0.shape[0]}")
    if isinstance(effectors, str):
        raise SolverInputError("effectors must be a sequence of effector names")
    effectors = tuple(effectors)
    for e in effectors:
        if e not in LIMB_OF_EFFECTOR:
            raise SolverInputError(f"unknown effector {e!r} (use hand.L hand.R foot.L foot.R head)")
        if e not in model.effectors:
            raise SolverInputError(f"effector {e!r} needs a head group with neck bones and a head bone")
    if len(set(effectors)) != len(effectors):
        raise SolverInputError("an effector is listed twice")
    E = len(effectors)
    t = np.asarray(targets, dtype=np.float64)
    if t.shape != (F, E, 3):
        raise SolverInputError(f"targets must have shape ({F},{E},3), got {t.shape}")
    nan_rows = np.isnan(t).all(axis=2)
    if any_set(~np.isfinite(t) & ~nan_rows[..., None]):
        raise SolverInputError("target has NaN/inf (a target row must be all finite, or all NaN for none)")
    if priorities is None:
        pr = np.ones(E)
    else:
        pr = np.asarray(priorities, dtype=np.float64)
        if pr.shape != (E,):
            raise SolverInputError(f"priorities must have shape ({E},), got {pr.shape}")
        if not all_set(np.isfinite(pr)) or any_set(pr < 0):
            raise SolverInputError("priorities must be finite numbers >= 0")
    if obstacles is not None:
        if not isinstance(obstacles, Boxes):
            raise SolverInputError("obstacles must be Boxes")
        if obstacles.batched and obstacles.mins.shape[0] != F:
            raise SolverInputError(f"per-frame boxes have {obstacles.mins.shape[0]} frames, expected {F}")
        if len(obstacles) == 0:
            obstacles = None
    return Inputs(H0, T0, effectors, t, ~nan_rows, pr, obstacles)


def end_goals(effectors, F, end_turns, poles):
    """Per limb: the end bone's wanted world rotation deltas (F,3,3) and the pole points (F,3), NaN rows where none
    (see adjust_frames), as two dicts {limb name: array}; limbs without any are left out."""
    turns, limb_pole = {}, {}
    E = len(effectors)
    for label, given, shape, store in (("end_turns", end_turns, (F, E, 3, 3), turns),
                                       ("poles", poles, (F, E, 3), limb_pole)):
        if given is None:
            continue
        given = np.asarray(given, dtype=np.float64)
        if given.shape != shape:
            raise SolverInputError(f"{label} must have shape {shape}, got {given.shape}")
        for k, e in enumerate(effectors):
            rows = given[:, k].reshape(F, -1)
            unset = np.isnan(rows).all(axis=1)
            if any_set(~np.isfinite(rows) & ~unset[:, None]):
                raise SolverInputError(f"{label} for {e} have NaN/inf (all NaN for none)")
            if e != "head" and not all_set(unset):
                store[LIMB_OF_EFFECTOR[e]] = given[:, k]
    return turns, limb_pole


def check_limits(model, limits, F):
    """A caller's limits {limb name: LimbLimits} for F frames of ``model``: SolverInputError (one line) if they
    do not fit."""
    if not isinstance(limits, dict) or any(not isinstance(v, LimbLimits) for v in limits.values()):
        raise SolverInputError("limits must be a dict of limb name -> LimbLimits")
    for name, ll in limits.items():
        if name not in model.limbs:
            raise SolverInputError(f"limits given for unknown limb {name!r}")
        m = model.limbs[name].n_joints - 1
        if len(ll.limits) != m:
            raise SolverInputError(f"limits for {name!r} cover {len(ll.limits)} joints, the chain has {m}")
        if ll.limits.hinge_axis.ndim == 3 and ll.limits.hinge_axis.shape[0] != F:
            raise SolverInputError(f"limits for {name!r}: per-frame hinge axes need {F} frames")
        pd = ll.parent_direction
        if pd is not None and (np.shape(pd) != (F, 3) or not all_set(np.isfinite(pd))):
            raise SolverInputError(f"limits for {name!r}: parent_direction must be finite, shape ({F},3)")
        if pd is None and ll.limits.kind[0] != FREE:
            raise SolverInputError(f"limits for {name!r}: joint 0 is limited but has no parent_direction")


def frames_array(a, label, shape):
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != shape:
        raise SolverInputError(f"{label} must have shape (F,{shape[0]},{shape[1]}), got {arr.shape}")
    if arr.shape[0] == 0:
        raise SolverInputError(f"{label} have no frames")
    if not all_set(np.isfinite(arr)):
        raise SolverInputError(f"{label} have NaN/inf")
    return arr
