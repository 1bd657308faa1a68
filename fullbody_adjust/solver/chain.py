"""FABRIK on one chain (Aristidou & Lasenby 2011) with the paper's obstacle response (§4.1) and joint limits.

Two implementations of the same iteration:
- a lean plain-float path (Python floats, math.sqrt) for the common single problem without limits or
  obstacles: numpy's per-call overhead dominates on a 4-joint arm, so plain floats are several times faster;
- a batch-first numpy path (B, n, 3) for limits, obstacles and many problems at once (e.g. every frame of a
  clip). Each problem stops iterating when it converges (its row leaves the active set), so a problem's
  result does not depend on what else is in the batch.
Both do the same floating-point operations in the same order, so they agree to rounding.

One iteration = a forward pass (effector pinned to the target, joints placed toward the base) then a
backward pass (base pinned, joints placed toward the effector). A solve always ends on a backward pass, which
is where joint limits are enforced: there the parent segment is already final, so the final pose satisfies
the limits exactly. The forward pass applies the limits too, in reverse, only to steer its proposal (as
FABRIK 2011 does in both passes).

Two-segment finish (limited chains, beyond FABRIK): in the backward pass, once joint n-3 is placed, the last
two segments are placed analytically where a swivel position of joint n-2 meets the target with every limit
and obstacle satisfied (ChainModel._two_bone_finish); otherwise the FABRIK step stands. It ends the slow
creep near full stretch, and lets a hinged limb (elbow, knee) turn its bend plane within its twist range.

Obstacles (paper §4.1, boxes): in both passes a joint that lands inside a box, or whose segment crosses one,
is moved (ChainModel._avoid). A reachable target must be outside the boxes for a collision-free result; a
target inside a box is a defined result (status 'blocked', reason 'target inside obstacle').

Statuses: 'reached'; 'unreachable' (beyond the reach, or closer to the base than the chain can fold);
'blocked' (penetrations left, target or base inside a box, or an obstacle held the chain); 'limited' (joint
limits held it); 'max_iterations' (iteration cap, or an unconstrained stall).
"""

import math
from dataclasses import dataclass

import numpy as np

from .errors import SolverInputError
from .geometry import any_perpendicular, cross, dot, norm
from .limits import CONE, FREE, HINGE, JointLimits, apply_cone, apply_hinge, carry_axis
from .obstacles import as_boxes, points_inside, segments_cross

STATUSES = ("reached", "unreachable", "blocked", "limited", "max_iterations")

# Segments shorter than this (scene units) are rejected: their direction is meaningless.
MIN_SEGMENT_LENGTH = 1e-12
# A joint closer than this fraction of the segment length to its anchor has no usable direction toward it:
# the segment keeps its previous direction instead (coincident joints never produce NaN).
_COINCIDENT = 1e-12
# An iteration that moves the end effector less than tolerance * _STALL has stalled.
_STALL = 1e-3
# With limits or obstacles FABRIK is no longer a descent method: it can creep away from the target or cycle
# (the forward pass proposes poses the constrained backward pass cannot keep). Such a problem also stops when
# its best residual has not improved by tolerance * _STALL for _PATIENCE iterations, and returns its best
# iterate (fewest penetrations, then smallest residual; every iterate ends on a backward pass, so each one
# satisfies the limits).
_PATIENCE = 20
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


# ----------------------------------------------------------------------------------------------------------
# Public entry points


def solve_chain(positions, target, *, settings=ChainSettings(), limits=None, obstacles=None,
                parent_direction=None):
    """Solve one chain; joint 0 is the fixed base, joint n-1 the end effector. obstacles: Boxes or an array
    of box corners. See ChainResult."""
    if not isinstance(settings, ChainSettings):
        raise SolverInputError("settings must be a ChainSettings")
    obstacles = as_boxes(obstacles)
    if limits is not None and not isinstance(limits, JointLimits):
        raise SolverInputError("limits must be a JointLimits")
    limited = limits is not None and limits.any_active
    if not limited and (obstacles is None or len(obstacles) == 0):
        return _solve_plain(positions, target, settings)
    p = _as_points(positions, "positions")
    t = _as_vector(target, "target")
    pd = None if parent_direction is None else _as_vector(parent_direction, "parent_direction")[None]
    if obstacles is not None and obstacles.batched and obstacles.mins.shape[0] != 1:
        raise SolverInputError("per-problem boxes for a single chain need a batch axis of 1")
    if limits is not None and limits.hinge_axis.ndim == 3 and limits.hinge_axis.shape[0] != 1:
        raise SolverInputError("per-problem hinge axes for a single chain need a batch axis of 1")
    if limits is not None and limits.hinge_reference is not None and limits.hinge_reference.ndim == 3 \
            and limits.hinge_reference.shape[0] != 1:
        raise SolverInputError("per-problem hinge references for a single chain need a batch axis of 1")
    return solve_chain_batch(p[None], t[None], settings=settings, limits=limits, obstacles=obstacles,
                             parent_directions=pd)[0]


