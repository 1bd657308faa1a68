"""Where the effectors ended: their joints in the solved pose or as Blender evaluates it, and the chain joints
and segments inside the obstacle boxes."""

import bpy
import numpy as np

from ...solver.body.joint_ends import end_points
from ...solver.obstacles.boxes import penetrations as box_penetrations
from ...solver.vocabulary import EFFECTORS
from . import solve_space


def effector_positions(model, heads, tails, matrix_world):
    """World positions (F,E,3) of the effector joints (the heads of the hand, foot and head bones; a hand-less
    arm's wrist: its last bone's end, from ``tails``, the joint ends)."""
    out = np.full(heads.shape[:1] + (len(EFFECTORS), 3), np.nan)
    for limb in model.limbs.values():
        if limb.effector in EFFECTORS:
            out[:, EFFECTORS.index(limb.effector)] = limb.end_point(heads, tails)
    return solve_space.transform(matrix_world, out)


def evaluated_ends(obj, rig, bones):
    """World joint ends (k,3) (rig_cache.Rig.ends) of ``bones`` (indices) in the evaluated pose."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    matrices = np.array([evaluated.pose.bones[rig.model.names[j]].matrix for j in bones], dtype=np.float64)
    return end_points(np.array(evaluated.matrix_world, dtype=np.float64) @ matrices, rig.ends[bones])


def penetrations(model, heads, tails, boxes):
    """Chain joints inside, and chain segments crossing, an obstacle box: (F,) counts each. Every limb's chain in
    one test (the counts add up over joints and segments, so they are the sums of the limbs' own)."""
    if boxes is None:
        none = np.zeros(heads.shape[0], dtype=np.int64)
        return none, none
    chains = [limb.joints(heads, tails) for limb in model.limbs.values()]
    segments, at = [], 0
    for chain in chains:
        n = chain.shape[1]
        segments.append(np.c_[np.arange(at, at + n - 1), np.arange(at + 1, at + n)])
        at += n
    return box_penetrations(np.concatenate(chains, axis=1), np.concatenate(segments), boxes)
