"""The solver core: FABRIK chains and trees with the paper's priorities, obstacle response and joint limits.

Pure Python + numpy (no bpy, no mathutils), so it runs and is tested outside Blender.
"""

from .chain import STATUSES, ChainBatchResult, ChainResult, ChainSettings, solve_chain, solve_chain_batch
from .errors import SolverInputError
from .geometry import normalize, rotate_about_axis, swing_rotation
from .limits import CONE, FREE, HINGE, JointLimits, carry_axis, hinge_axis_from_bend
from .obstacles import Boxes, as_boxes, penetrations, points_inside, segments_cross
from .tree import STRATEGIES, Effector, TreeResult, solve_tree

__all__ = [
    "STATUSES", "ChainBatchResult", "ChainResult", "ChainSettings", "solve_chain", "solve_chain_batch",
    "SolverInputError",
    "normalize", "rotate_about_axis", "swing_rotation",
    "CONE", "FREE", "HINGE", "JointLimits", "carry_axis", "hinge_axis_from_bend",
    "Boxes", "as_boxes", "penetrations", "points_inside", "segments_cross",
    "STRATEGIES", "Effector", "TreeResult", "solve_tree",
]
