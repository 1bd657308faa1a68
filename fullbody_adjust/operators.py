# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: thin wrappers around the bridge (adjustment, live, mapping, retarget). Each catches the bridge's
AdjustError and reports it as one line, so a bad input never shows a traceback and changes nothing; every option
is SKIP_SAVE, so a run starts from its defaults and the stored settings, never from the last run's values."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from .bridge import adjustment, live
from .bridge import files as batch
from .bridge.rig import mapping, target_empties
from .bridge.retarget import run as retarget
from .bridge.retarget.mirror import mirror_armature_pose
from .solver.retarget.root_motion import DEFAULT_SMOOTHING
from .bridge.errors import AdjustError
from .properties import FULLBODY_ADJUST_PG_settings


def armature_poll_message(context):
    """None when the active object can be adjusted, else why not (shown as the greyed-out tooltip)."""
    obj = context.active_object
    if obj is None:
        return "No active object: select an armature"
    if obj.type != 'ARMATURE':
        return f"'{obj.name}' is not an armature"
    if context.mode not in {'POSE', 'OBJECT'}:
        return "Switch to Object or Pose Mode"
    return None


def report_outcome(operator, outcome):
    """The run's summary: a WARNING naming what was missed when a target within reach was missed, a bone ends
    inside an obstacle or a contact within reach was not held (as the command line's exit code 1), else INFO."""
    warning = outcome.warning()
    if warning:
        operator.report({'WARNING'}, f"{warning}; {outcome.summary()}")
    else:
        operator.report({'INFO'}, outcome.summary())


class ArmatureOperator:
    """Operators on the active armature: greyed out, with the reason, when there is none."""

    @classmethod
    def poll(cls, context):
        reason = armature_poll_message(context)
        if reason is not None:
            cls.poll_message_set(reason)
        return reason is None

    def run(self, context, action):
        try:
            return action()
        except AdjustError as ex:
            self.report({'ERROR'}, str(ex))
            return None

    def run_and_report(self, context, action):
        """run(), with the window's progress bar following the ``progress(stage, fraction)`` callback that
        ``action`` is given, then the outcome reported (report_outcome): {'FINISHED'}, or {'CANCELLED'} when the
        run failed (its one line reported by run())."""
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            outcome = self.run(context, lambda: action(lambda stage, fraction: wm.progress_update(int(100 * fraction))))
        finally:
            wm.progress_end()
        if outcome is None:
            return {'CANCELLED'}
        report_outcome(self, outcome)
        return {'FINISHED'}


# The solver settings an adjust operator shows in its redo panel (same names as the stored settings).
SOLVER_OPTIONS = ("variant", "margin", "use_joint_limits", "keep_hand_orientation")


def _redo_option(name):
    """The operator's copy of the stored setting ``name``: the same property (name, text, default, range), but
    SKIP_SAVE, since Blender would otherwise start each run with the last run's value, marked as set, and the
    stored setting would never count again."""
    stored = FULLBODY_ADJUST_PG_settings.__annotations__[name]
    keywords = {key: value for key, value in stored.keywords.items() if key != "update"}
    return stored.function(**keywords, options={'SKIP_SAVE'})


class _SolverOptions:
    """Solver settings shown in the redo panel, declared from the stored settings; invoke() fills them from the
    armature's stored settings, and settings not passed to execute() come from there too."""

    __annotations__ = {name: _redo_option(name) for name in SOLVER_OPTIONS}

    def invoke(self, context, event):
        stored = context.active_object.fullbody_adjust
        for name in SOLVER_OPTIONS:
            if not self.properties.is_property_set(name):
                setattr(self, name, getattr(stored, name))
        return self.execute(context)

    def solver_options(self, **extra):
        chosen = {name: getattr(self, name) for name in SOLVER_OPTIONS if self.properties.is_property_set(name)}
        return adjustment.Options(**chosen, **extra)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in SOLVER_OPTIONS:
            layout.prop(self, name)


class FULLBODY_ADJUST_OT_map_bones(ArmatureOperator, bpy.types.Operator):
    """Map the armature's bones onto the body model again (presets, then detection from the hierarchy)"""
    bl_idname = "fullbody_adjust.map_bones"
    bl_label = "Map Bones"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        obj = context.active_object
        def remap():
            bone_map = mapping.map_rig(mapping.describe_armature(obj))
            mapping.store_map(obj, bone_map)
            return bone_map
        bone_map = self.run(context, remap)
        if bone_map is None:
            return {'CANCELLED'}
        self.report({'INFO'}, f"Mapped {len(bone_map.items())} bones ({bone_map.source})")
        return {'FINISHED'}


