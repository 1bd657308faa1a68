# SPDX-License-Identifier: GPL-3.0-or-later
"""The Retarget operator: another armature's motion onto the active armature, into a new action.

A thin wrapper around bridge.retarget.retarget (the same call the command line makes). The source is the
``source`` property when set, else the one selected armature other than the active one."""

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from .bridge import retarget
from .bridge.errors import AdjustError
from .operators import ArmatureOperator


def _armature_names(self, context, edit_text):
    return [ob.name for ob in context.scene.objects if ob.type == 'ARMATURE' and ob != context.active_object
            and edit_text.lower() in ob.name.lower()]


def _object_names(self, context, edit_text):
    return [ob.name for ob in context.scene.objects if ob.type != 'ARMATURE' and edit_text.lower() in ob.name.lower()]


def source_armature(context, name=""):
    """The source armature: the object named ``name``, else the one selected armature other than the
    active one. AdjustError (one line) when there is none or more than one."""
    if name:
        source = bpy.data.objects.get(name)
        if source is None:
            raise AdjustError(f"No object named '{name}' to retarget from")
        return source
    candidates = [ob for ob in context.selected_objects if ob.type == 'ARMATURE' and ob != context.active_object]
    if not candidates:
        raise AdjustError("Select the source armature too (the target is the active one), or name the source")
    if len(candidates) > 1:
        raise AdjustError("More than one other armature is selected: select only the source, or name it")
    return candidates[0]


def contact_list(kinds, object_names):
    """bridge.retarget's contacts of the operator's settings: 'ground' if GROUND is among ``kinds``, and with
    OBJECT one ('object', name) per comma-separated name (one with None when none is given: a clear error)."""
    out = ["ground"] if 'GROUND' in kinds else []
    if 'OBJECT' in kinds:
        names = [n.strip() for n in object_names.split(",") if n.strip()]
        out += [("object", n) for n in names] or [("object", None)]
    return out


class FULLBODY_ADJUST_OT_retarget(ArmatureOperator, bpy.types.Operator):
    """Retarget another armature's motion onto the active armature, into a new action (hands and feet keep \
to the source's trajectories and contacts)"""
    bl_idname = "fullbody_adjust.retarget"
    bl_label = "Retarget Motion"
    bl_options = {'REGISTER', 'UNDO'}

    source: StringProperty(name="Source", search=_armature_names,
                           description="Armature whose motion to retarget (default: the selected armature "
                                       "other than the active one)")
    frame_start: IntProperty(name="Start", description="First frame (default: the source action's first)")
    frame_end: IntProperty(name="End", description="Last frame (default: the source action's last)")
    contacts: EnumProperty(
        name="Contacts",
        items=(('GROUND', "Ground", "Planted feet rest on the floor and do not slide"),
               ('OBJECT', "Object", "Hands and feet touching the contact object are held on it")),
        options={'ENUM_FLAG'},
        default={'GROUND'},
        description="What hands and feet may touch (one or both)",
    )
    contact_object: StringProperty(name="Contact Object", search=_object_names,
                                   description="Object whose contacts are kept (for Object contacts; several: "
                                               "names separated by commas)")
    exact: BoolProperty(name="Exact Contacts", default=True,
                        description="Hands on the object go to the source's own positions on it, instead of "
                                    "the source's scaled by the legs' ratio (soles always rest on the floor)")
    new_action: StringProperty(name="New Action",
                               description="Name of the new action (default: <source action>_<target>)")

    def execute(self, context):
        props = self.properties
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            source = source_armature(context, self.source)
            outcome = retarget.retarget(
                context, source, context.active_object,
                self.frame_start if props.is_property_set("frame_start") else None,
                self.frame_end if props.is_property_set("frame_end") else None,
                contacts=contact_list(self.contacts, self.contact_object), exact=self.exact,
                new_action=self.new_action or None,
                progress=lambda stage, fraction: wm.progress_update(int(100 * fraction)))
        except AdjustError as ex:
            self.report({'ERROR'}, str(ex))
            return {'CANCELLED'}
        finally:
            wm.progress_end()
        self.report({'INFO'}, outcome.summary())
        return {'FINISHED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in ("source", "frame_start", "frame_end", "contacts", "contact_object", "exact", "new_action"):
            row = layout.row()
            row.prop(self, name)
            row.enabled = name != "contact_object" or 'OBJECT' in self.contacts


classes = (FULLBODY_ADJUST_OT_retarget,)

register, unregister = bpy.utils.register_classes_factory(classes)
