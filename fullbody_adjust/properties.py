# SPDX-License-Identifier: GPL-3.0-or-later
"""Settings stored on the armature object as `obj.fullbody_adjust`.

They live on every Object (the contract is `obj.fullbody_adjust`) but only mean something on armatures.
"""

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from .bridge import live
from .solver.vocabulary import DEFAULT_PRIORITY, DEFAULT_VARIANT, EFFECTORS, VARIANTS

_EFFECTOR_LABELS = {
    'hand.L': ("Left Hand", "Left wrist (head of the left hand bone)"),
    'hand.R': ("Right Hand", "Right wrist (head of the right hand bone)"),
    'foot.L': ("Left Foot", "Left ankle (head of the left foot bone)"),
    'foot.R': ("Right Foot", "Right ankle (head of the right foot bone)"),
    'head': ("Head", "Head bone"),
}
EFFECTOR_ITEMS = tuple((effector, *_EFFECTOR_LABELS[effector]) for effector in EFFECTORS)

# How the groups meeting at the chest and pelvis settle conflicting targets; the adjust operators offer the same.
_VARIANT_LABELS = {
    "fabrik": ("Plain FABRIK", "Unweighted centroid of the groups' proposals (the baseline)"),
    "weighted": ("Weighted", "Priority-weighted mean of the groups' proposals (paper variant 1)"),
    "priority": ("Priority", "Groups solved from lowest to highest priority, so the highest priority target is "
                             "met whenever it is reachable (paper variant 2)"),
}
VARIANT_ITEMS = tuple((variant.upper(), *_VARIANT_LABELS[variant]) for variant in ("fabrik", "weighted", "priority"))
assert set(_VARIANT_LABELS) == set(VARIANTS)


def _live_toggled(settings, context):
    live.live_toggled(settings.id_data, context)


def _solve_setting_changed(settings, context):
    live.settings_changed(settings.id_data)


def _is_not_owner(slot, obj):
    # A character cannot chase itself.
    return obj is not slot.id_data


def _object_of_slot(name, description):
    """A target slot's Object pointer (any object but the armature that owns the slot)."""
    return PointerProperty(name=name, description=description, type=bpy.types.Object, poll=_is_not_owner,
                           update=_solve_setting_changed)


def _distance(name, description, **keywords):
    """A length in scene units that the solve reads (Live solves again when it changes)."""
    return FloatProperty(name=name, description=description, subtype='DISTANCE', unit='LENGTH',
                         update=_solve_setting_changed, **keywords)


class FULLBODY_ADJUST_PG_target(bpy.types.PropertyGroup):
    effector: EnumProperty(name="Effector", description="The body part that reaches for the target",
                           items=EFFECTOR_ITEMS, default='hand.L')
    target: _object_of_slot("Target", "Object (normally an empty) whose location the effector reaches for")
    priority: IntProperty(name="Priority", default=DEFAULT_PRIORITY['hand.L'], min=0, soft_max=10,
                          description="When targets conflict, the higher priority is met first (by default feet 3, "
                                      "hands 2, head 1)", update=_solve_setting_changed)
    enabled: BoolProperty(name="Enabled", description="Use this target when adjusting", default=True,
                          update=_solve_setting_changed)
    use_rotation: BoolProperty(name="Rotation", default=False,
                               description="The hand or foot takes the target's world orientation (as far as the "
                                           "wrist's or ankle's limits allow); off: it keeps its own",
                               update=_solve_setting_changed)
    pole: _object_of_slot("Pole", "Object the elbow or knee points toward: the limb bends in the plane of the "
                                  "shoulder or hip, the target and the pole. Empty: the limb keeps its own bend plane")


class FULLBODY_ADJUST_PG_bone_map_item(bpy.types.PropertyGroup):
    group: StringProperty(name="Group", description="Body model group: root, trunk, arm.L, arm.R, hand.L, hand.R, "
                                                    "leg.L, leg.R, foot.L, foot.R or head")
    bone: StringProperty(name="Bone", description="Name of the rig bone in that group (items of one group are in "
                                                  "chain order, parent first)")


class FULLBODY_ADJUST_PG_settings(bpy.types.PropertyGroup):
    targets: CollectionProperty(name="Targets", type=FULLBODY_ADJUST_PG_target)
    active_target_index: IntProperty(name="Active Target", description="Target slot selected in the list")
    obstacles: PointerProperty(name="Obstacles", type=bpy.types.Collection,
                               description="Collection whose meshes are obstacles. Empty: every visible mesh that "
                                           "this armature neither deforms nor parents", update=_solve_setting_changed)
    bone_map: CollectionProperty(name="Bone Map", description="Which rig bones form each body model group",
                                 type=FULLBODY_ADJUST_PG_bone_map_item)
    active_bone_map_index: IntProperty(name="Active Bone Map Item", description="Bone map row selected in the list")
    variant: EnumProperty(name="Variant", items=VARIANT_ITEMS, default=DEFAULT_VARIANT.upper(),
                          description="How the groups meeting at the chest and at the pelvis settle conflicting "
                                      "targets", update=_solve_setting_changed)
    margin: _distance("Margin", "Clearance kept between a skinned limb's surface and obstacle boxes (without a "
                                "mesh: the paper's Δd, how far past a box a joint is pushed)",
                      default=0.01, min=0.0, soft_max=0.5)
    tolerance: _distance("Tolerance", "A target counts as reached within this distance",
                         default=1e-5, min=1e-9, soft_max=0.01, precision=6)
    max_iterations: IntProperty(name="Max Iterations", description="Iteration limit per solve",
                                default=200, min=1, soft_max=1000, update=_solve_setting_changed)
    use_joint_limits: BoolProperty(name="Joint Limits", default=True,
                                   description="Respect the rig's own IK locks and limits and Local Space Limit "
                                               "Rotation constraints on the mapped bones; elbows and knees that set "
                                               "none never bend backwards", update=_solve_setting_changed)
    keep_hand_orientation: BoolProperty(name="Keep Hand Orientation", default=True,
                                        description="Hands keep their world orientation while the arms move",
                                        update=_solve_setting_changed)
    live: BoolProperty(name="Live Adjust", default=False, update=_live_toggled,
                       description="Re-solve and show the pose (without keys) whenever a target, pole or obstacle "
                                   "moves, a setting changes or the frame changes; Key Pose keys what is shown, "
                                   "turning it off returns to the keyed pose")


classes = (
    FULLBODY_ADJUST_PG_target,
    FULLBODY_ADJUST_PG_bone_map_item,
    FULLBODY_ADJUST_PG_settings,
)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.fullbody_adjust = PointerProperty(type=FULLBODY_ADJUST_PG_settings)


def unregister():
    del bpy.types.Object.fullbody_adjust
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
