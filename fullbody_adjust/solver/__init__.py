"""The solver core: the paper's full-body adjustment (Algorithm 1 over many frames at once), FABRIK chains with
the paper's obstacle response and joint limits, and motion retargeting's pure part (`solver.retarget`).

Pure Python + numpy (no bpy, no mathutils), so it runs and is tested outside Blender. What the product calls is
exported here; the parts (chains, limits, geometry) are imported from their modules.
"""

from .fullbody.adjust import adjust_frames, adjust_pose
from .fullbody.settings import UNCONSTRAINED, AdjustBatchResult, AdjustResult, AdjustSettings
from .body.model import BodyModel
from .limits.human import default_limits
from .chain.settings import ChainSettings
from .errors import SolverInputError
from .obstacles.boxes import Boxes, penetrations

__all__ = [
    "adjust_frames", "adjust_pose", "UNCONSTRAINED", "AdjustBatchResult", "AdjustResult", "AdjustSettings",
    "BodyModel", "default_limits", "ChainSettings", "SolverInputError", "Boxes", "penetrations",
]
