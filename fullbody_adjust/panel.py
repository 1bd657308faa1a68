# SPDX-License-Identifier: GPL-3.0-or-later
"""The "Full Body" tab in the 3D viewport's sidebar (N-panel): the active armature's bone mapping, targets,
obstacles and settings, and the buttons that run the operators."""

import bpy

from .bridge import live
from .bridge.reading import start_checks
from .bone_mapping import GROUP_LABELS


def _active_armature(context):
    obj = context.active_object
    return obj if obj is not None and obj.type == 'ARMATURE' else None


def _not_armature_reason(obj):
    return "Select an armature" if obj is None else f"'{obj.name}' is not an armature: select an armature"


class FULLBODY_ADJUST_UL_targets(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.prop(item, "enabled", text="")
        row.prop(item, "effector", text="")
        row.prop(item, "target", text="")
        row.prop(item, "priority", text="")
        limb = item.effector != "head"  # the head has no pole and no orientation drive
        sub = row.row(align=True)
        sub.active = limb
        sub.prop(item, "use_rotation", text="", icon='ORIENTATION_GIMBAL')
        sub.prop(item, "pole", text="")


class FULLBODY_ADJUST_UL_bone_map(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.label(text=GROUP_LABELS.get(item.group, item.group))
        armature = data.id_data.data if data.id_data.type == 'ARMATURE' else None
        if armature is not None:
            row.prop_search(item, "bone", armature, "bones", text="")
        else:
            row.prop(item, "bone", text="")


class FULLBODY_ADJUST_PT_main(bpy.types.Panel):
    bl_label = "Full Body Adjust"
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Full Body"

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        if _active_armature(context) is None:
            # Greyed out rather than hidden, so the tab stays put and says what it needs.
            layout.label(text=_not_armature_reason(obj), icon='INFO')
            layout.enabled = False
            return
        settings = obj.fullbody_adjust
        mapped = len(settings.bone_map)
        row = layout.row()
        if mapped:
            row.label(text=f"Mapped: {mapped} bones", icon='CHECKMARK')
        else:
            row.label(text="Not mapped yet", icon='ERROR')
        row.operator("fullbody_adjust.map_bones", text="Map Bones" if not mapped else "Map Again")
        summary = start_checks.rig_summary(obj)
        if summary is not None:
            line, ok = summary
            layout.label(text=line, icon='ARMATURE_DATA' if ok else 'ERROR')

        layout.label(text="Targets")
        layout.template_list(
            "FULLBODY_ADJUST_UL_targets", "", settings, "targets", settings, "active_target_index", rows=3,
        )
        layout.operator("fullbody_adjust.create_targets", icon='EMPTY_AXIS')
        layout.prop(settings, "obstacles")
        layout.prop(settings, "variant")
        column = layout.column(align=True)
        column.scale_y = 1.4
        column.operator("fullbody_adjust.adjust_pose", icon='ARMATURE_DATA')
        column.operator("fullbody_adjust.adjust_frames", icon='ACTION')
        row = layout.row(align=True)
        row.prop(settings, "live", toggle=True, icon='PLAY' if not settings.live else 'PAUSE')
        if settings.live:
            row.operator("fullbody_adjust.key_pose", icon='KEY_HLT')
            problem = live.status(obj)
            if problem:
                layout.label(text=problem, icon='ERROR')
        layout.operator("fullbody_adjust.retarget", text="Retarget from Selected", icon='ARMATURE_DATA')
        layout.operator("fullbody_adjust.mirror_pose", icon='MOD_MIRROR')


class _SubPanel:
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Full Body"
    bl_parent_id = "FULLBODY_ADJUST_PT_main"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return _active_armature(context) is not None


class FULLBODY_ADJUST_PT_mapping(_SubPanel, bpy.types.Panel):
    bl_label = "Bone Mapping"

    def draw(self, context):
        settings = context.active_object.fullbody_adjust
        self.layout.template_list(
            "FULLBODY_ADJUST_UL_bone_map", "", settings, "bone_map", settings, "active_bone_map_index", rows=4,
        )


class FULLBODY_ADJUST_PT_solver(_SubPanel, bpy.types.Panel):
    bl_label = "Solver"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        settings = context.active_object.fullbody_adjust
        layout.prop(settings, "margin")
        layout.prop(settings, "tolerance")
        layout.prop(settings, "max_iterations")
        layout.prop(settings, "use_joint_limits")
        layout.prop(settings, "keep_hand_orientation")


classes = (
    FULLBODY_ADJUST_UL_targets,
    FULLBODY_ADJUST_UL_bone_map,
    FULLBODY_ADJUST_PT_main,
    FULLBODY_ADJUST_PT_mapping,
    FULLBODY_ADJUST_PT_solver,
)

register, unregister = bpy.utils.register_classes_factory(classes)
