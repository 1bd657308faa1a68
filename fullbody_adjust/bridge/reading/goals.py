"""What the armature's target slots ask of a solve: the targets of the current frame, the hands' and feet's
turns and poles in armature space, the effectors the model can serve and their priorities."""

import numpy as np

from ...solver.vocabulary import DEFAULT_PRIORITY, EFFECTORS
from ..errors import AdjustError
from ..rig import targets
from . import solve_space


def current_targets(obj, context, skip_missing=False):
    """FrameTargets (one frame: (1,E,...) each) of the enabled targets at the current frame as evaluated."""
    specs = targets.read_targets(obj, context.evaluated_depsgraph_get(), skip_missing=skip_missing)
    return targets.FrameTargets(*(field[None] for field in targets.frame_targets(specs)))


def end_goals(obj, model, snapshot, goals, to_arm):
    """The solver's end_turns (F,E,3,3) and poles (F,E,3) in armature space from the FrameTargets (None where
    no slot asks for them): a hand or foot with use_rotation turns from its pose orientation to its target's."""
    end_turns = None
    if goals.oriented.any():
        end_turns = np.full(goals.rotations.shape, np.nan)
        for limb in model.limbs.values():
            if limb.effector not in EFFECTORS:
                continue
            column = EFFECTORS.index(limb.effector)
            rows = goals.oriented[:, column] & np.isfinite(goals.positions[:, column, 0])
            if rows.any() and limb.end_bone is None:
                raise AdjustError(f"The {limb.effector} target of '{obj.name}' asks for its rotation, but the arm has "
                                  f"no hand bone to turn (the wrist is the end of '{model.names[limb.bones[-1]]}'): "
                                  f"switch Rotation off in that slot")
            if rows.any():
                wanted = _orthonormal(to_arm[rows, :3, :3] @ goals.rotations[rows, column])
                now = _orthonormal(snapshot.pose_matrices[rows, limb.end_bone, :3, :3])
                end_turns[rows, column] = wanted @ np.swapaxes(now, -1, -2)
    poles = solve_space.transform(to_arm, goals.poles) if np.isfinite(goals.poles).any() else None
    return end_turns, poles


def _orthonormal(matrices):
    """The rotations (...,3,3) nearest ``matrices`` (their polar factor): a rotation carried through a scaled
    armature transform, or a bone's pose matrix without its scale."""
    u, _s, vt = np.linalg.svd(matrices)
    return u @ vt


def served(obj, model, world_targets):
    """Columns of the EFFECTORS the model can serve (the head only with neck bones mapped); AdjustError naming the
    slot when an enabled target asks for one it cannot."""
    served = [k for k, effector in enumerate(EFFECTORS) if effector in model.effectors]
    for k, effector in enumerate(EFFECTORS):
        if k not in served and np.isfinite(world_targets[:, k]).any():
            raise AdjustError(f"The {effector} target of '{obj.name}' needs neck bones mapped below the head: "
                              f"map them in Bone Mapping, or switch the {effector} slot off")
    return served


def columns(values, served):
    return tuple(values[k] for k in served)


def widened(values, served, fill):
    """(F,k) values of the served effectors as (F,E), ``fill`` for the others."""
    out = np.full(values.shape[:1] + (len(EFFECTORS),), fill, dtype=object)
    out[:, served] = values
    return out.astype(str)


def priorities(obj):
    by_effector = {slot.effector: int(slot.priority) for slot in obj.fullbody_adjust.targets}
    return np.array([by_effector.get(e, DEFAULT_PRIORITY[e]) for e in EFFECTORS], dtype=np.float64)
