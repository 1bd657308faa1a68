# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: thin wrappers around bridge.adjustment. Each catches the bridge's AdjustError and reports it as
one line, so a bad input never shows a traceback and changes nothing."""

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty

from .bridge import adjustment, live, mapping
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
    """The run's summary: a WARNING naming what was missed when a target within reach was missed or a bone ends
    inside an obstacle (as the command line's exit code 1), else INFO."""
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
        created = self.run(context, lambda: adjustment.create_targets(context, context.active_object,
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
        outcome = self.run(context, lambda: adjustment.adjust_pose(context, context.active_object,
                                                                    self.solver_options()))
        if outcome is None:
            return {'CANCELLED'}
        report_outcome(self, outcome)
        return {'FINISHED'}


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
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            outcome = self.run(context, lambda: adjustment.adjust_frames(
                context, context.active_object, start, end, self.solver_options(new_action=self.new_action or None),
                progress=lambda stage, fraction: wm.progress_update(int(100 * fraction))))
        finally:
            wm.progress_end()
        if outcome is None:
            return {'CANCELLED'}
        report_outcome(self, outcome)
        return {'FINISHED'}

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


classes = (
    FULLBODY_ADJUST_OT_map_bones,
    FULLBODY_ADJUST_OT_create_targets,
    FULLBODY_ADJUST_OT_adjust_pose,
    FULLBODY_ADJUST_OT_adjust_frames,
    FULLBODY_ADJUST_OT_key_pose,
)

register, unregister = bpy.utils.register_classes_factory(classes)
