"""Which meshes an armature deforms: what the limbs' thickness (reading/limb_thickness.py) and the feet's soles
(retarget/soles.py) are read from."""

import bpy


def deformed_meshes(obj):
    """The mesh objects with vertex groups that armature ``obj`` deforms (an enabled Armature modifier that uses
    vertex groups, or an armature parent), in name order."""
    out = []
    for ob in bpy.data.objects:
        if ob.type != 'MESH' or ob.data is None or not len(ob.vertex_groups):
            continue
        by_modifier = any(m.type == 'ARMATURE' and m.object == obj and m.show_viewport and m.use_vertex_groups
                          for m in ob.modifiers)
        by_parent = ob.parent == obj and ob.parent_type == 'ARMATURE'
        if by_modifier or by_parent:
            out.append(ob)
    return sorted(out, key=lambda ob: ob.name)
