"""Obstacles: world-space bounding boxes of meshes, as corners in bound_box order for
solver.obstacles.Boxes.from_box_corners (each mesh's own box with its rotation).

Which meshes: those of ``obj.fullbody_adjust.obstacles`` (child collections included),
or, when that is None, every visible mesh that does not move with this armature.
"""

import numpy as np

from ..errors import AdjustError
from .frames import step_frames


def obstacle_meshes(obj, context):
    """The mesh objects that are obstacles for armature ``obj``, sorted by name.

    The chosen collection's meshes are taken whether visible or not (the user picked them), but a
    mesh that moves with this armature is never an obstacle to it: it would always collide.
    """
    collection = obj.fullbody_adjust.obstacles
    if collection is not None:
        candidates = [ob for ob in collection.all_objects if ob.type == 'MESH']
    else:
        # scene.objects, not view_layer.objects: the latter lags behind objects linked since the last update.
        # The type first: it is the cheaper test, and a scene's set has many objects.
        view_layer = context.view_layer
        candidates = [ob for ob in context.scene.objects if ob.type == 'MESH' and ob.visible_get(view_layer=view_layer)]
    meshes = [ob for ob in candidates if not moves_with(ob, obj)]
    return sorted(meshes, key=lambda ob: ob.name)


def moves_with(ob, armature):
    """True when ``ob`` is deformed by ``armature``, parented to it (directly or through other
    objects), or constrained to it — i.e. the character's own meshes and what it carries."""
    node = ob
    while node is not None:
        if node == armature:
            return True
        if any(mod.type == 'ARMATURE' and mod.object == armature for mod in node.modifiers):
            return True
        if any(_constraint_targets(con, armature) for con in node.constraints):
            return True
        node = node.parent
    return False


def _constraint_targets(constraint, armature):
    if getattr(constraint, "target", None) == armature:
        return True
    # The Armature constraint keeps its targets in a list.
    return any(item.target == armature for item in getattr(constraint, "targets", ()))


def obstacle_boxes(obj, context):
    """World-space corners (K, 8, 3) of the evaluated bounding boxes of obstacle_meshes(obj, context).

    Evaluated, so modifiers count. A rotated mesh gives its 8 transformed corners, in bound_box order, so
    Boxes.from_box_corners keeps its rotation. (A mesh with no geometry gives a point box at its origin.)
    """
    return _corners(obstacle_meshes(obj, context), context.evaluated_depsgraph_get())


def obstacle_box_frames(obj, context, frames):
    """Corners (F, K, 8, 3) per frame, for moving obstacles. The meshes are chosen once, at the
    current frame, so K is the same for every frame; the current frame is restored afterwards."""
    frames = [float(frame) for frame in frames]
    meshes = obstacle_meshes(obj, context)
    boxes = np.zeros((len(frames), len(meshes), 8, 3))
    for row, frame in step_frames(context.scene, frames):
        boxes[row] = _corners(meshes, context.evaluated_depsgraph_get(), frame)
    return boxes


def box_frame_reader(obj, context):
    """A function of the current scene frame giving the obstacles' world corners (K, 8, 3); the meshes are
    chosen once, here."""
    meshes = obstacle_meshes(obj, context)
    return lambda frame: _corners(meshes, context.evaluated_depsgraph_get(), frame)


def _corners(meshes, depsgraph, frame=None):
    corners = np.zeros((len(meshes), 8, 3))
    local = np.empty((len(meshes), 24), dtype=np.float32)  # Blender's float32 values, read in bulk
    for index, ob in enumerate(meshes):
        evaluated = ob.evaluated_get(depsgraph)
        evaluated.bound_box.foreach_get(local[index])  # np.array(bound_box) cost 20 times more
        world = np.array(evaluated.matrix_world, dtype=np.float64)
        corners[index] = local[index].reshape(8, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3]
    bad = np.nonzero(~np.isfinite(corners).all(axis=(1, 2)))[0]
    if len(bad):
        where = "" if frame is None else f" at frame {frame:g}"
        raise AdjustError(f"Obstacle '{meshes[bad[0]].name}' has a non-finite bounding box{where}")
    return corners
