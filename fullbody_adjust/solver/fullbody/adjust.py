"""Full-body adjustment (paper §5, Algorithm 1) for one pose or many frames at once.

    1. new SC and root positions from the targets (§5.2.1-5.2.2), with the fewest moved joints:
       - a limb alone serves when its target is within its reach: the SC and root then stay bit-exact;
       - else the SC moves to the nearest point from which every constrained arm (and the head) can reach: the
         intersection of the balls of limb-reach radius around the targets (the paper's two-sphere equation
         (1)), preferring points the trunk reaches by leaning, then by bending; when the balls do not
         intersect, the priority variants of §4.2 decide;
       - the pelvis translates when the trunk cannot bring the SC there (and by the trunk's remaining error
         when its joint limits hold it), but only where every constrained foot can still reach its ankle
         target: ankle tasks outrank the others by default (variant 2 at the root);
    2. trunk: FABRIK from the (translated) root to the new SC, started from the spine curled onto it where it leans;
    3. arms (and head) from their bases riding on the new chest; 4. legs from the hips riding on the root.
Obstacles and joint limits apply to every chain solve (solve_chain_batch). Bones outside the solved chains keep
their local transforms (rigid children), so head and neck ride on the chest, fingers on the hands. A limb whose
target its start pose already meets, on a parent that did not move, is left exactly as it was.
Bone rotations: each chain bone turns by the minimal swing from its old direction to its new one,
except that an upper arm / thigh also turns about its length by the twist the solver gave its elbow's / knee's
bend plane, and the forearm / shin then turns relative to it about the hinge axis only (_segment_rotations).

Everything is vectorised over frames; a frame's result depends only on its own data (chain solves mask
converged problems and every other step is row-wise), so adjust_pose equals a row of adjust_frames.

Modules: fullbody/settings.py (settings, results), fullbody/inputs.py (the input checked), fullbody/reach_balls.py
(sub-base geometry), fullbody/sub_bases.py (step 1), fullbody/trunk_curl.py (the spine's curl: the lean's radius and
the trunk solve's start), fullbody/limb_placement.py (steps 2-4: the chain solves and the top-down pass that places
the bones), chain/two_bone_start.py (a hinged limb's warm start), fullbody/limb_rotations.py (bone rotations),
fullbody/outcome.py (each effector's residual, status and reason; the result), fullbody/prepared.py (the work that
depends only on the start pose, kept while it is the same: Live's updates share it).
"""

from __future__ import annotations

import numpy as np

from .settings import UNCONSTRAINED, VARIANTS, AdjustBatchResult, AdjustResult, AdjustSettings
from ..body.model import LIMB_OF_EFFECTOR, BodyModel
from ..limits.human import LimbLimits
from ..errors import SolverInputError
from ..maths.geometry import any_set, apply_matrix, norm
from .inputs import check_limits, checked_inputs, end_goals
from .limb_placement import LimbPlacement
from .limb_rotations import LimbSolve, chest_rotation
from .outcome import batch_result, effector_outcome
from ..obstacles.reach import body_reach, reachable_boxes
from .prepared import prepare
from .reach_balls import nearest_in_balls, project_onto_balls, sub_base_point
from .sub_bases import SubBasePlacement

__all__ = ["UNCONSTRAINED", "VARIANTS", "AdjustBatchResult", "AdjustResult", "AdjustSettings", "adjust_frames",
           "adjust_pose", "nearest_in_balls", "project_onto_balls", "sub_base_point"]


# ----------------------------------------------------------------------------------------------------------
# Entry points


