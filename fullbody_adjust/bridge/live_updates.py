"""Which of a depsgraph's updates concern a live armature (bridge/live.py): one of its targets or poles moved, its
obstacles may have changed, its object moved."""

import bpy
import numpy as np

from .errors import AdjustError
from .reading import obstacles


def follow_obstacles(obj, state, depsgraph):
    """Drop the obstacles ``state`` keeps when ``depsgraph``'s updates may have changed them. A changed obstacle mesh
    has them read at once, and solves again only when the boxes did change: a mesh that follows the pose some other
    way (a driver) changes with every pose shown, and would otherwise keep Live solving."""
    changed = obstacles_changed(obj, depsgraph)
    if changed == MESH_CHANGED:
        kept = state.obstacle_corners
        try:
            state.obstacle_corners = obstacles.obstacle_boxes(obj, bpy.context)
        except AdjustError:  # the solve says why
            state.obstacle_corners = None
        state.pending |= state.obstacle_corners is None or kept is None \
            or not np.array_equal(kept, state.obstacle_corners)
    elif changed:
        state.obstacle_corners = None


def inputs_moved(obj, moved):
    """Whether one of the objects named ``moved`` is a target or a pole of ``obj`` (obstacles: see
    obstacles_changed)."""
    if not moved:
        return False
    slots = obj.fullbody_adjust.targets
    return bool(moved & {ob.name for slot in slots for ob in (slot.target, slot.pole) if ob is not None})


# What obstacles_changed tells.
MESH_CHANGED = "mesh"  # an obstacle mesh moved or changed: read them at once, solve again if they differ
SCENE_CHANGED = "scene"  # the scene's objects or collections changed: read them again at the next solve


def obstacles_changed(obj, depsgraph):
    """How ``depsgraph``'s updates may have changed the obstacles of ``obj``: MESH_CHANGED when a mesh that does not
    move with ``obj`` moved or changed (the character's own meshes, deformed by each pose shown, do not count);
    else SCENE_CHANGED when the scene or a collection was updated (objects linked, removed, shown, hidden: such
    updates name them; so do many other changes, which is why they do not solve again by themselves); else None."""
    scene = None
    for update in depsgraph.updates:
        data = update.id.original
        if isinstance(data, (bpy.types.Scene, bpy.types.Collection)):
            scene = SCENE_CHANGED
        elif (isinstance(data, bpy.types.Object) and data.type == 'MESH'
              and (update.is_updated_transform or update.is_updated_geometry) and not obstacles.moves_with(data, obj)):
            return MESH_CHANGED
    return scene


def object_moved(obj, state):
    return state.start is not None and not np.allclose(np.array(obj.matrix_world), state.start.matrix_world,
                                                        rtol=0.0, atol=1e-6)
