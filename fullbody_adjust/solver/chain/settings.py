"""Settings, results, statuses and iteration constants shared by the chain solver (chain/fabrik.py, chain/model.py and its parts)."""

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import any_set, norm

STATUSES = ("reached", "unreachable", "blocked", "limited", "max_iterations")

# Segments shorter than this (scene units) are rejected: their direction is meaningless.
MIN_SEGMENT_LENGTH = 1e-12
# A joint closer than this fraction of the segment length to its anchor has no usable direction toward it:
# the segment keeps its previous direction instead (coincident joints never produce NaN).
_COINCIDENT = 1e-12
# An iteration that moves the end effector less than tolerance * _STALL has stalled.
_STALL = 1e-3
# With limits or obstacles FABRIK is no longer a descent method: it can creep away from the target or cycle (the
# forward pass proposes poses the constrained backward pass cannot keep), and near the edge of its reach it creeps
# even without them. A problem also stops when, for _PATIENCE iterations, its best iterate has neither lost a
# penetration nor cut its residual's excess over the tolerance by _PROGRESS of that excess (and at least by
# tolerance * _STALL): creeping at that pace could not reach the tolerance within the cap, and what it would still
# gain there is a small share of its residual. A problem with limits or obstacles returns its best iterate (fewest
# penetrations, then smallest residual; every iterate ends on a backward pass, so each one satisfies the limits);
# one without returns its last.
_PATIENCE = 20
_PROGRESS = 0.01
# Every _WINDOW iterations (the first window from the first iterate) a problem without penetrations also stops when
# its best residual, shrinking for the rest of the cap at the rate it shrank over that window, would still miss the
# tolerance and gain less than _GAIN of itself (Iteration._hopeless): a limited chain creeping at the edge of its
# reach ends at the cap short of the target anyway (bench/interactive.py's drag: 200 iterations from 0.96 to 0.49
# mm). A window without any gain is left to _PATIENCE.
_WINDOW = 10
_GAIN = 0.75
# A stall with no limit or obstacle in play is a symmetric fixed point of FABRIK: a straight chain whose
# target lies on its own line (every direction toward the old joints is along the line, or undefined and
# falling back to the previous one). Up to _NUDGES times such a chain gets its interior joints pushed
# sideways by _NUDGE of their segment length (first perpendicular to base->target, then perpendicular to
# both) and iterates on; the next passes restore the segment lengths.
_NUDGES = 2
_NUDGE = 0.05


@dataclass(frozen=True)
class ChainSettings:
    """tolerance: residual (scene units) at which the target counts as met; max_iterations: iteration cap;
    margin: the paper's Δd, clearance added around an obstacle when a joint is pushed out of it."""

    tolerance: float = 1e-5
    max_iterations: int = 200
    margin: float = 0.01

    def __post_init__(self):
        if not (isinstance(self.tolerance, (int, float)) and math.isfinite(self.tolerance) and self.tolerance > 0):
            raise SolverInputError("tolerance must be a finite number > 0")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, (int, np.integer)) \
                or self.max_iterations < 1:
            raise SolverInputError("max_iterations must be an integer >= 1")
        if not (isinstance(self.margin, (int, float)) and math.isfinite(self.margin) and self.margin >= 0):
            raise SolverInputError("margin must be a finite number >= 0")


@dataclass
class ChainResult:
    positions: np.ndarray  # (n,3)
    iterations: int
    residual: float  # distance end effector -> target
    reachable: bool  # the target lies within the chain's reach (ignoring limits and obstacles)
    status: str  # one of STATUSES
    reason: str  # a human-readable explanation of the status


@dataclass
class ChainBatchResult:
    positions: np.ndarray  # (B,n,3)
    iterations: np.ndarray  # (B,) int
    residual: np.ndarray  # (B,)
    reachable: np.ndarray  # (B,) bool
    status: np.ndarray  # (B,) str
    reason: np.ndarray  # (B,) str

    def __len__(self):
        return self.positions.shape[0]

    def __getitem__(self, i):
        return ChainResult(self.positions[i].copy(), int(self.iterations[i]), float(self.residual[i]),
                           bool(self.reachable[i]), str(self.status[i]), str(self.reason[i]))


def _segment_lengths(p):
    """(..., n, 3) -> (..., n-1); raises for a zero-length segment."""
    seg = p[..., 1:, :] - p[..., :-1, :]
    lengths = norm(seg)
    short = lengths <= MIN_SEGMENT_LENGTH
    if any_set(short):
        raise SolverInputError(f"segment {int(np.nonzero(short)[-1][0])} has zero length")
    return lengths


def _reach_bounds(lengths):
    """(total reach, inner radius): targets closer to the base than the inner radius are out of reach too
    (a segment longer than all others together cannot fold back onto the base). Summed left to right, as
    the plain path does."""
    total = lengths[..., 0].copy()
    for i in range(1, lengths.shape[-1]):
        total = total + lengths[..., i]
    inner = np.maximum(2.0 * lengths.max(axis=-1) - total, 0.0)
    return total, inner


def _unreachable_reason(dist, total, inner):
    if dist > total:
        return f"target is {dist - total:.6g} beyond the chain's reach {total:.6g}: stretched toward it"
    return f"target is closer to the base ({dist:.6g}) than the chain can fold ({inner:.6g})"


def _final_status(reached, reachable, dist, total, inner, stalled, iterations, obstacle_active, limit_binding):
    """Status of a problem without penetrations (those are settled by the caller)."""
    if dist > total:  # the reachability test decides, even if the stretched chain ends within tolerance
        return "unreachable", _unreachable_reason(dist, total, inner)
    if reached:
        return "reached", f"reached in {iterations} iterations"
    if not reachable:
        return "unreachable", _unreachable_reason(dist, total, inner)
    how = f"stalled after {iterations} iterations" if stalled else f"iteration cap {iterations} reached"
    if obstacle_active:
        return "blocked", f"an obstacle kept the chain from the target ({how})"
    if limit_binding:
        return "limited", f"joint limits kept the chain from the target ({how})"
    return "max_iterations", how



def statuses(per_problem, obstacles, inside, crossing):
    """(status, reason) arrays of str of a batch: _final_status of each problem's arguments (per_problem), with the
    obstacles' notes (ObstacleResponse or None; inside, crossing: each problem's penetration counts)."""
    status, reason = [], []
    for j, args in enumerate(per_problem):
        st, why = _final_status(*args)
        if obstacles is not None:
            notes = []
            if inside[j] or crossing[j]:
                notes.append(f"could not avoid obstacles: {inside[j]} joints inside, {crossing[j]} segments crossing")
            if np.count_nonzero(obstacles.ignore_end[j]):
                notes.append("target inside obstacle")
            if np.count_nonzero(obstacles.ignore_base[j]):
                notes.append("base inside obstacle")
            if notes:
                st, why = "blocked", "; ".join(notes + [why])
        status.append(st)
        reason.append(why)
    return np.array(status, dtype=object).astype(str), np.array(reason, dtype=object).astype(str)