def solve_chain_batch(positions, targets, *, settings=ChainSettings(), limits=None, obstacles=None,
                      parent_directions=None):
    """Solve B independent chains of n joints: positions (B,n,3), targets (B,3); limits shared (hinge axes may
    be per problem), obstacles shared (K,3) or per problem (B,K,3), parent_directions (B,3) for joint 0's
    limit. Each problem stops iterating when it converges, so row i equals solve_chain on problem i."""
    if not isinstance(settings, ChainSettings):
        raise SolverInputError("settings must be a ChainSettings")
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3:
        raise SolverInputError(f"positions must have shape (B,n,3), got {p.shape}")
    if p.shape[1] < 2:
        raise SolverInputError("a chain needs at least 2 joints")
    if not np.all(np.isfinite(p)):
        raise SolverInputError("positions have NaN/inf")
    t = np.asarray(targets, dtype=np.float64)
    if t.shape != (p.shape[0], 3):
        raise SolverInputError(f"targets must have shape ({p.shape[0]},3), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise SolverInputError("target has NaN/inf")
    model = ChainModel(p, t, settings, limits, obstacles, parent_directions)
    return model.solve(p)


# ----------------------------------------------------------------------------------------------------------
# Input conversion


def _as_points(positions, name):
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SolverInputError(f"{name} must have shape (n,3), got {p.shape}")
    if p.shape[0] < 2:
        raise SolverInputError("a chain needs at least 2 joints")
    if not np.all(np.isfinite(p)):
        raise SolverInputError(f"{name} have NaN/inf")
    return p


def _as_vector(v, name):
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,):
        raise SolverInputError(f"{name} must have shape (3,), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise SolverInputError(f"{name} has NaN/inf")
    return v


def _segment_lengths(p):
    """(..., n, 3) -> (..., n-1); raises for a zero-length segment."""
    seg = p[..., 1:, :] - p[..., :-1, :]
    lengths = norm(seg)
    short = lengths <= MIN_SEGMENT_LENGTH
    if np.any(short):
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


# ----------------------------------------------------------------------------------------------------------
# Plain-float path (no limits, no obstacles)


def _solve_plain(positions, target, settings):
    if not isinstance(positions, np.ndarray):
        try:
            positions = np.asarray(positions, dtype=np.float64)
        except (TypeError, ValueError) as ex:
            raise SolverInputError(f"positions must be numbers: {ex}") from None
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise SolverInputError(f"positions must have shape (n,3), got {positions.shape}")
    rows = positions.tolist()
    n = len(rows)
    if n < 2:
        raise SolverInputError("a chain needs at least 2 joints")
    try:
        px = [float(r[0]) for r in rows]
        py = [float(r[1]) for r in rows]
        pz = [float(r[2]) for r in rows]
        tl = target.tolist() if isinstance(target, np.ndarray) else list(target)
        if len(tl) != 3:
            raise SolverInputError("target must have shape (3,)")
        tx, ty, tz = float(tl[0]), float(tl[1]), float(tl[2])
    except (TypeError, ValueError) as ex:
        if isinstance(ex, SolverInputError):
            raise
        raise SolverInputError(f"positions and target must be numbers: {ex}") from None
    # One sum tells whether everything is finite (NaN/inf propagate); only an overflow would need the slow look.
    if not math.isfinite(sum(px) + sum(py) + sum(pz)):
        if not all(math.isfinite(v) for v in px + py + pz):
            raise SolverInputError("positions have NaN/inf")
    if not (math.isfinite(tx) and math.isfinite(ty) and math.isfinite(tz)):
        raise SolverInputError("target has NaN/inf")

    sqrt = math.sqrt
    m = n - 1
    lengths = []
    for i in range(m):
        dx, dy, dz = px[i + 1] - px[i], py[i + 1] - py[i], pz[i + 1] - pz[i]
        length = sqrt(dx * dx + dy * dy + dz * dz)
        if length <= MIN_SEGMENT_LENGTH:
            raise SolverInputError(f"segment {i} has zero length")
        lengths.append(length)
    total = lengths[0]
    for i in range(1, m):
        total = total + lengths[i]
    inner = max(2.0 * max(lengths) - total, 0.0)
    bx, by, bz = px[0], py[0], pz[0]
    dx, dy, dz = tx - bx, ty - by, tz - bz
    dist = sqrt(dx * dx + dy * dy + dz * dz)
    tol = settings.tolerance
    last = m

    if dist > total:
        # Out of reach: one backward pass with every segment aimed at the target stretches the chain along
        # the line base -> target.
        ox, oy, oz = px[:], py[:], pz[:]
        for i in range(m):
            dx, dy, dz = tx - px[i], ty - py[i], tz - pz[i]
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i + 1] - ox[i], oy[i + 1] - oy[i], oz[i + 1] - oz[i]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i + 1], py[i + 1], pz[i + 1] = px[i] + dx * s, py[i] + dy * s, pz[i] + dz * s
        dx, dy, dz = px[last] - tx, py[last] - ty, pz[last] - tz
        residual = sqrt(dx * dx + dy * dy + dz * dz)
        return ChainResult(np.array([px, py, pz]).T, 1, residual, False, "unreachable",
                           _unreachable_reason(dist, total, inner))

    dx, dy, dz = px[last] - tx, py[last] - ty, pz[last] - tz
    residual = sqrt(dx * dx + dy * dy + dz * dz)
    iterations = 0
    stalled = False
    max_iterations = settings.max_iterations
    stall = tol * _STALL
    nudges = 0
    while residual > tol and iterations < max_iterations:
        ox, oy, oz = px[:], py[:], pz[:]
        # Forward: pin the effector to the target, place each joint toward its old position.
        px[last], py[last], pz[last] = tx, ty, tz
        for i in range(m - 1, -1, -1):
            ax, ay, az = px[i + 1], py[i + 1], pz[i + 1]
            dx, dy, dz = px[i] - ax, py[i] - ay, pz[i] - az
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i] - ox[i + 1], oy[i] - oy[i + 1], oz[i] - oz[i + 1]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i], py[i], pz[i] = ax + dx * s, ay + dy * s, az + dz * s
        # Backward: pin the base, place each joint toward its forward-pass position.
        px[0], py[0], pz[0] = bx, by, bz
        for i in range(m):
            ax, ay, az = px[i], py[i], pz[i]
            dx, dy, dz = px[i + 1] - ax, py[i + 1] - ay, pz[i + 1] - az
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i + 1] - ox[i], oy[i + 1] - oy[i], oz[i + 1] - oz[i]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i + 1], py[i + 1], pz[i + 1] = ax + dx * s, ay + dy * s, az + dz * s
        iterations += 1
        ex, ey, ez = px[last], py[last], pz[last]
        dx, dy, dz = ex - tx, ey - ty, ez - tz
        residual = sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = ex - ox[last], ey - oy[last], ez - oz[last]
        if residual > tol and sqrt(dx * dx + dy * dy + dz * dz) < stall:
            if nudges < _NUDGES and iterations < max_iterations:
                ux, uy, uz = _nudge_direction(tx - bx, ty - by, tz - bz, px[1] - bx, py[1] - by, pz[1] - bz, nudges)
                for i in range(1, m):
                    k = lengths[i - 1] * _NUDGE
                    px[i], py[i], pz[i] = px[i] + ux * k, py[i] + uy * k, pz[i] + uz * k
                nudges += 1
                continue
            stalled = True
            break
    reachable = dist >= inner
    status, reason = _final_status(residual <= tol, reachable, dist, total, inner, stalled, iterations,
                                   False, False)
    return ChainResult(np.array([px, py, pz]).T, iterations, residual, reachable, status, reason)


