"""Create Targets: an empty at each wrist and ankle (and the head), linked in the armature's target slots."""

import numpy as np

from ...solver.body.joint_ends import end_points
from ...solver.body.model import LIMB_OF_EFFECTOR
from ..reading import pose, start_checks
from . import rig_cache, targets


def create_targets(context, obj, *, reset=False):
    """Empties at the current wrists and ankles (and head, when mapped), linked in the armature's target slots.
    Returns {effector: empty}."""
    start_checks.check_armature(obj)
    rig = rig_cache.rig_of(obj)
    snapshot = pose.read_pose(obj, rig.static(obj))
    positions = {}
    for effector in targets.EFFECTORS:
        bones = rig.bone_map.bones(effector)  # the hand, foot and head groups are named after their effectors
        if bones:
            positions[effector] = snapshot.heads[snapshot.index(bones[-1])]
        elif effector in rig.model.effectors:  # a hand-less arm: its wrist is its last bone's end
            last = rig.model.limbs[LIMB_OF_EFFECTOR[effector]].bones[-1]
            positions[effector] = end_points(snapshot.matrices[last], rig.ends[last])
    size = 0.04 * max(float(np.ptp(snapshot.heads, axis=0).max()), 1e-3)
    targets.ensure_slots(obj)
    return targets.create_targets(context, obj, positions, size, reset=reset)
