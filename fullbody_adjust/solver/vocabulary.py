"""The names every layer shares, defined once: the body model's groups, the effectors and their default
priorities, the sub-base variants, and Blender's rotation modes. Pure data: the solver, the bridge, the settings
and the command line all import them from here."""

# Body-model groups (the paper's five IK groups joined at the chest and the pelvis, plus hands, feet and head).
GROUPS = ("root", "trunk", "arm.L", "arm.R", "hand.L", "hand.R", "leg.L", "leg.R", "foot.L", "foot.R", "head")
REQUIRED_GROUPS = GROUPS[:-1]
CHAIN_GROUPS = ("trunk", "arm.L", "arm.R", "leg.L", "leg.R", "head")
SINGLE_BONE_GROUPS = ("root", "hand.L", "hand.R", "foot.L", "foot.R")

# End effectors: the wrists and ankles (heads of the hand and foot bones) and, optionally, the head.
EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R", "head")
LIMB_EFFECTORS = EFFECTORS[:4]  # hands and feet: what a retarget holds

# Ankles highest, then wrists, then the head (paper §5.2.2: ankle tasks win by default).
DEFAULT_PRIORITY = {"foot.L": 3, "foot.R": 3, "hand.L": 2, "hand.R": 2, "head": 1}

# How the groups meeting at a sub-base settle conflicting targets (the solver's names; the settings and the
# command line show them upper-case): paper variant 2, variant 1 (eq. 4), and plain FABRIK's centroid.
VARIANTS = ("priority", "weighted", "fabrik")
DEFAULT_VARIANT = "priority"

EULER_ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
# The pose bone property that holds the rotation of each rotation mode.
ROTATION_PROPERTY = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle",
                     **{order: "rotation_euler" for order in EULER_ORDERS}}