class FULLBODY_ADJUST_OT_create_targets(ArmatureOperator, bpy.types.Operator):
    """Create an empty at each wrist and ankle (and the head) and use them as the targets"""
    bl_idname = "fullbody_adjust.create_targets"
    bl_label = "Create Targets"
    bl_options = {'REGISTER', 'UNDO'}

    reset: BoolProperty(name="Reset", default=False, options={'SKIP_SAVE'},
                        description="Move existing target empties back to the current wrists and ankles")

    def execute(self, context):
        created = self.run(context, lambda: target_empties.create_targets(context, context.active_object,
                                                                        reset=self.reset))
        if created is None:
            return {'CANCELLED'}
        self.report({'INFO'}, f"{len(created)} targets ready: " + ", ".join(sorted(created)))
        return {'FINISHED'}


class FULLBODY_ADJUST_OT_adjust_pose(_SolverOptions, ArmatureOperator, bpy.types.Operator):
    """Adjust the whole body so hands and feet reach their targets, and key the bones that moved"""
    bl_idname = "fullbody_adjust.adjust_pose"
    bl_label = "Adjust Pose"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        return self.run_and_report(context, lambda _progress: adjustment.adjust_pose(
            context, context.active_object, self.solver_options()))


class FULLBODY_ADJUST_OT_adjust_frames(_SolverOptions, ArmatureOperator, bpy.types.Operator):
    """Adjust every frame of a range in one solve and key the bones that moved"""
    bl_idname = "fullbody_adjust.adjust_frames"
    bl_label = "Adjust Frames"
    bl_options = {'REGISTER', 'UNDO'}

    frame_start: IntProperty(name="Start", description="First frame (default: the scene's start)",
                             options={'SKIP_SAVE'})
    frame_end: IntProperty(name="End", description="Last frame (default: the scene's end)", options={'SKIP_SAVE'})
    new_action: StringProperty(name="New Action", options={'SKIP_SAVE'},
                               description="Write the keys into a new action of this name, keeping the original")

    def invoke(self, context, event):
        scene = context.scene
        for name, value in (("frame_start", scene.frame_start), ("frame_end", scene.frame_end)):
            if not self.properties.is_property_set(name):
                setattr(self, name, value)  # so the redo panel shows the range that was adjusted
        return super().invoke(context, event)

    def execute(self, context):
        scene = context.scene
        start = self.frame_start if self.properties.is_property_set("frame_start") else scene.frame_start
        end = self.frame_end if self.properties.is_property_set("frame_end") else scene.frame_end
        return self.run_and_report(context, lambda progress: adjustment.adjust_frames(
            context, context.active_object, start, end, self.solver_options(new_action=self.new_action or None),
            progress=progress))

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "frame_start")
        layout.prop(self, "frame_end")
        layout.prop(self, "new_action")
        super().draw(context)


class FULLBODY_ADJUST_OT_key_pose(ArmatureOperator, bpy.types.Operator):
    """Key the pose Live Adjust shows on the current frame (the bones it moved)"""
    bl_idname = "fullbody_adjust.key_pose"
    bl_label = "Key Pose"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not super().poll(context):
            return False
        if not context.active_object.fullbody_adjust.live:
            cls.poll_message_set("Turn Live Adjust on first")
            return False
        return True

    def execute(self, context):
        keyed = self.run(context, lambda: live.key_pose(context, context.active_object))
        if keyed is None:
            return {'CANCELLED'}
        self.report({'INFO'}, f"{len(keyed)} bones keyed" if keyed else "Nothing to key: the pose is the keyed one")
        return {'FINISHED'}


def _armature_names(self, context, edit_text):
    return [ob.name for ob in context.scene.objects if ob.type == 'ARMATURE' and ob != context.active_object
            and edit_text.lower() in ob.name.lower()]


def _object_names(self, context, edit_text):
    return [ob.name for ob in context.scene.objects if ob.type != 'ARMATURE' and edit_text.lower() in ob.name.lower()]


