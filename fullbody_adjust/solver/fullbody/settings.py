"""Settings and results of the full-body adjustment (fullbody/adjust.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..body.model import LIMB_NAMES
from ..limits.human import HumanLimits
from ..chain.fabrik import ChainSettings
from ..errors import SolverInputError
from ..obstacles.surface import LimbSurface
from ..vocabulary import DEFAULT_VARIANT, VARIANTS

UNCONSTRAINED = "unconstrained"  # status of an effector without a target on that frame


@dataclass(frozen=True)
class AdjustSettings:
    """chain: per-chain FABRIK settings (tolerance is also the "target met" threshold);
    variant: how the SC is placed when the arms' reach balls do not intersect: 'weighted' (paper variant 1,
        eq. 4: priority-weighted mean of the arms' proposals), 'priority' (variant 2: the highest priority arm
        is served, lower ones best effort), 'fabrik' (unweighted mean, plain FABRIK's centroid);
    feet_first: ankle tasks have the highest priority at the root (paper §5.2.2); False: the root uses
        `variant` with the tasks' own priorities;
    use_limits: apply the default human joint limits (human.HumanLimits) when no limits are passed;
    reach_margin: a sub-base that must move is placed so the limbs end this fraction short of full stretch:
        FABRIK converges slowly on a nearly straight chain (200 iterations leave ~1e-4 of a 0.3 m chain at
        0.1 % short; 1 % short converges in ~90), and a slightly bent elbow looks more natural anyway;
    sub_base_passes: the SC is placed with the arm bases' current offsets; when the chest turns, the bases turn
        with it, so up to this many passes re-place the SC with the turned offsets;
    limit_passes: a limb held short by its joint limits (a clavicle that may swing only so far, a bent knee)
        reaches less far than its length: the frame is solved again up to this many times with that limb's
        reach cut to what it achieved, so the sub-base moves far enough (kept if more tasks are met, or as many
        with smaller residuals);
    help_held_limbs: a limb whose target lies within its length but whose limits hold it short does not serve
        alone (rule (i) means a limb that can reach): its sub-base moves to help, as for a target beyond its
        length. False reads rule (i) by length alone: the sub-base then stays and the task is 'limited'.
        Either way a limb that reaches its target alone leaves the SC and root exactly where they were.
    clearance: per limb (a mapping or (limb, distance) pairs; stored as sorted pairs), the distance its centre
        line keeps from every obstacle box: its surface's radius plus the margin the user wants between surface
        and box (bridge/reading/limb_thickness.py measures the radius from the meshes the armature deforms). The limb's
        chain solve tests its joints and segments against the boxes grown by it (obstacles.grown_clear_of; a box
        its target or base lies nearer than that is grown less). A limb not listed (the default: every limb)
        keeps the paper's behaviour: its joints and segments out of the boxes themselves, `chain.margin` only
        the Δd of the push out.
    surface: per limb (a mapping or (limb, LimbSurface) pairs; stored as sorted pairs), its mesh's surface as
        points riding on its segments (obstacles/surface.py): where the limb reached its target with some of them in a
        box, the poses that swivel round the target are tried and the one whose points lie least deep in the boxes
        (grown by `chain.margin`) is kept (obstacles/easing.py). A limb not listed keeps its clearance's capsule alone."""

    chain: ChainSettings = ChainSettings()
    variant: str = DEFAULT_VARIANT
    feet_first: bool = True
    use_limits: bool = True
    human_limits: HumanLimits = HumanLimits()
    reach_margin: float = 0.01
    sub_base_passes: int = 4
    limit_passes: int = 2
    help_held_limbs: bool = True
    clearance: tuple = ()
    surface: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "clearance", _clearance_pairs(self.clearance))
        object.__setattr__(self, "surface", _surface_pairs(self.surface))
        if not isinstance(self.help_held_limbs, bool):
            raise SolverInputError("help_held_limbs must be a bool")
        if not isinstance(self.chain, ChainSettings):
            raise SolverInputError("chain must be a ChainSettings")
        if self.variant not in VARIANTS:
            raise SolverInputError(f"unknown variant {self.variant!r} (use {', '.join(VARIANTS)})")
        if not (isinstance(self.reach_margin, (int, float)) and 0.0 <= self.reach_margin < 0.5):
            raise SolverInputError("reach_margin must be a number in [0, 0.5)")
        for name, low in (("sub_base_passes", 1), ("limit_passes", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise SolverInputError(f"{name} must be an integer >= {low}")

    def surface_of(self, limb):
        """The LimbSurface of `limb` (None: none)."""
        return dict(self.surface).get(limb)

    def clearance_of(self, limb):
        """The clearance of `limb` (0.0: none, the paper's behaviour)."""
        for name, distance in self.clearance:
            if name == limb:
                return distance
        return 0.0


def _limb_pairs(value, what, values, kind, fits):
    """``value`` (a mapping or pairs) as sorted (limb, value) pairs, each limb known and its value ``fits``
    (else one line: '<what> of <limb> must be <kind>'; not a mapping: '<what> must map limb names to
    <values>')."""
    try:
        pairs = dict(value.items() if hasattr(value, "items") else value)
    except (TypeError, ValueError):
        raise SolverInputError(f"{what} must map limb names to {values}") from None
    for limb, item in pairs.items():
        if limb not in LIMB_NAMES:
            raise SolverInputError(f"{what} for unknown limb {limb!r} (use {', '.join(LIMB_NAMES)})")
        if not fits(item):
            raise SolverInputError(f"{what} of {limb} must be {kind}")
    return tuple(sorted(pairs.items(), key=lambda pair: pair[0]))


def _distance(x):
    return (not isinstance(x, bool) and isinstance(x, (int, float, np.floating, np.integer)) and math.isfinite(x)
            and x >= 0)


def _clearance_pairs(clearance):
    """AdjustSettings.clearance as sorted (limb, float) pairs, checked."""
    pairs = _limb_pairs(clearance, "clearance", "distances", "a finite number >= 0", _distance)
    return tuple((limb, float(distance)) for limb, distance in pairs)


def _surface_pairs(surface):
    """AdjustSettings.surface as sorted (limb, LimbSurface) pairs, checked."""
    return _limb_pairs(surface, "surface", "LimbSurface", "a LimbSurface", lambda x: isinstance(x, LimbSurface))


@dataclass
class AdjustResult:
    """One adjusted pose. rotations: world rotation deltas (new world rotation = R @ old) per bone."""

    heads: np.ndarray  # (J,3)
    tails: np.ndarray  # (J,3)
    rotations: np.ndarray  # (J,3,3)
    effectors: tuple
    residuals: np.ndarray  # (E,) NaN where unconstrained
    status: np.ndarray  # (E,) 'reached' | 'unreachable' | 'blocked' | 'limited' | 'max_iterations' | 'unconstrained'
    reasons: np.ndarray  # (E,) human-readable
    iterations: int
    sc_displacement: float
    root_displacement: float


@dataclass
class AdjustBatchResult:
    heads: np.ndarray  # (F,J,3)
    tails: np.ndarray  # (F,J,3)
    rotations: np.ndarray  # (F,J,3,3)
    effectors: tuple  # (E,) names
    residuals: np.ndarray  # (F,E)
    status: np.ndarray  # (F,E) str
    reasons: np.ndarray  # (F,E) str
    iterations: np.ndarray  # (F,) chain iterations spent on the frame
    sc_displacement: np.ndarray  # (F,)
    root_displacement: np.ndarray  # (F,)

    def __len__(self):
        return self.heads.shape[0]

    def __getitem__(self, i) -> AdjustResult:
        return AdjustResult(self.heads[i].copy(), self.tails[i].copy(), self.rotations[i].copy(), self.effectors,
                            self.residuals[i].copy(), self.status[i].copy(), self.reasons[i].copy(),
                            int(self.iterations[i]), float(self.sc_displacement[i]),
                            float(self.root_displacement[i]))
