"""What Adjust Pose checks before it changes anything: that the armature may be keyed, that its start pose can be
solved from (scales, bone lengths), that keys on its mapped bones would hold, and that no target lies absurdly far.
Each problem is one AdjustError line."""

import numpy as np

from ...solver.body.model import CHAIN, END, ROOT
from ...solver.maths.geometry import norm
from ..rig import control_rig, mapping, targets
from . import solve_space
from ..errors import AdjustError


# A pose scale (or a bone length relative to the rig's size) at or below this counts as zero.
_FLAT = 1e-6


# A target further than this many rig sizes away is an error (see check_target_distances).
_FAR = 1e6


def check_armature(obj):
    """AdjustError (one line) unless ``obj`` is an armature whose pose and keys may be changed."""
    if obj is None:
        raise AdjustError("No active object: select an armature")
    if obj.type != 'ARMATURE':
        raise AdjustError(f"'{obj.name}' is not an armature")
    if obj.library is not None:
        raise AdjustError(f"Armature '{obj.name}' is linked from library '{obj.library.name}' and cannot be edited")
    if not obj.is_editable:
        raise AdjustError(f"Armature '{obj.name}' is not editable (a library override the file does not own)")
    action = obj.animation_data.action if obj.animation_data is not None else None
    if action is not None and not action.is_editable:
        where = f"linked from library '{action.library.name}'" if action.library is not None else "not editable"
        raise AdjustError(f"Action '{action.name}' of '{obj.name}' is {where} and cannot be keyed")
    if obj.matrix_world.to_3x3().determinant() <= 0.0:
        raise AdjustError(f"Armature '{obj.name}' has a negative or zero scale: fix its scale first")


def check_start(obj, model, snapshot):
    """AdjustError unless the start pose can be solved from (object scale, bones' lengths and scales)."""
    _check_object_scale(obj, snapshot)
    _check_driven_bones(model, snapshot)
    return True


def _check_object_scale(obj, snapshot):
    """A mirrored or flattened object transform (on some frame, or through a parent) cannot be solved in."""
    det = np.linalg.det(snapshot.matrix_world[:, :3, :3])
    if (det <= 0.0).any():
        frame = snapshot.frame[int(np.argmax(det <= 0.0))]
        raise AdjustError(f"Armature '{obj.name}' has a negative or zero scale at frame {frame:g}: "
                          f"fix its scale first")


def _check_driven_bones(model, snapshot):
    """Each bone the solver may move, and each parent it is posed relative to, needs a length and an
    invertible pose matrix: a bone scaled to 0 in Pose Mode (on any axis) has neither."""
    moving = driven_bones(model.roles, with_ends=True)
    needed = moving.copy()
    needed[snapshot.parents[moving & (snapshot.parents >= 0)]] = True
    needed = np.nonzero(needed)[0]  # only these are measured (a fraction of a full rig's bones)
    axis_scales = norm(np.swapaxes(snapshot.pose_matrices[:, needed, :3, :3], -1, -2))  # (F,k,3)
    size = solve_space.world_size(snapshot)
    flat = (axis_scales.min(axis=-1) <= _FLAT) | (snapshot.lengths[:, needed] <= _FLAT * size)
    bad = needed[flat.any(axis=0)]
    if len(bad):
        raise AdjustError(f"Bone '{snapshot.names[bad[0]]}' has zero length or scale (scaled to 0 in Pose Mode?): "
                          f"fix it before adjusting")


def driven_bones(roles, with_ends):
    """(J,) bool: the bones the solver moves (root and chain bones; with_ends also hands, feet and head). By
    comparisons: np.isin costs ~0.1 ms a call, a fair part of a Live update's reading."""
    mask = (roles == ROOT) | (roles == CHAIN)
    return mask | (roles == END) if with_ends else mask


def check_not_driven(obj, bone_map):
    problem = driven_problem(obj, bone_map)
    if problem:
        raise AdjustError(problem)


def driven_problem(obj, bone_map):
    """On a rig this extension does not know as a control rig, a mapped bone that follows a constraint would
    override the keys written to it: the one line saying so, or None. Limit constraints only bound the pose."""
    for _group, name in bone_map.items():
        pose_bone = obj.pose.bones.get(name)
        for con in pose_bone.constraints if pose_bone is not None else ():
            if con.enabled and con.influence > 0.0 and not con.type.startswith("LIMIT_"):
                return (f"Bone '{name}' of '{obj.name}' follows its constraint '{con.name}', which would override "
                        f"keys written to it: pose the controls that drive it, or map other bones")
    return None


def rig_summary(obj):
    """(line, ok) for the panel: what kind of rig ``obj`` is and what Adjust Pose keys on it, or why keys on
    its mapped bones would not hold. None before the rig is mapped."""
    if control_rig.is_generated_rigify(obj):
        return control_rig.describe(obj), True
    bone_map = mapping.load_map(obj)
    if bone_map is None or obj.pose is None:  # not mapped yet, or an armature never evaluated
        return None
    problem = driven_problem(obj, bone_map)
    return (problem, False) if problem else ("Keys the mapped bones", True)


def check_target_distances(obj, world_targets, snapshot):
    """A target further from the rig than _FAR times its size is an error, not a goal: Blender's float32
    positions cannot place anything that far to better than a tenth of the rig (typing inf into a location
    field stores the largest float, 3.4e38)."""
    distance = norm(world_targets - snapshot.heads[:, :1])  # (F,E), NaN: no target
    far = np.nonzero((distance > _FAR * solve_space.world_size(snapshot)).any(axis=0))[0]
    if len(far):
        effector = targets.EFFECTORS[far[0]]
        name = next(s.target.name for s in obj.fullbody_adjust.targets if s.enabled and s.effector == effector)
        raise AdjustError(f"Target '{name}' for {effector} is {np.nanmax(distance[:, far[0]]):.3g} units away, "
                          f"too far to reach for (a location set to inf?)")