def source_armature(context, name=""):
    """The armature to retarget from: the object named ``name``, else the one selected armature other than the
    active one. AdjustError (one line) when there is none or more than one."""
    if name:
        return batch.armature_named(context, name, "Source")
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

    source: StringProperty(name="Source", search=_armature_names, options={'SKIP_SAVE'},
                           description="Armature whose motion to retarget (default: the selected armature "
                                       "other than the active one)")
    frame_start: IntProperty(name="Start", description="First frame (default: the source action's first)",
                             options={'SKIP_SAVE'})
    frame_end: IntProperty(name="End", description="Last frame (default: the source action's last)",
                           options={'SKIP_SAVE'})
    contacts: EnumProperty(
        name="Contacts",
        items=(('GROUND', "Ground", "Planted feet rest on the floor and do not slide"),
               ('OBJECT', "Object", "Hands and feet touching the contact object are held on it")),
        options={'ENUM_FLAG', 'SKIP_SAVE'},
        default={'GROUND'},
        description="What hands and feet may touch (one or both)",
    )
    contact_object: StringProperty(name="Contact Object", search=_object_names, options={'SKIP_SAVE'},
                                   description="Object whose contacts are kept (for Object contacts; several: "
                                               "names separated by commas)")
    exact: BoolProperty(name="Exact Contacts", default=True, options={'SKIP_SAVE'},
                        description="Hands on the object go to the source's own positions on it, instead of "
                                    "the source's scaled by the legs' ratio (soles always rest on the floor)")
    new_action: StringProperty(name="New Action", options={'SKIP_SAVE'},
                               description="Name of the new action (default: <source action>_<target>)")
    root_motion: EnumProperty(
        name="Root Motion",
        items=(('HIPS', "Hips", "The travel stays on the hips, as captured"),
               ('BONE', "Root Bone", "The horizontal travel and turn go onto the root bone above the hips"),
               ('OBJECT', "Object", "The horizontal travel and turn go onto the armature object's keys"),
               ('IN_PLACE', "In Place", "The horizontal travel and turn are removed")),
        default='HIPS', options={'SKIP_SAVE'},
        description="Where the body's travel goes (planted feet hold in the world the root and the pose build)")
    root_bone: StringProperty(name="Root Bone", options={'SKIP_SAVE'},
                              description="With Root Bone: the bone above the hips, created at the floor when the "
                                          "armature has none of this name (default: the topmost bone above them)")
    root_smoothing: FloatProperty(name="Root Smoothing", default=DEFAULT_SMOOTHING, min=0.0, soft_max=3.0,
                                  unit='TIME_ABSOLUTE', options={'SKIP_SAVE'},
                                  description="Seconds the root's path and heading are smoothed over (a walking "
                                              "stride): it travels steadily, the hips keeping their sway relative "
                                              "to it; 0: the root follows the hips exactly")

    def execute(self, context):
        props = self.properties
        return self.run_and_report(context, lambda progress: retarget.retarget(
            context, source_armature(context, self.source), context.active_object,
            self.frame_start if props.is_property_set("frame_start") else None,
            self.frame_end if props.is_property_set("frame_end") else None,
            contacts=contact_list(self.contacts, self.contact_object), exact=self.exact,
            new_action=self.new_action or None, progress=progress,
            root_motion=self.root_motion.lower().replace("_", "-"), root_bone=self.root_bone or None,
            root_smoothing=None if self.root_motion == 'HIPS' else self.root_smoothing))

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in ("source", "frame_start", "frame_end", "contacts", "contact_object", "exact", "new_action",
                     "root_motion", "root_bone", "root_smoothing"):
            row = layout.row()
            row.prop(self, name)
            row.enabled = ((name != "contact_object" or 'OBJECT' in self.contacts)
                           and (name != "root_bone" or self.root_motion == 'BONE')
                           and (name != "root_smoothing" or self.root_motion != 'HIPS'))


class FULLBODY_ADJUST_OT_mirror_pose(ArmatureOperator, bpy.types.Operator):
    """Mirror the armature's pose across the character's own sagittal plane, left and right swapped through its \
bone map"""
    bl_idname = "fullbody_adjust.mirror_pose"
    bl_label = "Mirror Pose"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        count = self.run(context, lambda: mirror_armature_pose(context.active_object))
        if count is None:
            return {'CANCELLED'}
        self.report({'INFO'}, f"Mirrored the pose of {count} bones")
        return {'FINISHED'}


classes = (
    FULLBODY_ADJUST_OT_map_bones,
    FULLBODY_ADJUST_OT_create_targets,
    FULLBODY_ADJUST_OT_adjust_pose,
    FULLBODY_ADJUST_OT_adjust_frames,
    FULLBODY_ADJUST_OT_key_pose,
    FULLBODY_ADJUST_OT_retarget,
    FULLBODY_ADJUST_OT_mirror_pose,
)

register, unregister = bpy.utils.register_classes_factory(classes)
