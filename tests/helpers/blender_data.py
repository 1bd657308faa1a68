"""Reading what Blender evaluated, for tests and benches: an object as the depsgraph has it, a collection's property
in one bulk read, and the bone map stored on an armature."""

import bpy
import numpy as np


def evaluated(obj):
    bpy.context.view_layer.update()
    return obj.evaluated_get(bpy.context.evaluated_depsgraph_get())


def bulk(collection, prop, shape):
    """``prop`` of every item of ``collection`` as float64 (len, *shape), read with foreach_get."""
    out = np.empty(len(collection) * int(np.prod(shape)), dtype=np.float32)
    collection.foreach_get(prop, out)
    return out.reshape((len(collection),) + shape).astype(np.float64)


def bone_map(obj):
    """{group: [bone, ...]} as stored on the armature by the extension."""
    groups = {}
    for item in obj.fullbody_adjust.bone_map:
        groups.setdefault(item.group, []).append(item.bone)
    return groups
