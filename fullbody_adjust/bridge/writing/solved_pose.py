"""The solved pose as armature-space matrices of the bones to write: the bones the solver drives that moved on
some frame, and those below them."""

import numpy as np

from ...solver.maths.geometry import norm
from ...solver.vocabulary import EFFECTORS
from ..reading import solve_space, start_checks

# A bone counts as moved when its rotation changed by more than this (radians, about) or its head moved by
# more than this fraction of the rig's size: below it, a key would only record float noise.
_MOVED = 1e-9


def new_pose_matrices(snapshot, result, unit, bones):
    """Armature-space matrices (F,k,4,4) of ``bones`` in the solved pose (their scale kept); ``unit`` (F,): the
    solve space's length of one armature unit (solve_space.solve_space)."""
    new_pose = np.zeros(snapshot.pose_matrices[:, bones].shape)
    new_pose[..., :3, :3] = result.rotations[:, bones] @ snapshot.pose_matrices[:, bones, :3, :3]
    new_pose[..., :3, 3] = solve_space.armature_units(result.heads[:, bones], unit)
    new_pose[..., 3, 3] = 1.0
    return new_pose


def bones_to_write(model, snapshot, result, unit, keep_hands, oriented):
    """Indices of the bones the solver drives whose transform changed on some frame, or below one that did (a
    foot that keeps its world orientation while its shin turns changes its local rotation), parents first.
    ``oriented`` (E,) bool: effectors whose end bone takes its target's orientation, written even without
    ``keep_hands``."""
    driven = start_checks.driven_bones(model.roles, with_ends=keep_hands)
    for limb in model.limbs.values():
        if limb.effector in EFFECTORS and oriented[EFFECTORS.index(limb.effector)] \
                and limb.end_bone is not None:
            driven[limb.end_bone] = True
    driven = np.nonzero(driven)[0]  # only these are measured (a fraction of a full rig's bones)
    turn = np.abs(result.rotations[:, driven] - np.eye(3)).max(axis=(-1, -2))  # (F,k)
    old_heads = snapshot.pose_matrices[..., :3, 3]
    shift = norm(solve_space.armature_units(result.heads[:, driven], unit) - old_heads[:, driven])
    shift = shift / snapshot.derived("armature size", lambda: solve_space.size_of(old_heads))
    changed = set(driven[((turn > _MOVED) | (shift > _MOVED)).any(axis=0)].tolist())
    below = set()  # bones some ancestor of which changed
    parents = model.parents.tolist()
    for bone in model.order.tolist():
        parent = parents[bone]
        if parent in changed or parent in below:
            below.add(bone)
    return np.array([bone for bone in driven.tolist() if bone in changed or bone in below], dtype=driven.dtype)