def _nudge_direction(vx, vy, vz, fx, fy, fz, k):
    """Unit sideways direction of nudge number k for the line v = base->target (or, for a target at the
    base, the first segment f): geometry.any_perpendicular(v) for k = 0, v x that for k = 1. Plain floats
    written to round exactly like the numpy path."""
    sqrt = math.sqrt
    if not sqrt(vx * vx + vy * vy + vz * vz) > 0.0:
        vx, vy, vz = fx, fy, fz
    n = sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    ax, ay, az = abs(vx), abs(vy), abs(vz)
    ex, ey, ez = (1.0, 0.0, 0.0) if ax <= ay and ax <= az else ((0.0, 1.0, 0.0) if ay <= az else (0.0, 0.0, 1.0))
    px, py, pz = vy * ez - vz * ey, vz * ex - vx * ez, vx * ey - vy * ex
    n = sqrt(px * px + py * py + pz * pz)
    px, py, pz = px / n, py / n, pz / n
    if k == 0:
        return px, py, pz
    qx, qy, qz = vy * pz - vz * py, vz * px - vx * pz, vx * py - vy * px
    n = sqrt(qx * qx + qy * qy + qz * qz)
    return qx / n, qy / n, qz / n


def _nudge_directions(v, first, k):
    """numpy twin of _nudge_direction for rows v (b,3), first (b,3)."""
    zero = ~(norm(v) > 0.0)
    v = np.where(zero[:, None], first, v)
    v = v / norm(v)[:, None]
    p = any_perpendicular(v)
    if k == 0:
        return p
    q = cross(v, p)
    return q / norm(q)[:, None]


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


# ----------------------------------------------------------------------------------------------------------
# numpy path