def adjust_pose(model, heads, tails, targets, effectors, priorities=None, *, obstacles=None,
                settings=AdjustSettings(), limits=None, bone_x_axes=None, end_turns=None,
                poles=None) -> AdjustResult:
    """Adjust one pose: heads/tails (J,3), targets (E,3) (a NaN row = no target). = adjust_frames with F = 1."""
    heads = np.asarray(heads, dtype=np.float64)
    tails = np.asarray(tails, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    if heads.ndim != 2 or tails.ndim != 2 or targets.ndim != 2:
        raise SolverInputError("adjust_pose takes heads (J,3), tails (J,3) and targets (E,3); "
                               "use adjust_frames for many frames")
    if bone_x_axes is not None:
        bone_x_axes = np.asarray(bone_x_axes, dtype=np.float64)[None]
    per_frame = (lambda a: None if a is None else np.asarray(a, dtype=np.float64)[None])
    return adjust_frames(model, heads[None], tails[None], targets[None], effectors, priorities,
                         obstacles=obstacles, settings=settings, limits=limits, bone_x_axes=bone_x_axes,
                         end_turns=per_frame(end_turns), poles=per_frame(poles))[0]


def adjust_frames(model, heads, tails, targets, effectors, priorities=None, *, obstacles=None,
                  settings=AdjustSettings(), limits=None, bone_x_axes=None, end_turns=None,
                  poles=None) -> AdjustBatchResult:
    """Adjust F frames at once.

    heads, tails (F,J,3): world bone heads/tails at the start poses; targets (F,E,3) for the effector names
    `effectors` (E,) (from hand.L hand.R foot.L foot.R head), a NaN row meaning no target on that frame;
    priorities (E,) >= 0, higher wins (default all 1); obstacles: Boxes shared (K,3) or per frame (F,K,3);
    limits: {limb name: human.LimbLimits} to replace the defaults (a limb missing from the dict is free);
    bone_x_axes: optional per-bone world axes (J,3)/(F,J,3) for the default hinge axes of straight elbows and
    knees (the forearms' and shins' rows: human.default_limits);
    end_turns (F,E,3,3): world rotation deltas wanted for the hand and foot bones (e.g. to a target's
    orientation), turned no further from where the forearm/shin carries them than END_SWING allows; a NaN
    entry (or None) keeps the bone's world orientation;
    poles (F,E,3): for hands and feet, a point the elbow/knee bends toward (the bend plane through the
    shoulder/hip, the target and the pole); NaN (or None): the limb's own bend plane."""
    if not isinstance(model, BodyModel):
        raise SolverInputError("model must be a BodyModel")
    if not isinstance(settings, AdjustSettings):
        raise SolverInputError("settings must be an AdjustSettings")
    problem = _Problem(model, heads, tails, targets, effectors, priorities, obstacles, settings, limits,
                       bone_x_axes)
    problem.set_end_goals(end_turns, poles)
    return problem.solve()


# ----------------------------------------------------------------------------------------------------------
# The solve

class _Problem:
    """One adjustment of F frames: its inputs and per-frame state, the sub-bases placed by ``sub_bases``
    (SubBasePlacement) and the limbs by ``limbs`` (LimbPlacement), both working on this problem."""

    _PER_FRAME = ("H0", "T0", "targets", "active_e", "iterations")
    _PER_FRAME_DICTS = ("chain0", "reach", "reach_eff", "limb_target", "limb_active", "end_turns", "limb_pole")

    def __init__(self, model, heads, tails, targets, effectors, priorities, obstacles, settings, limits,
                 bone_x_axes):
        self.model = model
        self.settings = settings
        checked = checked_inputs(model, heads, tails, targets, effectors, priorities, obstacles)
        self.H0, self.T0, self.effectors = checked.heads, checked.tails, checked.effectors
        F = self.F = self.H0.shape[0]
        t = self.targets = checked.targets
        self.active_e = checked.active
        pr = self.priorities = checked.priorities
        self.obstacles = checked.obstacles

        # Limb chains at the start poses and their reach (read-only, kept with the prepared start pose).
        self.prepared = prepare(model, self.H0, self.T0, settings, bone_x_axes)
        if self.obstacles is not None:  # boxes no bone can reach are left out before any test
            centre, radius = body_reach(model, self.H0, self.T0, t, self.prepared.skeleton_reach())
            self.obstacles = reachable_boxes(self.obstacles, centre, radius + settings.chain.margin)
        self.chain0, self.reach = self.prepared.chains()
        # Reach used for the sub-base decisions; cut where joint limits held a limb short (limit_passes).
        self.reach_eff = {n: r.copy() for n, r in self.reach.items()}
        self.limb_target = {}
        self.limb_active = {}
        self.limb_priority = {}
        for name in model.limbs:
            self.limb_target[name] = np.zeros((F, 3))
            self.limb_active[name] = np.zeros(F, dtype=bool)
            self.limb_priority[name] = 0.0
        for k, e in enumerate(self.effectors):
            name = LIMB_OF_EFFECTOR[e]
            self.limb_target[name] = np.where(self.active_e[:, k, None], t[:, k], 0.0)
            self.limb_active[name] = self.active_e[:, k].copy()
            self.limb_priority[name] = float(pr[k])

        self.default_limits = limits is None
        if limits is None:
            limits = self.prepared.limits  # the solver's own, made to fit: not checked again on every solve
        else:
            check_limits(model, limits, F)
        self.limits = limits
        self.iterations = np.zeros(F, dtype=np.int64)
        self.end_turns, self.limb_pole = {}, {}
        self._own_parts()

    def _own_parts(self):
        self.limbs = LimbPlacement(self)
        self.sub_bases = SubBasePlacement(self, self.limbs)

    def set_end_goals(self, end_turns, poles):
        """Per limb: the end bone's wanted world rotation deltas (F,3,3) and the pole points (F,3), NaN rows
        where none (see adjust_frames); limbs without any are left out."""
        self.end_turns, self.limb_pole = end_goals(self.effectors, self.F, end_turns, poles)

    def _subset(self, rows):
        """The same problem restricted to frames `rows` (a fresh iteration count)."""
        sub = object.__new__(type(self))
        sub.__dict__.update(self.__dict__)
        sub.F = len(rows)
        for name in self._PER_FRAME:
            setattr(sub, name, getattr(self, name)[rows])
        sub.iterations = np.zeros(len(rows), dtype=np.int64)
        for name in self._PER_FRAME_DICTS:
            setattr(sub, name, {k: v[rows] for k, v in getattr(self, name).items()})
        sub.limits = {k: LimbLimits(_take_limits(v.limits, rows),
                                    None if v.parent_direction is None else v.parent_direction[rows])
                      for k, v in self.limits.items()}
        if self.obstacles is not None:
            sub.obstacles = self.obstacles.select(rows)
        sub._own_parts()
        return sub

    def solve(self) -> AdjustBatchResult:
        result = self._solve_once()
        # Fixed-width string arrays would cut a longer status or reason copied in from a re-solve short.
        result.status, result.reasons = result.status.astype(object), result.reasons.astype(object)
        tol = self.settings.chain.tolerance
        # A frame whose re-solve was not taken would be re-solved from the same result, so with the same cut
        # reaches, into the same pose again, and not taken again: it has no further pass.
        rejected = np.zeros(self.F, dtype=bool)
        for _ in range(self.settings.limit_passes):
            held = ((result.status == "limited") | (result.status == "max_iterations")) & (result.residuals > tol)
            held &= ~rejected[:, None]
            if not self.settings.help_held_limbs:
                # Rule (i) read literally: a limb's reach is cut only where its sub-base already had to move.
                for k, e in enumerate(self.effectors):
                    hub_moved = result.sc_displacement if self.model.limbs[LIMB_OF_EFFECTOR[e]].hub == "sc" \
                        else result.root_displacement
                    held[:, k] &= hub_moved > 0.0
            rows = np.nonzero(held.any(axis=1))[0]
            if rows.size == 0:
                break
            for k, e in enumerate(self.effectors):
                name = LIMB_OF_EFFECTOR[e]
                limb = self.model.limbs[name]
                r = rows[held[rows, k]]
                got = norm(limb.end_point(result.heads[r], result.tails[r]) - result.heads[r, limb.bones[0]])
                self.reach_eff[name][r] = np.minimum(self.reach_eff[name][r], got)
            sub = self._subset(rows)
            again = sub._solve_once()
            self.iterations[rows] += again.iterations
            # Better = more tasks met, or as many with a smaller total residual.
            met_new = np.sum(again.status == "reached", axis=1)
            met_old = np.sum(result.status[rows] == "reached", axis=1)
            smaller = np.nansum(again.residuals, axis=1) < np.nansum(result.residuals[rows], axis=1) - 1e-12
            better = (met_new > met_old) | ((met_new == met_old) & smaller)
            take = rows[better]
            rejected[rows[~better]] = True
            for f in ("heads", "tails", "rotations", "residuals", "status", "reasons",
                      "sc_displacement", "root_displacement"):
                getattr(result, f)[take] = getattr(again, f)[better]
        result.iterations = self.iterations.copy()
        result.status, result.reasons = result.status.astype(str), result.reasons.astype(str)
        return result

    def _solve_once(self) -> AdjustBatchResult:
        F = self.F
        upper = self.sub_bases._upper()
        trunk0 = self.chain0["trunk"]
        sc0 = trunk0[:, -1]
        offsets0 = {n: self.chain0[n][:, 0] - sc0 for n in upper}

        rows = np.arange(F)
        delta, sc_star, trunk_joints, trunk_solved, t_status, t_reason = self.sub_bases._sub_bases(rows, offsets0)
        # The chest turns, and the arm bases with it: re-place the SC with the turned offsets (fixed point).
        # A frame whose turned offsets moved less than the tolerance since its last placement would get the same
        # SC again (within tolerance): it stops there (a target out of reach converges to such a fixed point).
        tol = self.settings.chain.tolerance
        placed_with = dict(offsets0)
        fixable = None
        for _ in range(self.settings.sub_base_passes - 1):
            if not any_set(trunk_solved):
                break  # the chest did not turn on any frame: no limb's base moved (far below is empty)
            chest_r = chest_rotation(trunk0, trunk_joints)
            turned = {n: apply_matrix(chest_r, offsets0[n]) for n in upper}
            changed = np.zeros(F, dtype=bool)
            far, turn = {}, {}
            for n in upper:
                base = trunk_joints[:, -1] + turned[n]
                out_of_reach = norm(self.limb_target[n] - base) > self.reach_eff[n] + tol
                far[n] = trunk_solved & self.limb_active[n] & out_of_reach
                turn[n] = norm(turned[n] - placed_with[n])
                changed |= turn[n] > tol
            if not any(any_set(far[n] & changed) for n in upper):
                break
            if fixable is None:  # the same on every pass: it depends on the start offsets only
                fixable = self.sub_bases._fixable(upper, offsets0)
            retry = np.zeros(F, dtype=bool)
            for n in upper:
                # A limb that may still reach is re-placed while its base moves at all; one that cannot, only
                # while its base moves by more than the reach margin: its best effort cannot gain more.
                worth = np.where(fixable[n], changed, turn[n] > self.settings.reach_margin * self.reach_eff[n])
                retry |= far[n] & worth
            if not any_set(retry):
                break
            r = np.nonzero(retry)[0]
            offsets = {n: turned[n][r] for n in upper}
            for n in upper:
                placed_with[n] = placed_with[n].copy()
                placed_with[n][r] = offsets[n]
            out = self.sub_bases._sub_bases(r, offsets, force_sc=np.ones(r.size, dtype=bool))
            delta[r], sc_star[r], trunk_joints[r] = out[0], out[1], out[2]
            trunk_solved[r], t_status[r], t_reason[r] = out[3], out[4], out[5]

        trunk = LimbSolve(trunk_joints, trunk_solved, t_status, t_reason)
        heads, tails, rotations, limb_solves = self.limbs._propagate(delta, trunk)
        return self._result(heads, tails, rotations, limb_solves)

    def _result(self, heads, tails, rotations, solves) -> AdjustBatchResult:
        outcome = effector_outcome(self.model, self.effectors, self.targets, self.active_e,
                                   self.settings.chain.tolerance, heads, tails, solves)
        return batch_result(self.model, self.H0, self.T0, self.effectors, self.iterations.copy(), heads, tails,
                            rotations, outcome)


def _take_limits(limits, rows):
    """JointLimits with per-frame hinge axes (and references) restricted to frames `rows`."""
    axes, ref = limits.hinge_axis, limits.hinge_reference
    return limits.derived(hinge_axis=axes[rows] if axes.ndim == 3 else axes,
                          hinge_reference=ref[rows] if ref is not None and ref.ndim == 3 else ref)