# Obstacle response candidates (see _avoid for which one is taken).
# The paper's circle (sphere(anchor, D) ∩ sphere(pos_i, dis)): every point is at distance dis from pos_i, so
# "nearest the unconstrained position" does not single one out. We take the point nearest the joint's
# position at the start of the iteration (continuity: the joint does not flip around the box between
# iterations or frames), then the rest of the circle by increasing angle from that point.
_CIRCLE_SAMPLES = 24
_circle_angles = [0.0]
for _k in range(1, _CIRCLE_SAMPLES // 2):
    _circle_angles += [_k * 2 * math.pi / _CIRCLE_SAMPLES, -_k * 2 * math.pi / _CIRCLE_SAMPLES]
_circle_angles.append(math.pi)
_CIRCLE_ANGLES = np.array(_circle_angles)
# Beyond the paper: when the circle does not exist (the box is larger than twice the segment: dis > 2D) or
# none of its points is clear (another box, or the segment still crosses), directions on the whole sphere
# of radius D around the anchor, by increasing angle from the unconstrained direction (the smallest change
# to what FABRIK asked for), azimuths ordered from the reference side.
_SPHERE_POLAR = np.radians([5, 10, 15, 20, 30, 40, 50, 60, 75, 90, 105, 120, 135, 150, 165, 180])
# Two-segment finish (ChainModel._two_bone_finish): swivel angles of the middle joint around the pivot ->
# target line, from FABRIK's proposal outward (0, +d, -d, +2d, ...), and the least hinge twist range that
# leaves an interval of them to pick from (a twist-free hinge fits one swivel angle, never a sample).
_SWIVEL_SAMPLES = 48
_swivel = [0.0]
for _k in range(1, _SWIVEL_SAMPLES // 2):
    _swivel += [_k * 2 * math.pi / _SWIVEL_SAMPLES, -_k * 2 * math.pi / _SWIVEL_SAMPLES]
_swivel.append(math.pi)
_SWIVEL_ANGLES = np.array(_swivel)
_MIN_FINISH_TWIST = math.radians(5)


class ChainModel:
    """Per-solve constant data of B chains and the two FABRIK passes on any subset of them.

    Built from the start positions: segment lengths and directions, limits (per joint), obstacles, and the
    boxes each problem ignores (those containing its target for the end joint and last segment, those
    containing its base for segment 0 — unavoidable, reported in the reason)."""

    def __init__(self, start, targets, settings, limits, obstacles, parent_directions, *,
                 end_is_target=True, base_is_fixed=True):
        """end_is_target / base_is_fixed False (a tree's inner chains, whose ends are sub-bases): no box is
        ignored for the end joint / the base."""
        self.B, self.n = start.shape[0], start.shape[1]
        self.settings = settings
        self.targets = targets
        self.base = start[:, 0].copy()
        self.lengths = _segment_lengths(start)
        self.start_dirs = (start[:, 1:] - start[:, :-1]) / self.lengths[..., None]
        m = self.n - 1

        if limits is not None and not isinstance(limits, JointLimits):
            raise SolverInputError("limits must be a JointLimits")
        if limits is not None and len(limits) != m:
            raise SolverInputError(f"limits cover {len(limits)} joints but the chain has {m} limitable joints")
        self.limits = limits if limits is not None and limits.any_active else None
        self._finishes = False
        if self.limits is not None:
            axes = self.limits.hinge_axis
            if axes.ndim == 3 and axes.shape[0] != self.B:
                raise SolverInputError(f"per-problem hinge axes have batch size {axes.shape[0]}, expected {self.B}")
            self.hinge_axes = np.broadcast_to(axes, (self.B, m, 3))
            # The analytic two-segment finish needs a swivel range to pick from: not a hinge whose plane is fixed.
            self._finishes = self.n >= 3 and (self.limits.kind[m - 1] != HINGE
                                              or self.limits.hinge_twist[m - 1] >= _MIN_FINISH_TWIST)
            # Where each hinge axis is given: its parent direction at the start pose, or the caller's.
            ref = self.limits.hinge_reference
            if ref is None:
                self.hinge_refs = np.concatenate([self.start_dirs[:, :1], self.start_dirs[:, :-1]], axis=1)
            else:
                if ref.ndim == 3 and ref.shape[0] != self.B:
                    raise SolverInputError(
                        f"per-problem hinge references have batch size {ref.shape[0]}, expected {self.B}")
                ref = np.broadcast_to(ref, (self.B, m, 3))
                self.hinge_refs = ref / np.maximum(norm(ref), 1e-300)[..., None]
        self.parent_dirs = None
        if parent_directions is not None:
            pd = np.asarray(parent_directions, dtype=np.float64)
            if pd.shape != (self.B, 3):
                raise SolverInputError(f"parent_directions must have shape ({self.B},3), got {pd.shape}")
            if not np.all(np.isfinite(pd)):
                raise SolverInputError("parent_direction has NaN/inf")
            pn = norm(pd)
            if np.any(pn <= 1e-12):
                raise SolverInputError("parent_direction has zero length")
            self.parent_dirs = pd / pn[:, None]
        if self.limits is not None and self.limits.kind[0] != FREE and self.parent_dirs is None:
            raise SolverInputError("joint 0 has a limit but no parent_direction was given")

        obstacles = as_boxes(obstacles)
        self.boxes = obstacles if obstacles is not None and len(obstacles) > 0 else None
        if self.boxes is not None:
            if self.boxes.batched and self.boxes.mins.shape[0] != self.B:
                raise SolverInputError(
                    f"per-problem boxes have batch size {self.boxes.mins.shape[0]}, expected {self.B}")
            self.ignore_end = points_inside(targets, self.boxes)  # (B,K)
            self.ignore_base = points_inside(self.base, self.boxes)
            if not end_is_target:
                self.ignore_end[:] = False
            if not base_is_fixed:
                self.ignore_base[:] = False
            self.corners = self.boxes.corners()

    # -- limits -----------------------------------------------------------------------------------------------

    def _limit(self, i, rows, parent, dirs, fallback):
        """Apply joint i's limit to unit dirs (b,3) or (b,c,3). Returns (dirs, binding (b,...))."""
        kind = self.limits.kind[i]
        extra = dirs.ndim - 2
        expand = (lambda a: a.reshape(a.shape[:1] + (1,) * extra + a.shape[1:]))
        if kind == CONE:
            return apply_cone(expand(parent), dirs, self.limits.cone_angle[i], expand(fallback))
        axis = self.hinge_axes[rows, i]
        if i > 0:
            axis = carry_axis(axis, self.hinge_refs[rows, i], parent)
        return apply_hinge(expand(parent), dirs, expand(axis), self.limits.hinge_min[i], self.limits.hinge_max[i],
                           expand(fallback), self.limits.hinge_twist[i])

    def _limit_reverse(self, j, rows, child, dirs, fallback):
        """Forward-pass counterpart of joint j's limit (FABRIK 2011 applies limits in both passes): segment j
        is placed, so bend the parent direction dirs (b,3) of segment j-1 until segment j is a valid child of
        it. A cone is symmetric; for a hinge the angle from child to parent is clamped to [-max, -min], about
        the axis carried by the proposed parent direction. Only steers the proposal the backward pass starts
        from: the backward pass enforces the limits exactly."""
        if self.limits.kind[j] == CONE:
            return apply_cone(child, dirs, self.limits.cone_angle[j], fallback)[0]
        axis = carry_axis(self.hinge_axes[rows, j], self.hinge_refs[rows, j], dirs)
        return apply_hinge(child, dirs, axis, -self.limits.hinge_max[j], -self.limits.hinge_min[j], fallback,
                           self.limits.hinge_twist[j])[0]

    # -- obstacles ---------------------------------------------------------------------------------------------

    def _ignored(self, rows, joint, segment):
        """(b,K) boxes ignored for `joint` and (b,K) for `segment` (None: nothing ignored)."""
        last = self.n - 1
        ign_joint = self.ignore_end[rows] if joint == last else None
        ign_seg = None
        if segment == last - 1:
            ign_seg = self.ignore_end[rows]
        if segment == 0:
            ign_seg = self.ignore_base[rows] if ign_seg is None else (ign_seg | self.ignore_base[rows])
        return ign_joint, ign_seg

    def _violations(self, boxes, anchor, points, ign_joint, ign_seg):
        inside = points_inside(points, boxes)
        crossing = segments_cross(anchor, points, boxes)
        if ign_joint is not None:
            inside &= ~ign_joint
        if ign_seg is not None:
            crossing &= ~ign_seg
        return inside, crossing

    def _avoid(self, rows, anchor, cand, lengths, ref, joint, segment, limit_fn):
        """Paper §4.1.2 collision response for joints placed at `cand` (b,3) from `anchor` (b,3) at distance
        `lengths` (b,): if a joint is inside a box or its segment crosses one, move it as described at
        _CIRCLE_ANGLES / _SPHERE_POLAR. Returns (positions, responded (b,), failed (b,))."""
        boxes = self.boxes.select(rows)
        ign_joint, ign_seg = self._ignored(rows, joint, segment)
        inside, crossing = self._violations(boxes, anchor, cand, ign_joint, ign_seg)
        hit = inside.any(axis=1) | crossing.any(axis=1)
        b = cand.shape[0]
        if not hit.any():
            return cand, hit, np.zeros(b, dtype=bool)
        h = np.nonzero(hit)[0]
        a, p, L, r = anchor[h], cand[h], lengths[h], ref[h]
        # The colliding box: one containing the joint, else the first one the segment crosses.
        k = np.where(inside[h].any(axis=1), np.argmax(inside[h], axis=1), np.argmax(crossing[h], axis=1))
        corners = self.corners[rows[h], k] if self.boxes.batched else self.corners[k]  # (h,8,3)
        dis = norm(corners - p[:, None, :]).max(axis=1) + self.settings.margin
        # Circle of sphere(a, L) ∩ sphere(p, dis); |p - a| = L up to rounding.
        axis_vec = p - a
        dd = norm(axis_vec)
        nvec = axis_vec / dd[:, None]
        along = (dd * dd + L * L - dis * dis) / (2.0 * dd)
        rho2 = L * L - along * along
        has_circle = rho2 > 0.0
        rho = np.sqrt(np.maximum(rho2, 0.0))
        center = a + along[:, None] * nvec
        # In-plane basis: e1 toward the reference (the joint's position at the start of the iteration).
        w = r - center
        w = w - dot(w, nvec)[:, None] * nvec
        wn = norm(w)
        ok = wn > 1e-12 * L
        e1 = np.where(ok[:, None], w / np.where(ok, wn, 1.0)[:, None], any_perpendicular(nvec))
        e2 = cross(nvec, e1)
        cos_c, sin_c = np.cos(_CIRCLE_ANGLES), np.sin(_CIRCLE_ANGLES)
        ring = cos_c[None, :, None] * e1[:, None, :] + sin_c[None, :, None] * e2[:, None, :]  # (h,24,3)
        circle_pts = center[:, None, :] + rho[:, None, None] * ring
        circle_dirs = (circle_pts - a[:, None, :]) / L[:, None, None]
        polar = np.repeat(_SPHERE_POLAR, _CIRCLE_SAMPLES)
        azim = np.tile(_CIRCLE_ANGLES, _SPHERE_POLAR.size)
        sphere_dirs = (np.cos(polar)[None, :, None] * nvec[:, None, :]
                       + (np.sin(polar) * np.cos(azim))[None, :, None] * e1[:, None, :]
                       + (np.sin(polar) * np.sin(azim))[None, :, None] * e2[:, None, :])
        dirs = np.concatenate([circle_dirs, sphere_dirs], axis=1)
        dirs = dirs / norm(dirs)[..., None]
        if limit_fn is not None:
            dirs = limit_fn(h, dirs)
        pts = a[:, None, :] + L[:, None, None] * dirs
        sub = boxes.select(h)
        ij = None if ign_joint is None else ign_joint[h][:, None, :]
        iseg = None if ign_seg is None else ign_seg[h][:, None, :]
        c_in, c_cross = self._violations(sub, a[:, None, :], pts, ij, iseg)
        # Least penetration = fewest boxes entered or crossed; a missing circle is never a candidate.
        score = c_in.sum(axis=-1) + c_cross.sum(axis=-1)
        score[:, :_CIRCLE_SAMPLES] = np.where(has_circle[:, None], score[:, :_CIRCLE_SAMPLES], np.iinfo(np.int64).max)
        # Which candidate: first the fewest boxes entered or crossed ("least penetration"), then
        # - a joint inside a box (the paper's case): preference order, i.e. the paper's circle from its point
        #   nearest the reference, then the sphere samples;
        # - only the segment crossing a box (beyond the paper): the candidate nearest the unconstrained
        #   position, circle and sphere alike: every circle point is `dis` away, a needlessly large jump for
        #   a segment that only grazes a box, and the smallest correction keeps FABRIK converging.
        never = score == np.iinfo(np.int64).max
        order = np.broadcast_to(np.arange(score.shape[1]) / score.shape[1], score.shape)
        deviation = norm(pts - p[:, None, :]) / (2.0 * L[:, None])  # < 1: never outweighs a penetration
        tiebreak = np.where(inside[h].any(axis=1)[:, None], order, deviation)
        key = np.where(never, np.inf, score + 0.5 * tiebreak)
        pick = np.argmin(key, axis=1)
        out = cand.copy()
        out[h] = pts[np.arange(h.size), pick]
        failed = np.zeros(b, dtype=bool)
        failed[h] = score[np.arange(h.size), pick] > 0
        return out, hit, failed

    # -- passes ------------------------------------------------------------------------------------------------

    def forward(self, P, rows, prev, ref, tip=None):
        """Forward pass in place on P (b,n,3) of problems `rows`: effector to the target (or to `tip` (b,3)),
        joints toward the base. prev: positions at the start of the iteration (fallback directions); ref:
        obstacle-response reference."""
        lengths = self.lengths[rows]
        P[:, -1] = self.targets[rows] if tip is None else tip
        responded = np.zeros(len(rows), dtype=bool)
        failed = np.zeros(len(rows), dtype=bool)
        for i in range(self.n - 2, -1, -1):
            anchor = P[:, i + 1]
            d = P[:, i] - anchor
            L = lengths[:, i]
            dn = norm(d)
            bad = ~(dn > L * _COINCIDENT)
            if bad.any():
                d = np.where(bad[:, None], prev[:, i] - prev[:, i + 1], d)
                dn = norm(d)
            if self.limits is not None and i < self.n - 2 and self.limits.kind[i + 1] != FREE:
                child = (P[:, i + 2] - anchor) / lengths[:, i + 1, None]
                child = child / norm(child)[:, None]
                fallback = prev[:, i + 1] - prev[:, i]
                fallback = fallback / norm(fallback)[:, None]
                u = self._limit_reverse(i + 1, rows, child, -d / dn[:, None], fallback)
                cand = anchor - u * L[:, None]
            else:
                cand = anchor + d * (L / dn)[:, None]
            if self.boxes is not None and i > 0:  # joint 0 is re-pinned by the backward pass anyway
                cand, resp, fail = self._avoid(rows, anchor, cand, L, ref[:, i], i, i, None)
                responded |= resp
                failed |= fail
            P[:, i] = cand
        return responded, failed

    def backward(self, P, rows, aims, prev, ref, root=None, stretch=False):
        """Backward pass in place on P (b,n,3): base pinned (to `root` (b,3) if given), joint i+1 placed toward
        aims[:, i+1] (the forward-pass positions, or with `stretch` the target for every joint), limits then
        obstacles applied. Returns (limit binding, obstacle responded, obstacle failed), each (b,)."""
        lengths = self.lengths[rows]
        P[:, 0] = self.base[rows] if root is None else root
        b = len(rows)
        binding = np.zeros(b, dtype=bool)
        responded = np.zeros(b, dtype=bool)
        failed = np.zeros(b, dtype=bool)
        pivot = self.n - 3 if not stretch and root is None and self._finishes else -1
        finished = None
        for i in range(self.n - 1):
            if i == pivot:
                finished, elbow, wrist = self._two_bone_finish(P, rows, aims)
            anchor = P[:, i]
            d = aims[:, i + 1] - anchor
            if not stretch and self.limits is not None and i + 1 < self.n - 1 and self.limits.kind[i + 1] == HINGE:
                # The parent segment of a hinge keeps its forward-pass direction instead of aiming at the
                # forward-pass joint from the moved anchor: the hinge plane is carried by this direction, and
                # the forward pass fitted that plane to the child (_limit_reverse). Re-aiming would turn the
                # plane away from the target every iteration (measured: a limb with an elbow hinge and
                # perturbed targets went from about 1 in 3 reached to nearly all).
                d = aims[:, i + 1] - aims[:, i]
            L = lengths[:, i]
            dn = norm(d)
            bad = ~(dn > L * _COINCIDENT)
            if bad.any():
                d = np.where(bad[:, None], prev[:, i + 1] - prev[:, i], d)
                dn = norm(d)
            limit_fn = None
            if self.limits is not None and self.limits.kind[i] != FREE:
                if i == 0:
                    parent = self.parent_dirs[rows]
                else:
                    parent = (P[:, i] - P[:, i - 1]) / lengths[:, i - 1, None]
                    parent = parent / norm(parent)[:, None]
                fallback = prev[:, i + 1] - prev[:, i]
                fallback = fallback / norm(fallback)[:, None]
                u, bind = self._limit(i, rows, parent, d / dn[:, None], fallback)
                binding |= bind
                cand = anchor + u * L[:, None]

                def limit_fn(h, dirs, i=i, rows=rows, parent=parent, fallback=fallback):
                    return self._limit(i, rows[h], parent[h], dirs, fallback[h])[0]
            else:
                cand = anchor + d * (L / dn)[:, None]
            if self.boxes is not None:
                cand, resp, fail = self._avoid(rows, anchor, cand, L, ref[:, i + 1], i + 1, i, limit_fn)
                responded |= resp
                failed |= fail
            if finished is not None and i >= pivot:
                cand[finished] = (elbow if i == pivot else wrist)[finished]
                binding &= ~finished
                responded &= ~finished
                failed &= ~finished
            P[:, i + 1] = cand
        return binding, responded, failed

    def _two_bone_finish(self, P, rows, aims):
        """Analytic placement of the last two segments in the backward pass, once their pivot joint n-3 is
        placed, for a limited chain whose joint n-2 is free, a cone, or a hinge with a twist range
        (_finishes): FABRIK creeps toward a target near full stretch, and a hinge lets it reach only by
        turning the bend plane, which its passes do not seek. With pivot S, target T and lengths a, c, the
        middle joint lies on the circle
        where the spheres (S, a) and (T, c) meet; of _SWIVEL_ANGLES around it (from the forward pass's middle
        joint, the one FABRIK aims at, outward) the first is taken where the pivot's limit, the hinge (bend
        and twist) and the obstacles all hold exactly. Returns (finished (b,), middle (b,3), end (b,3)); rows
        with no such point (target out of the two segments' range, limits or boxes) are left to FABRIK."""
        j = self.n - 3
        b = len(rows)
        finished = np.zeros(b, dtype=bool)
        middle = np.zeros((b, 3))
        end = np.zeros((b, 3))
        lengths = self.lengths[rows]
        a, c = lengths[:, j], lengths[:, j + 1]
        S = P[:, j]
        to_t = self.targets[rows] - S
        d = norm(to_t)
        h = np.nonzero((d > np.abs(a - c) * (1.0 + 1e-9)) & (d < (a + c) * (1.0 - 1e-9)))[0]
        if h.size == 0:
            return finished, middle, end
        a, c, d, S, T = a[h], c[h], d[h], S[h], self.targets[rows[h]]
        e = to_t[h] / d[:, None]
        along = (a * a + d * d - c * c) / (2.0 * d)
        rho = np.sqrt(np.maximum(a * a - along * along, 0.0))
        centre = S + along[:, None] * e
        w = aims[h, j + 1] - centre
        w = w - dot(w, e)[:, None] * e
        wn = norm(w)
        ok = wn > 1e-12 * a
        e1 = np.where(ok[:, None], w / np.where(ok, wn, 1.0)[:, None], any_perpendicular(e))
        e2 = cross(e, e1)
        ring = np.cos(_SWIVEL_ANGLES)[None, :, None] * e1[:, None] \
            + np.sin(_SWIVEL_ANGLES)[None, :, None] * e2[:, None]
        E = centre[:, None] + rho[:, None, None] * ring  # (h,K,3)
        u = (E - S[:, None]) / a[:, None, None]
        u = u / norm(u)[..., None]
        v = T[:, None] - E
        v = v / norm(v)[..., None]
        ok = np.ones(E.shape[:2], dtype=bool)
        if self.limits.kind[j] != FREE:
            if j == 0:
                parent = self.parent_dirs[rows[h]]
            else:
                parent = P[h, j] - P[h, j - 1]
                parent = parent / norm(parent)[:, None]
            ok &= ~self._limit(j, rows[h], parent, u, u[:, 0])[1]
        k = j + 1
        if self.limits.kind[k] == CONE:
            ok &= ~apply_cone(u, v, self.limits.cone_angle[k], v)[1]
        elif self.limits.kind[k] == HINGE:
            axis = carry_axis(self.hinge_axes[rows[h], k][:, None], self.hinge_refs[rows[h], k][:, None], u)
            ok &= ~apply_hinge(u, v, axis, self.limits.hinge_min[k], self.limits.hinge_max[k], v,
                               self.limits.hinge_twist[k])[1]
        wrist = E + c[:, None, None] * v
        if self.boxes is not None:
            boxes = self.boxes.select(rows[h])
            for seg, (p0, p1) in ((j, (S[:, None], E)), (k, (E, wrist))):
                ign_joint, ign_seg = self._ignored(rows[h], seg + 1, seg)
                inside, crossing = self._violations(
                    boxes, np.broadcast_to(p0, p1.shape), p1,
                    None if ign_joint is None else ign_joint[:, None], None if ign_seg is None else ign_seg[:, None])
                ok &= ~(inside.any(axis=-1) | crossing.any(axis=-1))
        pick = np.argmax(ok, axis=1)
        found = ok[np.arange(h.size), pick]
        finished[h] = found
        middle[h] = E[np.arange(h.size), pick]
        end[h] = wrist[np.arange(h.size), pick]
        return finished, middle, end

    # -- solve -------------------------------------------------------------------------------------------------

    def penetration_counts(self, P, rows=None):
        """(joints inside, segments crossing) per problem (b,) of P (b,n,3) = problems `rows` (default all),
        ignoring what each problem must ignore."""
        rows = np.arange(self.B) if rows is None else rows
        if self.boxes is None:
            z = np.zeros(P.shape[0], dtype=np.int64)
            return z, z.copy()
        boxes = self.boxes.select(rows)
        inside = points_inside(P[:, 1:], boxes)  # (b,n-1,K): joint 0 is fixed, reported separately
        inside[:, -1] &= ~self.ignore_end[rows]
        crossing = segments_cross(P[:, :-1], P[:, 1:], boxes)  # (b,n-1,K)
        crossing[:, -1] &= ~self.ignore_end[rows]
        crossing[:, 0] &= ~self.ignore_base[rows]
        return inside.any(axis=-1).sum(axis=-1), crossing.any(axis=-1).sum(axis=-1)

    def _nudge(self, P, rows, nudges, slots):
        """Push the interior joints of stalled problems `rows` sideways (see _NUDGES), in place; nudges[slots]
        counts the nudges each has had."""
        for k in range(_NUDGES):
            pick = nudges[slots] == k
            sel = rows[pick]
            if sel.size == 0:
                continue
            u = _nudge_directions(self.targets[sel] - self.base[sel], P[sel, 1] - self.base[sel], k)
            shift = self.lengths[sel, :-1] * _NUDGE  # joint i moves by _NUDGE of segment i-1
            P[sel, 1:-1] = P[sel, 1:-1] + u[:, None, :] * shift[:, :, None]
        nudges[slots] += 1

    def violations(self, P, rows):
        """(b,) problems `rows` whose pose P (b,n,3) breaks a joint limit (beyond rounding) or penetrates a box
        it does not ignore."""
        bad = np.zeros(len(rows), dtype=bool)
        if self.limits is not None:
            lengths = self.lengths[rows]
            dirs = (P[:, 1:] - P[:, :-1]) / lengths[..., None]
            dirs = dirs / norm(dirs)[..., None]
            for i in np.nonzero(self.limits.kind != FREE)[0]:
                parent = self.parent_dirs[rows] if i == 0 else dirs[:, i - 1]
                bad |= self._limit(i, rows, parent, dirs[:, i], dirs[:, i])[1]
        if self.boxes is not None:
            inside, crossing = self.penetration_counts(P, rows)
            bad |= (inside + crossing) > 0
        return bad

    def _iterate(self, P, rows, force):
        """FABRIK iterations on problems `rows`, in place on P (B,n,3). Rows whose end is already within
        tolerance only iterate if `force` (bool or per row (b,)). Returns per-row (iterations, residual,
        stalled, limit binding, obstacle responses in the returned iterate, penetrations of the returned
        iterate)."""
        s = self.settings
        tol = s.tolerance
        stall = tol * _STALL
        b = rows.size
        constrained = self.limits is not None or self.boxes is not None
        iterations = np.zeros(b, dtype=np.int64)
        stalled = np.zeros(b, dtype=bool)
        binding_out = np.zeros(b, dtype=bool)
        obstacle_out = np.zeros(b, dtype=bool)
        nudges = np.zeros(b, dtype=np.int64)
        residual = norm(P[rows, -1] - self.targets[rows])
        if constrained:
            best_P = P[rows].copy()
            best_pen = np.full(b, np.iinfo(np.int64).max)
            best_res = np.full(b, np.inf)
            best_iter = np.zeros(b, dtype=np.int64)  # iteration of the last real improvement
        act = np.nonzero((residual > tol) | force)[0]  # positions within `rows`
        while act.size:
            active = rows[act]
            Pa = P[active]
            prev = Pa.copy()
            resp_f, _ = self.forward(Pa, active, prev, prev)
            aims = Pa.copy()
            binding, resp_b, _ = self.backward(Pa, active, aims, prev, prev)
            responded = resp_f | resp_b
            P[active] = Pa
            iterations[act] += 1
            res = norm(Pa[:, -1] - self.targets[active])
            moved = norm(Pa[:, -1] - prev[:, -1])
            residual[act] = res
            binding_out[act] = binding
            obstacle_out[act] = responded
            now_stalled = (res > tol) & (moved < stall)
            free = now_stalled & (nudges[act] < _NUDGES) & (iterations[act] < s.max_iterations) \
                & ~binding & ~responded
            if free.any():
                self._nudge(P, active[free], nudges, act[free])
                now_stalled &= ~free
            if constrained:
                pen = sum(self.penetration_counts(Pa, active))
                better = (pen < best_pen[act]) | ((pen == best_pen[act]) & (res < best_res[act]))
                improved = (pen < best_pen[act]) | (res < best_res[act] - stall)
                up = act[better]
                best_P[up], best_pen[up], best_res[up] = Pa[better], pen[better], res[better]
                binding_out[act] = np.where(better, binding, binding_out[act])
                obstacle_out[act] = np.where(better, responded, obstacle_out[act])
                best_iter[act[improved]] = iterations[act[improved]]
                now_stalled |= (res > tol) & (iterations[act] - best_iter[act] >= _PATIENCE)
            stalled[act] = now_stalled
            done = (res <= tol) | now_stalled | (iterations[act] >= s.max_iterations)
            act = act[~done]
        if constrained:
            ran = iterations > 0
            P[rows[ran]] = best_P[ran]
            residual[ran] = best_res[ran]
            pen = np.where(ran, best_pen, sum(self.penetration_counts(P[rows], rows)))
        else:
            pen = np.zeros(b, dtype=np.int64)
        return iterations, residual, stalled, binding_out, obstacle_out, pen

    def solve(self, start):
        B = self.B
        tol = self.settings.tolerance
        P = start.copy()
        total, inner = _reach_bounds(self.lengths)
        dist = norm(self.targets - self.base)
        beyond = dist > total
        reachable = ~beyond & (dist >= inner)
        iterations = np.zeros(B, dtype=np.int64)
        residual = np.zeros(B)
        stalled = np.zeros(B, dtype=bool)
        obstacle_active = np.zeros(B, dtype=bool)
        limit_binding = np.zeros(B, dtype=bool)

        rows = np.nonzero(beyond)[0]
        if rows.size:
            Pa = P[rows]
            prev = Pa.copy()
            aims = np.broadcast_to(self.targets[rows][:, None, :], Pa.shape)
            binding, responded, _ = self.backward(Pa, rows, aims, prev, prev, stretch=True)
            P[rows] = Pa
            iterations[rows] = 1
            residual[rows] = norm(Pa[:, -1] - self.targets[rows])
            limit_binding[rows] = binding
            obstacle_active[rows] = responded

        # A start pose already at its target is returned untouched (bit-exact, 0 iterations) unless it breaks a
        # limit or penetrates a box: then at least one iteration runs, so it is never returned unchecked.
        constrained = self.limits is not None or self.boxes is not None
        rows = np.nonzero(~beyond)[0]
        if rows.size:
            force = False
            if constrained:
                force = np.zeros(rows.size, dtype=bool)
                met = norm(P[rows, -1] - self.targets[rows]) <= tol
                force[met] = self.violations(P[rows[met]], rows[met])
            its, res, stl, bind, obst, pen = self._iterate(P, rows, force)
            iterations[rows], residual[rows], stalled[rows] = its, res, stl
            limit_binding[rows], obstacle_active[rows] = bind, obst
            # FABRIK's obstacle response is local: the chain can wrap around the wrong side of a box and stay
            # trapped there. A problem that is not reached gets a second start from the pose plain FABRIK
            # finds (no obstacles, no limits; the constrained iterations then push that pose out of the boxes
            # and into the limits), and keeps the better outcome: fewer penetrations, then the smaller residual.
            retry = rows[(res > tol) & reachable[rows]] if self.boxes is not None else rows[:0]
            if retry.size:
                free = ChainModel(start[retry], self.targets[retry], self.settings, None, None, None)
                Q = P.copy()
                unobstructed = free.solve(start[retry])
                Q[retry] = unobstructed.positions
                its2, res2, stl2, bind2, obst2, pen2 = self._iterate(Q, retry, True)
                old_pen = pen[np.searchsorted(rows, retry)]
                better = (pen2 < old_pen) | ((pen2 == old_pen) & (res2 < residual[retry]))
                iterations[retry] += unobstructed.iterations + its2
                keep = retry[better]
                P[keep], residual[keep], stalled[keep] = Q[keep], res2[better], stl2[better]
                limit_binding[keep], obstacle_active[keep] = bind2[better], obst2[better]

        inside, crossing = self.penetration_counts(P)
        status = np.empty(B, dtype=object)
        reason = np.empty(B, dtype=object)
        # Plain Python values: indexing numpy arrays element by element costs more than the status logic.
        per_problem = zip((residual <= tol).tolist(), reachable.tolist(), dist.tolist(), total.tolist(),
                          inner.tolist(), stalled.tolist(), iterations.tolist(), obstacle_active.tolist(),
                          limit_binding.tolist())
        for j, args in enumerate(per_problem):
            st, why = _final_status(*args)
            if self.boxes is not None:
                notes = []
                if inside[j] or crossing[j]:
                    notes.append(f"could not avoid obstacles: {inside[j]} joints inside, "
                                 f"{crossing[j]} segments crossing")
                if self.ignore_end[j].any():
                    notes.append("target inside obstacle")
                if self.ignore_base[j].any():
                    notes.append("base inside obstacle")
                if notes:
                    st, why = "blocked", "; ".join(notes + [why])
            status[j], reason[j] = st, why
        return ChainBatchResult(P, iterations, residual, reachable, status.astype(str), reason.astype(str))

