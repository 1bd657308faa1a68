"""Full-body adjustment (paper §5, Algorithm 1) for one pose or many frames at once.

    1. new SC and root positions from the targets (§5.2.1-5.2.2), with the fewest moved joints:
       - a limb alone serves when its target is within its reach: the SC and root then stay bit-exact;
       - else the SC moves to the nearest point from which every constrained arm (and the head) can reach: the
         intersection of the balls of limb-reach radius around the targets (the paper's two-sphere equation
         (1)), preferring points the trunk reaches by leaning, then by bending; when the balls do not
         intersect, the priority variants of §4.2 decide;
       - the pelvis translates when the trunk cannot bring the SC there (and by the trunk's remaining error
         when its joint limits hold it), but only where every constrained foot can still reach its ankle
         target: ankle tasks outrank the others by default (variant 2 at the root);
    2. trunk: FABRIK from the (translated) root to the new SC;
    3. arms (and head) from their bases riding on the new chest; 4. legs from the hips riding on the root.
Obstacles and joint limits apply to every chain solve (solve_chain_batch). Bones outside the solved chains keep
their local transforms (rigid children), so head and neck ride on the chest, fingers on the hands. A limb whose
target its start pose already meets, on a parent that did not move, is left exactly as it was.
Bone rotations (DESIGN §2.6): each chain bone turns by the minimal swing from its old direction to its new one,
except that an upper arm / thigh also turns about its length by the twist the solver gave its elbow's / knee's
bend plane, and the forearm / shin then turns relative to it about the hinge axis only (_segment_rotations).

Everything is vectorised over frames; a frame's result depends only on its own data (chain solves mask
converged problems and every other step is row-wise), so adjust_pose equals a row of adjust_frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .body import (CHAIN, END, FIXED, GROUP_NAMES, LIMB_OF_EFFECTOR, ROOT, BodyModel, HumanLimits, LimbLimits,
                   default_limits)
from .chain import ChainSettings, solve_chain_batch
from .errors import SolverInputError
from .geometry import any_perpendicular, apply_matrix, cross, dot, norm, rotate_about_axis, swing_rotation
from .limits import FREE, HINGE, carry_axis, hinge_twist_angle
from .obstacles import Boxes, penetrations

VARIANTS = ("weighted", "priority", "fabrik")
UNCONSTRAINED = "unconstrained"  # status of an effector without a target on that frame
_EYE = np.eye(3)
# Relative slack of "inside a ball" tests on computed points (their rounding is ~1e-16 relative).
_INSIDE_SLACK = 1e-12


@dataclass(frozen=True)
class AdjustSettings:
    """chain: per-chain FABRIK settings (tolerance is also the "target met" threshold);
    variant: how the SC is placed when the arms' reach balls do not intersect: 'weighted' (paper variant 1,
        eq. 4: priority-weighted mean of the arms' proposals), 'priority' (variant 2: the highest priority arm
        is served, lower ones best effort), 'fabrik' (unweighted mean, plain FABRIK's centroid);
    feet_first: ankle tasks have the highest priority at the root (paper §5.2.2); False: the root uses
        `variant` with the tasks' own priorities;
    use_limits: apply the default human joint limits (body.HumanLimits) when no limits are passed;
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
        Either way a limb that reaches its target alone leaves the SC and root exactly where they were."""

    chain: ChainSettings = ChainSettings()
    variant: str = "weighted"
    feet_first: bool = True
    use_limits: bool = True
    human_limits: HumanLimits = HumanLimits()
    reach_margin: float = 0.01
    sub_base_passes: int = 4
    limit_passes: int = 2
    help_held_limbs: bool = True

    def __post_init__(self):
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
    moved_groups: dict  # group name -> bool
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
    moved: np.ndarray  # (F,G) bool, columns = group_names
    group_names: tuple
    iterations: np.ndarray  # (F,) chain iterations spent on the frame
    sc_displacement: np.ndarray  # (F,)
    root_displacement: np.ndarray  # (F,)

    def __len__(self):
        return self.heads.shape[0]

    def __getitem__(self, i) -> AdjustResult:
        return AdjustResult(self.heads[i].copy(), self.tails[i].copy(), self.rotations[i].copy(), self.effectors,
                            self.residuals[i].copy(), self.status[i].copy(), self.reasons[i].copy(),
                            {g: bool(self.moved[i, k]) for k, g in enumerate(self.group_names)},
                            int(self.iterations[i]), float(self.sc_displacement[i]),
                            float(self.root_displacement[i]))


# ----------------------------------------------------------------------------------------------------------
# Sub-base geometry: nearest point of an intersection of balls, and the priority variants


def project_onto_balls(points, centres, radii):
    """Nearest point of each ball to each point: (F,3), (F,K,3), (F,K) -> (F,K,3). Inside points stay exactly."""
    d = points[:, None, :] - centres
    dist = norm(d)
    outside = dist > radii
    scale = np.where(outside, radii / np.where(outside, dist, 1.0), 1.0)
    return np.where(outside[..., None], centres + d * scale[..., None], points[:, None, :])


def _inside(x, centres, radii, active):
    """(F,) x lies in every active ball (F,K), within rounding slack."""
    dist = norm(x[:, None, :] - centres)
    ok = dist <= radii * (1.0 + _INSIDE_SLACK) + _INSIDE_SLACK
    return np.all(ok | ~active, axis=1)


def _circle_point(point, c1, r1, c2, r2):
    """Nearest point to `point` on the circle where spheres (c1,r1) and (c2,r2) meet: (F,3), valid (F,)."""
    axis = c2 - c1
    d = norm(axis)
    ok = d > 0.0
    u = np.where(ok[:, None], axis / np.where(ok, d, 1.0)[:, None], _EYE[0])  # concentric: no circle
    a = (d * d + r1 * r1 - r2 * r2) / (2.0 * np.where(ok, d, 1.0))
    h2 = r1 * r1 - a * a
    ok &= h2 >= 0.0
    h = np.sqrt(np.maximum(h2, 0.0))
    m = c1 + a[:, None] * u
    w = point - m
    w = w - dot(w, u)[:, None] * u
    wn = norm(w)
    # On the axis every circle point is equally near: take a deterministic one.
    w = np.where((wn > 1e-15)[:, None], w / np.where(wn > 1e-15, wn, 1.0)[:, None], any_perpendicular(u))
    return m + h[:, None] * w, ok


def _sphere_triple(c1, r1, c2, r2, c3, r3):
    """The two points where three spheres meet (trilateration): (2,F,3), valid (F,)."""
    ex_v = c2 - c1
    d = norm(ex_v)
    ok = d > 0.0
    ex = np.where(ok[:, None], ex_v / np.where(ok, d, 1.0)[:, None], _EYE[0])
    v3 = c3 - c1
    i = dot(ex, v3)
    ey_v = v3 - i[:, None] * ex
    j = norm(ey_v)
    ok &= j > 1e-12 * np.maximum(d, 1e-300)
    ey = ey_v / np.where(ok, j, 1.0)[:, None]
    ez = cross(ex, ey)
    x = (r1 * r1 - r2 * r2 + d * d) / (2.0 * np.where(ok, d, 1.0))
    y = (r1 * r1 - r3 * r3 + i * i + j * j) / (2.0 * np.where(ok, j, 1.0)) - i / np.where(ok, j, 1.0) * x
    z2 = r1 * r1 - x * x - y * y
    ok &= z2 >= 0.0
    z = np.sqrt(np.maximum(z2, 0.0))
    base = c1 + x[:, None] * ex + y[:, None] * ey
    return np.stack([base + z[:, None] * ez, base - z[:, None] * ez]), ok


def nearest_in_balls(points, centres, radii, active):
    """Nearest point to `points` (F,3) of the intersection of the active balls (F,K,3)/(F,K)/(F,K) bool.

    Exact (closed form), by the active-set argument: the optimum is the point itself, its projection onto one
    sphere, the nearest point of a two-sphere circle, or a three-sphere point; the nearest feasible candidate
    wins. Returns (x (F,3), feasible (F,)): feasible False where the balls have no common point (x = points).
    A point already inside every ball is returned unchanged (bit-exact)."""
    best = points.copy()
    feasible = _inside(points, centres, radii, active)
    best_d = np.where(feasible, 0.0, np.inf)
    todo = ~feasible
    if np.any(todo):
        # Only the rows outside some ball have candidates to weigh (a point inside all stays, at distance 0).
        rows = np.nonzero(todo)[0]
        best[rows], best_d[rows] = _nearest_candidate(points[rows], centres[rows], radii[rows], active[rows])
    feasible = np.isfinite(best_d)
    best = np.where(feasible[:, None], best, points)
    return best, feasible


def _nearest_candidate(points, centres, radii, active):
    """nearest_in_balls' candidates (projections, circle points, three-sphere points) for points outside
    some ball: the nearest valid one and its distance (inf where none is valid)."""
    k = radii.shape[1]
    best = points.copy()
    best_d = np.full(len(points), np.inf)
    proj = project_onto_balls(points, centres, radii)

    def consider(cand, valid):
        nonlocal best, best_d
        valid = valid & _inside(cand, centres, radii, active)
        dist = norm(cand - points)
        take = valid & (dist < best_d)
        best = np.where(take[:, None], cand, best)
        best_d = np.where(take, dist, best_d)

    for a in range(k):
        consider(proj[:, a], active[:, a])
    for a in range(k):
        for b in range(a + 1, k):
            cand, ok = _circle_point(points, centres[:, a], radii[:, a], centres[:, b], radii[:, b])
            consider(cand, ok & active[:, a] & active[:, b])
    for a in range(k):
        for b in range(a + 1, k):
            for c in range(b + 1, k):
                pts, ok = _sphere_triple(centres[:, a], radii[:, a], centres[:, b], radii[:, b],
                                         centres[:, c], radii[:, c])
                both = ok & active[:, a] & active[:, b] & active[:, c]
                consider(pts[0], both)
                consider(pts[1], both)
    return best, best_d


def nearest_on_sphere_in_balls(points, centre, radius, centres, radii, active):
    """Nearest point to `points` (F,3) on the sphere (centre (F,3), radius (F,)) that lies in every active ball
    (F,K,3)/(F,K)/(F,K). Candidates as in nearest_in_balls with the sphere always active: the radial
    projection, the sphere's circle with each ball's boundary, the two points it shares with two boundaries.
    Returns (x, found (F,))."""
    k = radii.shape[1]
    d = points - centre
    dn = norm(d)
    radial = centre + d * (radius / np.where(dn > 0.0, dn, 1.0))[:, None]
    radial = np.where((dn > 0.0)[:, None], radial, centre + radius[:, None] * _EYE[0])  # any point will do
    best = points.copy()
    best_d = np.full(len(points), np.inf)

    def consider(cand, valid):
        nonlocal best, best_d
        valid = valid & _inside(cand, centres, radii, active)
        dist = norm(cand - points)
        take = valid & (dist < best_d)
        best = np.where(take[:, None], cand, best)
        best_d = np.where(take, dist, best_d)

    consider(radial, np.ones(len(points), dtype=bool))
    for a in range(k):
        cand, ok = _circle_point(points, centre, radius, centres[:, a], radii[:, a])
        consider(cand, ok & active[:, a])
    for a in range(k):
        for b in range(a + 1, k):
            pts, ok = _sphere_triple(centre, radius, centres[:, a], radii[:, a], centres[:, b], radii[:, b])
            both = ok & active[:, a] & active[:, b]
            consider(pts[0], both)
            consider(pts[1], both)
    found = np.isfinite(best_d)
    return np.where(found[:, None], best, points), found


def sub_base_point(points, centres, radii, active, priorities, variant):
    """Where a sub-base goes: the nearest point of the active balls' intersection (paper eq. (1)); where that
    is empty, the variant decides (paper §4.2):
      'weighted' (variant 1, eq. 4): priority-weighted mean of each ball's proposal (its nearest point);
      'fabrik': the unweighted mean (plain FABRIK's centroid);
      'priority' (variant 2): balls taken from the highest priority down while they still intersect; the
        others are served best effort: like solving the chains from the lowest priority to the highest, the
        point is pulled onto each dropped ball in turn (lowest first), then onto the kept intersection.
    priorities (K,): higher wins; ties keep the given order (earlier wins). Returns (x (F,3), feasible (F,))."""
    x, feasible = nearest_in_balls(points, centres, radii, active)
    todo = ~feasible & np.any(active, axis=1)
    if not np.any(todo):
        return x, feasible
    rows = np.nonzero(todo)[0]
    p, c, r, act = points[rows], centres[rows], radii[rows], active[rows]
    if variant in ("weighted", "fabrik"):
        proposals = project_onto_balls(p, c, r)
        w = np.where(act, np.asarray(priorities, dtype=np.float64)[None, :] if variant == "weighted" else 1.0, 0.0)
        w = np.where(w.sum(axis=1, keepdims=True) > 0.0, w, act.astype(np.float64))  # all-zero priorities
        y = np.einsum("fk,fki->fi", w, proposals) / w.sum(axis=1)[:, None]
    else:
        order = np.argsort(-np.asarray(priorities, dtype=np.float64), kind="stable")
        kept = np.zeros_like(act)
        for k in order:
            trial = kept.copy()
            trial[:, k] |= act[:, k]
            _, ok = nearest_in_balls(p, c, r, trial)
            kept = np.where(ok[:, None], trial, kept)
        y = p.copy()
        for k in order[::-1]:
            dropped = act[:, k] & ~kept[:, k]
            y = np.where(dropped[:, None], project_onto_balls(y, c[:, k:k + 1], r[:, k:k + 1])[:, 0], y)
        y, _ = nearest_in_balls(y, c, r, kept)
    x = x.copy()
    x[rows] = y
    return x, feasible


# ----------------------------------------------------------------------------------------------------------
# Entry points


def adjust_pose(model, heads, tails, targets, effectors, priorities=None, *, obstacles=None,
                settings=AdjustSettings(), limits=None, bone_x_axes=None) -> AdjustResult:
    """Adjust one pose: heads/tails (J,3), targets (E,3) (a NaN row = no target). = adjust_frames with F = 1."""
    heads = np.asarray(heads, dtype=np.float64)
    tails = np.asarray(tails, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    if heads.ndim != 2 or tails.ndim != 2 or targets.ndim != 2:
        raise SolverInputError("adjust_pose takes heads (J,3), tails (J,3) and targets (E,3); "
                               "use adjust_frames for many frames")
    if bone_x_axes is not None:
        bone_x_axes = np.asarray(bone_x_axes, dtype=np.float64)[None]
    return adjust_frames(model, heads[None], tails[None], targets[None], effectors, priorities,
                         obstacles=obstacles, settings=settings, limits=limits, bone_x_axes=bone_x_axes)[0]


def adjust_frames(model, heads, tails, targets, effectors, priorities=None, *, obstacles=None,
                  settings=AdjustSettings(), limits=None, bone_x_axes=None) -> AdjustBatchResult:
    """Adjust F frames at once.

    heads, tails (F,J,3): world bone heads/tails at the start poses; targets (F,E,3) for the effector names
    `effectors` (E,) (from hand.L hand.R foot.L foot.R head), a NaN row meaning no target on that frame;
    priorities (E,) >= 0, higher wins (default all 1); obstacles: Boxes shared (K,3) or per frame (F,K,3);
    limits: {limb name: body.LimbLimits} to replace the defaults (a limb missing from the dict is free);
    bone_x_axes: optional per-bone world X axes (J,3)/(F,J,3) for the default hinge axes."""
    if not isinstance(model, BodyModel):
        raise SolverInputError("model must be a BodyModel")
    if not isinstance(settings, AdjustSettings):
        raise SolverInputError("settings must be an AdjustSettings")
    problem = _Problem(model, heads, tails, targets, effectors, priorities, obstacles, settings, limits,
                       bone_x_axes)
    return problem.solve()


# ----------------------------------------------------------------------------------------------------------
# The solve


@dataclass
class _LimbSolve:
    """A limb's solved chain on every frame (rigidly carried where not solved)."""

    joints: np.ndarray  # (F,n,3)
    solved: np.ndarray  # (F,) bool
    status: np.ndarray  # (F,) str ('' where not solved)
    reason: np.ndarray  # (F,) str
    rotations: np.ndarray = field(default=None)  # (F,n-1,3,3) each segment's world rotation delta

    def segment_rotations(self, start, limits):
        """World rotation deltas of the chain's segments from the start chain to the solved one, on solved
        frames (computed once per limb; `limits` the limb's LimbLimits or None): see _segment_rotations."""
        if self.rotations is None:
            self.rotations = np.broadcast_to(_EYE, self.joints.shape[:2] + (3, 3))[:, 1:].copy()
            s = self.solved
            if np.any(s):
                self.rotations[s] = _segment_rotations(start[s], self.joints[s], limits, s)
        return self.rotations


class _Problem:
    def __init__(self, model, heads, tails, targets, effectors, priorities, obstacles, settings, limits,
                 bone_x_axes):
        self.model = model
        self.settings = settings
        j = len(model.names)
        self.H0 = _frames_array(heads, "heads", (j, 3))
        self.T0 = _frames_array(tails, "tails", (j, 3))
        F = self.F = self.H0.shape[0]
        if self.T0.shape[0] != F:
            raise SolverInputError(f"heads have {F} frames but tails {self.T0.shape[0]}")
        if isinstance(effectors, str):
            raise SolverInputError("effectors must be a sequence of effector names")
        self.effectors = tuple(effectors)
        for e in self.effectors:
            if e not in LIMB_OF_EFFECTOR:
                raise SolverInputError(f"unknown effector {e!r} (use hand.L hand.R foot.L foot.R head)")
            if e not in model.effectors:
                raise SolverInputError(f"effector {e!r} needs a head group with neck bones and a head bone")
        if len(set(self.effectors)) != len(self.effectors):
            raise SolverInputError("an effector is listed twice")
        E = len(self.effectors)
        t = np.asarray(targets, dtype=np.float64)
        if t.shape != (F, E, 3):
            raise SolverInputError(f"targets must have shape ({F},{E},3), got {t.shape}")
        nan_rows = np.isnan(t).all(axis=2)
        if np.any(~np.isfinite(t) & ~nan_rows[..., None]):
            raise SolverInputError("target has NaN/inf (a target row must be all finite, or all NaN for none)")
        self.targets = t
        self.active_e = ~nan_rows
        if priorities is None:
            pr = np.ones(E)
        else:
            pr = np.asarray(priorities, dtype=np.float64)
            if pr.shape != (E,):
                raise SolverInputError(f"priorities must have shape ({E},), got {pr.shape}")
            if not np.all(np.isfinite(pr)) or np.any(pr < 0):
                raise SolverInputError("priorities must be finite numbers >= 0")
        self.priorities = pr
        if obstacles is not None:
            if not isinstance(obstacles, Boxes):
                raise SolverInputError("obstacles must be Boxes")
            if obstacles.batched and obstacles.mins.shape[0] != F:
                raise SolverInputError(f"per-frame boxes have {obstacles.mins.shape[0]} frames, expected {F}")
            if len(obstacles) == 0:
                obstacles = None
        self.obstacles = obstacles

        # Limb chains at the start poses, their targets and reach.
        self.chain0 = {}
        self.reach = {}
        for name, limb in model.limbs.items():
            joints = limb.joints(self.H0, self.T0)
            lengths = norm(joints[:, 1:] - joints[:, :-1])
            short = lengths <= 1e-12
            if np.any(short):
                i = int(np.nonzero(short.any(axis=0))[0][0])
                what = model.names[limb.bones[i]]
                raise SolverInputError(f"{name}: chain segment {i} (from bone {what!r}) has zero length")
            self.chain0[name] = joints
            total = lengths[:, 0].copy()
            for i in range(1, lengths.shape[1]):
                total = total + lengths[:, i]
            self.reach[name] = total
        # Reach used for the sub-base decisions; cut where joint limits held a limb short (limit_passes).
        self.reach_eff = {n: r.copy() for n, r in self.reach.items()}
        self.limb_target = {}
        self.limb_active = {}
        self.limb_priority = {}
        for name in model.limbs:
            self.limb_target[name] = np.zeros((F, 3))
            self.limb_active[name] = np.zeros(F, dtype=bool)
            self.limb_priority[name] = 0.0
        for k, e in enumerate(self.effectors):
            name = LIMB_OF_EFFECTOR[e]
            self.limb_target[name] = np.where(self.active_e[:, k, None], t[:, k], 0.0)
            self.limb_active[name] = self.active_e[:, k].copy()
            self.limb_priority[name] = float(pr[k])

        if limits is None:
            limits = default_limits(model, self.H0, self.T0, settings.human_limits, bone_x_axes) \
                if settings.use_limits else {}
        elif not isinstance(limits, dict) or any(not isinstance(v, LimbLimits) for v in limits.values()):
            raise SolverInputError("limits must be a dict of limb name -> LimbLimits")
        for name, ll in limits.items():
            if name not in model.limbs:
                raise SolverInputError(f"limits given for unknown limb {name!r}")
            m = model.limbs[name].n_joints - 1
            if len(ll.limits) != m:
                raise SolverInputError(f"limits for {name!r} cover {len(ll.limits)} joints, the chain has {m}")
            if ll.limits.hinge_axis.ndim == 3 and ll.limits.hinge_axis.shape[0] != F:
                raise SolverInputError(f"limits for {name!r}: per-frame hinge axes need {F} frames")
            pd = ll.parent_direction
            if pd is not None and (np.shape(pd) != (F, 3) or not np.all(np.isfinite(pd))):
                raise SolverInputError(f"limits for {name!r}: parent_direction must be finite, shape ({F},3)")
            if pd is None and ll.limits.kind[0] != FREE:
                raise SolverInputError(f"limits for {name!r}: joint 0 is limited but has no parent_direction")
        self.limits = limits
        self.iterations = np.zeros(F, dtype=np.int64)

    # -- chain solves on a subset of frames --------------------------------------------------------------

    def _solve(self, name, rows, start, targets, carry=None):
        """solve_chain_batch on frames `rows` with the limb's limits and the frames' obstacles. `carry` (b,3,3):
        the rotation that took the limb's start-pose chain to `start` (its parent's rotation), applied to
        joint 0's parent direction (and a hinge axis at joint 0), which are given at the start pose. The other
        hinge axes are carried from the start pose's own chain (hinge_reference; any reference the caller's
        limits had is replaced), the frame _segment_rotations writes the bones in.

        Warm start for a hinged limb (elbow, knee) whose end is not at its target yet: the last two segments
        are first placed by the two-bone solution in the plane of the start hinge axis carried to the
        target (_two_bone_start), which keeps the elbow/knee near where it was (measured: without it the
        mean joint angle error of bench/fullbody.py rises from 0.118 to 0.144 rad); FABRIK and the chain's
        two-segment finish then settle the twist, the cones, obstacles and the clavicle."""
        kwargs = {}
        ll = self.limits.get(name)
        if ll is not None and ll.limits.any_active:
            lim = ll.limits
            m = len(lim)
            axes = np.broadcast_to(lim.hinge_axis, (self.F,) + lim.hinge_axis.shape[-2:])[rows].copy()
            pdir = None if ll.parent_direction is None else ll.parent_direction[rows]
            # Hinge axes of joints > 0 stay in the start pose's frame: the solver carries them from the START
            # chain's parent directions by the parent's minimal swing, as _segment_rotations turns the bones,
            # so the output's elbow/knee is the hinge the solver enforced. Joint 0's parent direction (and a
            # hinge there) rides on the limb's parent.
            reference = np.diff(self.chain0[name][rows], axis=1)
            reference = np.concatenate([reference[:, :1], reference[:, :-1]], axis=1)
            if carry is not None:
                axes[:, 0] = apply_matrix(carry, axes[:, 0])
                pdir = None if pdir is None else apply_matrix(carry, pdir)
            if lim.kind[m - 1] == HINGE and m >= 2:
                met = norm(start[:, -1] - targets) <= self.settings.chain.tolerance
                at_start = carry_axis(axes[:, m - 1], reference[:, m - 1], start[:, m - 1] - start[:, m - 2])
                start = np.where(met[:, None, None], start, _two_bone_start(start, targets, at_start))
            kwargs["limits"] = lim.derived(hinge_axis=axes, hinge_reference=reference)
            kwargs["parent_directions"] = pdir
        if self.obstacles is not None:
            kwargs["obstacles"] = self.obstacles.select(rows)
        res = solve_chain_batch(start, targets, settings=self.settings.chain, **kwargs)
        self.iterations[rows] += res.iterations
        return res

    # -- step 1: sub-bases (SC, root) and the trunk ---------------------------------------------------------

    def _upper(self):
        return [n for n, limb in self.model.limbs.items() if limb.hub == "sc"]

    def _legs(self):
        return [n for n in ("leg.L", "leg.R")]

    def _balls(self, names, rows, offsets_from):
        """Reach balls for the sub-base `anchor`: a limb with base b (rigidly offset from the anchor by
        o = b - anchor) reaches its target t iff |anchor' - (t - o)| <= reach."""
        centres = np.stack([self.limb_target[n][rows] - offsets_from[n] for n in names], axis=1)
        radii = np.stack([self.reach_eff[n][rows] * (1.0 - self.settings.reach_margin) for n in names], axis=1)
        active = np.stack([self.limb_active[n][rows] for n in names], axis=1)
        prio = np.array([self.limb_priority[n] for n in names])
        return centres, radii, active, prio

    def _in_reach(self, names, rows, bases):
        """(b,) every active limb's target lies within its reach from `bases[name]` (rule (i), no margin)."""
        ok = np.ones(len(rows), dtype=bool)
        for n in names:
            d = norm(self.limb_target[n][rows] - bases[n])
            ok &= ~self.limb_active[n][rows] | (d <= self.reach_eff[n][rows])
        return ok

    def _place_sc(self, rows, pref, trunk_base, offsets):
        """New SC for frames `rows`, from which every constrained upper limb reaches, in this order of
        preference (the first that exists wins):
          1. the trunk leans: the point nearest `pref` (b,3) at the SC's current distance from the trunk base
             (the spine hardly shortens: its joints bend a few tens of degrees each, so pulling the SC
             straight toward the target would ask for a fold the joint limits refuse);
          2. the trunk bends: nearest `pref` within the trunk's reach from `trunk_base`;
          3. from the arms' balls alone (the root will have to move), the variant deciding if they are
             disjoint. The root stays in cases 1-2."""
        upper = self._upper()
        centres, radii, active, prio = self._balls(upper, rows, offsets)
        trunk_r = self.reach["trunk"][rows] * (1.0 - self.settings.reach_margin)
        lean_r = np.minimum(norm(pref - trunk_base), trunk_r)  # a straight spine: keep FABRIK off full stretch
        lean, ok_lean = nearest_on_sphere_in_balls(pref, trunk_base, lean_r, centres, radii, active)
        if np.all(ok_lean):
            return lean
        bend, ok_bend = nearest_in_balls(
            pref, np.concatenate([centres, trunk_base[:, None]], axis=1),
            np.concatenate([radii, trunk_r[:, None]], axis=1),
            np.concatenate([active, np.ones((len(rows), 1), dtype=bool)], axis=1))
        arms_only, _ = sub_base_point(pref, centres, radii, active, prio, self.settings.variant)
        out = np.where(ok_bend[:, None], bend, arms_only)
        return np.where(ok_lean[:, None], lean, out)

    def _root_delta(self, rows, pref, trunk_centre, trunk_active):
        """Root translation for frames `rows`: nearest to `pref` (b,3) where every constrained foot reaches its
        target and (where trunk_active) the trunk reaches the SC target (trunk_centre = sc* - trunk base)."""
        legs = self._legs()
        hips = {n: self.chain0[n][rows, 0] for n in legs}
        centres, radii, active, prio = self._balls(legs, rows, hips)
        upper_prio = max([self.limb_priority[n] for n in self._upper()] + [0.0])
        centres = np.concatenate([centres, trunk_centre[:, None]], axis=1)
        radii = np.concatenate([radii, (self.reach["trunk"][rows] * (1.0 - self.settings.reach_margin))[:, None]], 1)
        active = np.concatenate([active, trunk_active[:, None]], axis=1)
        if self.settings.feet_first:
            prio = np.append(prio, -np.inf)  # ankle tasks first (variant 2 at the root)
            variant = "priority"
        else:
            prio = np.append(prio, upper_prio)
            variant = self.settings.variant
        delta, _ = sub_base_point(pref, centres, radii, active, prio, variant)
        return delta

    def _sub_bases(self, rows, offsets, force_sc=None):
        """Steps 1-2 for frames `rows`, with the upper limbs' base offsets from the SC `offsets[name]` (b,3);
        force_sc (b,) marks frames whose SC must move (a later pass: the turned offsets alone may look in
        reach, but only because the SC moved). Returns (delta, sc_star, trunk joints, trunk solved, trunk status,
        trunk reason)."""
        upper = self._upper()
        trunk0 = self.chain0["trunk"][rows]
        sc0, base0 = trunk0[:, -1], trunk0[:, 0]
        b = len(rows)
        any_upper = np.zeros(b, dtype=bool)
        for n in upper:
            any_upper |= self.limb_active[n][rows]

        # SC: stays exactly unless some constrained arm cannot reach from its current base (rule (i)).
        need_sc = ~self._in_reach(upper, rows, {n: sc0 + offsets[n] for n in upper})
        if force_sc is not None:
            need_sc |= force_sc
        sc_star = sc0.copy()
        if np.any(need_sc):
            sc_star = np.where(need_sc[:, None], self._place_sc(rows, sc0, base0, offsets), sc0)

        # Root: stays exactly while every constrained foot reaches from its hip and the trunk reaches sc*.
        legs = self._legs()
        trunk_ok = ~need_sc | (norm(sc_star - base0) <= self.reach["trunk"][rows])
        need_root = ~(self._in_reach(legs, rows, {n: self.chain0[n][rows, 0] for n in legs}) & trunk_ok)
        delta = np.zeros((b, 3))
        if np.any(need_root):
            d = self._root_delta(rows, np.zeros((b, 3)), sc_star - base0, need_sc)
            delta = np.where(need_root[:, None], d, 0.0)
        moved_root = np.any(delta != 0.0, axis=1)

        # A root moved for the feet carries the SC along if the arms still reach from there; else the SC goes
        # to the nearest point (to where it was carried) from which they do.
        carried = ~need_sc & any_upper & moved_root
        if np.any(carried):
            sc_c = sc0 + delta
            need_c = carried & ~self._in_reach(upper, rows, {n: sc_c + offsets[n] for n in upper})
            if np.any(need_c):
                point = self._place_sc(rows, sc_c, base0 + delta, offsets)
                sc_star = np.where(need_c[:, None], point, sc_star)
                need_sc = need_sc | need_c

        # Trunk: FABRIK from the translated root to sc* where the SC moves relative to the root; else it rides.
        joints = trunk0 + delta[:, None, :]
        status = np.full(b, "", dtype=object)
        reason = np.full(b, "", dtype=object)
        solve = np.nonzero(need_sc)[0]
        if solve.size:
            res = self._solve("trunk", rows[solve], joints[solve], sc_star[solve])
            joints[solve] = res.positions
            status[solve] = res.status
            reason[solve] = res.reason
            # Paper §5.2.1: when the trunk cannot bring the SC there (joint limits), the pelvis moves by the
            # remaining error, as far as the feet allow. Not past obstacles: a blocked trunk stays.
            err = sc_star[solve] - res.positions[:, -1]
            late = (norm(err) > self.settings.chain.tolerance) & np.isin(res.status, ("limited", "max_iterations"))
            if np.any(late):
                s2 = solve[late]
                d2 = self._root_delta(rows[s2], delta[s2] + err[late], np.zeros((s2.size, 3)),
                                      np.zeros(s2.size, dtype=bool))
                shift = d2 - delta[s2]
                moved_chain = joints[s2] + shift[:, None, :]
                if self.obstacles is not None:
                    segs = np.stack([np.arange(joints.shape[1] - 1), np.arange(1, joints.shape[1])], axis=1)
                    boxes = self.obstacles.select(rows[s2])
                    before = sum(penetrations(joints[s2], segs, boxes))
                    after = sum(penetrations(moved_chain, segs, boxes))
                    keep = after <= before
                    shift = np.where(keep[:, None], shift, 0.0)
                    moved_chain = joints[s2] + shift[:, None, :]
                joints[s2] = moved_chain
                delta[s2] = delta[s2] + shift
                res_err = norm(sc_star[s2] - moved_chain[:, -1])
                fixed = res_err <= self.settings.chain.tolerance
                status[s2[fixed]] = "reached"
                reason[s2[fixed]] = "reached after the pelvis moved by the remaining error"
        return delta, sc_star, joints, need_sc, status, reason

    # -- the whole solve -------------------------------------------------------------------------------------

    _PER_FRAME = ("H0", "T0", "targets", "active_e", "iterations")
    _PER_FRAME_DICTS = ("chain0", "reach", "reach_eff", "limb_target", "limb_active")

    def _subset(self, rows):
        """The same problem restricted to frames `rows` (a fresh iteration count)."""
        sub = object.__new__(type(self))
        sub.__dict__.update(self.__dict__)
        sub.F = len(rows)
        for name in self._PER_FRAME:
            setattr(sub, name, getattr(self, name)[rows])
        sub.iterations = np.zeros(len(rows), dtype=np.int64)
        for name in self._PER_FRAME_DICTS:
            setattr(sub, name, {k: v[rows] for k, v in getattr(self, name).items()})
        sub.limits = {k: LimbLimits(_take_limits(v.limits, rows),
                                    None if v.parent_direction is None else v.parent_direction[rows])
                      for k, v in self.limits.items()}
        if self.obstacles is not None:
            sub.obstacles = self.obstacles.select(rows)
        return sub

    def solve(self) -> AdjustBatchResult:
        result = self._solve_once()
        tol = self.settings.chain.tolerance
        for _ in range(self.settings.limit_passes):
            held = np.isin(result.status, ("limited", "max_iterations")) & (result.residuals > tol)
            if not self.settings.help_held_limbs:
                # Rule (i) read literally: a limb's reach is cut only where its sub-base already had to move.
                for k, e in enumerate(self.effectors):
                    hub_moved = result.sc_displacement if self.model.limbs[LIMB_OF_EFFECTOR[e]].hub == "sc" \
                        else result.root_displacement
                    held[:, k] &= hub_moved > 0.0
            rows = np.nonzero(held.any(axis=1))[0]
            if rows.size == 0:
                break
            for k, e in enumerate(self.effectors):
                name = LIMB_OF_EFFECTOR[e]
                limb = self.model.limbs[name]
                r = rows[held[rows, k]]
                got = norm(result.heads[r, limb.end_bone] - result.heads[r, limb.bones[0]])
                self.reach_eff[name][r] = np.minimum(self.reach_eff[name][r], got)
            sub = self._subset(rows)
            again = sub._solve_once()
            self.iterations[rows] += again.iterations
            # Better = more tasks met, or as many with a smaller total residual.
            met_new = np.sum(again.status == "reached", axis=1)
            met_old = np.sum(result.status[rows] == "reached", axis=1)
            smaller = np.nansum(again.residuals, axis=1) < np.nansum(result.residuals[rows], axis=1) - 1e-12
            better = (met_new > met_old) | ((met_new == met_old) & smaller)
            take = rows[better]
            for f in ("heads", "tails", "rotations", "residuals", "status", "reasons", "moved",
                      "sc_displacement", "root_displacement"):
                getattr(result, f)[take] = getattr(again, f)[better]
        result.iterations = self.iterations.copy()
        return result

    def _solve_once(self) -> AdjustBatchResult:
        model, F = self.model, self.F
        upper = self._upper()
        trunk0 = self.chain0["trunk"]
        sc0 = trunk0[:, -1]
        offsets0 = {n: self.chain0[n][:, 0] - sc0 for n in upper}

        rows = np.arange(F)
        delta, sc_star, trunk_joints, trunk_solved, t_status, t_reason = self._sub_bases(rows, offsets0)
        # The chest turns, and the arm bases with it: re-place the SC with the turned offsets (fixed point).
        for _ in range(self.settings.sub_base_passes - 1):
            chest_r = _chest_rotation(trunk0, trunk_joints)
            retry = np.zeros(F, dtype=bool)
            for n in upper:
                base = trunk_joints[:, -1] + apply_matrix(chest_r, offsets0[n])
                far = norm(self.limb_target[n] - base) > self.reach_eff[n] + self.settings.chain.tolerance
                retry |= trunk_solved & self.limb_active[n] & far
            if not np.any(retry):
                break
            r = np.nonzero(retry)[0]
            offsets = {n: apply_matrix(chest_r[r], offsets0[n][r]) for n in upper}
            out = self._sub_bases(r, offsets, force_sc=np.ones(r.size, dtype=bool))
            delta[r], sc_star[r], trunk_joints[r] = out[0], out[1], out[2]
            trunk_solved[r], t_status[r], t_reason[r] = out[3], out[4], out[5]

        trunk = _LimbSolve(trunk_joints, trunk_solved, t_status, t_reason)
        heads, tails, rotations, limb_solves = self._propagate(delta, trunk)
        return self._result(heads, tails, rotations, limb_solves)

    def _propagate(self, delta, trunk):
        """Top-down pass over the bones: new heads, tails and world rotation deltas; limbs other than the
        trunk are solved when their first bone is reached (their base then rides on its parent)."""
        model, F, H0, T0 = self.model, self.F, self.H0, self.T0
        J = len(model.names)
        heads, tails = H0.copy(), T0.copy()
        rot = np.broadcast_to(_EYE, (F, J, 3, 3)).copy()
        moved = np.zeros((F, J), dtype=bool)
        solves = {"trunk": trunk}

        for j in model.order:
            role = model.roles[j]
            if role == FIXED:
                continue
            p = model.parents[j]
            if role == ROOT:
                heads[:, j] = H0[:, j] + delta  # x + 0.0 == x: an unmoved root stays bit-exact
                moved[:, j] = np.any(delta != 0.0, axis=1)
            else:
                if p >= 0 and moved[:, p].any():  # rigid child of its parent (overridden below for solved chain
                    mp = moved[:, p]               # bones); of an unmoved parent it stays as initialised
                    h = heads[:, p] + apply_matrix(rot[:, p], H0[:, j] - H0[:, p])
                    heads[:, j] = np.where(mp[:, None], h, H0[:, j])
                    rot[:, j] = rot[:, p]
                    moved[:, j] = mp
                name = model.role_limb[j]
                if role == CHAIN:
                    k = model.role_index[j]
                    if k == 0 and name not in solves:
                        solves[name] = self._solve_limb(name, heads[:, j], rot[:, p] if p >= 0 else None,
                                                        moved[:, p] if p >= 0 else np.zeros(F, dtype=bool))
                    ls = solves[name]
                    s = ls.solved
                    if np.any(s):
                        heads[s, j] = ls.joints[s, k]
                        rot[s, j] = ls.segment_rotations(self.chain0[name], self.limits.get(name))[s, k]
                        moved[s, j] = True
                elif role == END:
                    ls = solves[name]
                    s = ls.solved
                    if np.any(s):
                        # Hands, feet and the head keep their world orientation on a solved limb.
                        heads[s, j] = ls.joints[s, -1]
                        rot[s, j] = _EYE
                        moved[s, j] = True
            m = moved[:, j]
            if np.any(m):
                tails[m, j] = heads[m, j] + apply_matrix(rot[m, j], T0[m, j] - H0[m, j])
        return heads, tails, rot, solves

    def _solve_limb(self, name, base, parent_rot, parent_moved):
        """Solve limb `name` on the frames where its effector has a target, from its base `base` (F,3) riding
        on its parent (rotation parent_rot (F,3,3), moved (F,) bool); the start chain is the old one carried
        rigidly. A limb whose parent did not move and whose start pose already meets its target (within its
        limits, clear of the obstacles) stays exactly as it was: not solved, so its bones keep their
        positions bit-exact and their rotations exactly identity ("moves only the joints that need to")."""
        F = self.F
        c0 = self.chain0[name]
        r = np.broadcast_to(_EYE, (F, 3, 3)) if parent_rot is None else parent_rot
        carried = base[:, None, :] + np.einsum("fij,fkj->fki", r, c0 - c0[:, :1])
        carried = np.where(parent_moved[:, None, None], carried, c0)  # (c0 - b) + b may differ from c0 by 1 ulp
        solved = self.limb_active[name].copy()
        status = np.full(F, "", dtype=object)
        reason = np.full(F, "", dtype=object)
        joints = carried
        rows = np.nonzero(solved)[0]
        if rows.size:
            res = self._solve(name, rows, carried[rows], self.limb_target[name][rows], carry=r[rows])
            joints = carried.copy()
            joints[rows] = res.positions
            status[rows] = res.status
            reason[rows] = res.reason
            # The chain returns a valid start pose that meets its target untouched (0 iterations).
            kept = (res.iterations == 0) & ~parent_moved[rows] & np.all(res.positions == c0[rows], axis=(1, 2))
            solved[rows[kept]] = False
        return _LimbSolve(joints, solved, status, reason)

    def _result(self, heads, tails, rotations, solves) -> AdjustBatchResult:
        model, F = self.model, self.F
        E = len(self.effectors)
        tol = self.settings.chain.tolerance
        residuals = np.full((F, E), np.nan)
        status = np.full((F, E), UNCONSTRAINED, dtype=object)
        reasons = np.full((F, E), "no target on this frame", dtype=object)
        trunk = solves["trunk"]
        for k, e in enumerate(self.effectors):
            name = LIMB_OF_EFFECTOR[e]
            limb = model.limbs[name]
            act = self.active_e[:, k]
            pos = heads[:, limb.end_bone]
            res = norm(pos - np.where(act[:, None], self.targets[:, k], 0.0))
            residuals[act, k] = res[act]
            ls = solves[name]
            rows = np.nonzero(act)[0]
            met = res[rows] <= tol
            st = np.array(ls.status[rows], dtype=object)
            why = np.array(ls.reason[rows], dtype=object)
            # Met by its chain, then moved (cannot happen with rigid propagation).
            moved_off = ~met & (st == "reached")
            st[moved_off] = "unreachable"
            why[moved_off] = "moved off its target after the chain solve"
            if limb.hub == "sc":
                t_st = np.asarray(trunk.status)[rows]
                by_trunk = ~met & (st == "unreachable") & np.asarray(trunk.solved)[rows] \
                    & ((t_st == "blocked") | (t_st == "limited"))
                for i in np.nonzero(by_trunk)[0]:
                    f = rows[i]
                    st[i], why[i] = trunk.status[f], f"the trunk could not bring the SC into reach: {trunk.reason[f]}"
            st[met] = "reached"
            why[met & np.array([not r for r in why], dtype=bool)] = "reached"
            status[rows, k] = st
            reasons[rows, k] = why
        moved = np.zeros((F, len(GROUP_NAMES)), dtype=bool)
        for g, name in enumerate(GROUP_NAMES):
            bones = list(model.groups.get(name, ()))
            if bones:
                moved[:, g] = np.any(heads[:, bones] != self.H0[:, bones], axis=(1, 2)) | \
                    np.any(tails[:, bones] != self.T0[:, bones], axis=(1, 2))
        chest = model.groups["trunk"][-1]
        sc_disp = norm(tails[:, chest] - self.T0[:, chest])
        root_disp = norm(heads[:, model.root] - self.H0[:, model.root])
        return AdjustBatchResult(heads, tails, rotations, self.effectors, residuals, status.astype(str),
                                 reasons.astype(str), moved, GROUP_NAMES, self.iterations.copy(), sc_disp,
                                 root_disp)


def _two_bone_start(start, targets, axis):
    """Place the last two segments of chains (b,n,3) so the end meets `targets` (b,3) with the last joint's
    hinge (axis (b,3) at the start pose) bending to its positive side. Rigid turns only, smallest first:
      0. (chains with segments before the two, e.g. a clavicle) if the target is beyond the two segments'
         reach, turn the whole chain about joint 0 by the least angle that brings it within reach;
      1. swing the two segments about their root (shoulder/hip) so the end points at the target;
      2. turn the upper segment about the hinge axis (made perpendicular to root -> target) so the end lies
         at the target's distance (law of cosines; out-of-range distances are clamped: FABRIK reports them).
    """
    m = start.shape[1] - 1
    out = start.copy()
    a = norm(out[:, m - 1] - out[:, m - 2])
    c = norm(out[:, m] - out[:, m - 1])
    if m >= 3:
        base = out[:, 0]
        arm = out[:, m - 2] - base  # joint 0 -> root of the two segments, turned as one rigid piece
        length = norm(arm)
        to_t = targets - base
        dist = norm(to_t)
        reach2 = (a + c) * (1.0 - 1e-3)
        # Pivot p = base + length * w is within reach2 of the target iff w . t_dir >= cos_max.
        cos_max = (dist * dist + length * length - reach2 * reach2) / (2.0 * length * np.maximum(dist, 1e-300))
        cos_now = dot(arm, to_t) / (length * np.maximum(dist, 1e-300))
        need = (cos_now < cos_max) & (dist > 0.0)
        if np.any(need):
            t_dir = to_t / np.maximum(dist, 1e-300)[:, None]
            angle_now = np.arccos(np.clip(cos_now, -1.0, 1.0))
            angle_ok = np.arccos(np.clip(cos_max, -1.0, 1.0))
            new_w = rotate_about_axis(t_dir, cross(t_dir, arm) + (norm(cross(t_dir, arm)) <= 1e-12)[:, None]
                                      * any_perpendicular(t_dir), angle_ok)
            turn = swing_rotation(arm, np.where((angle_now > angle_ok)[:, None], new_w, arm))
            turn = np.where(need[:, None, None], turn, _EYE)
            out = base[:, None, :] + np.einsum("bij,bkj->bki", turn, out - base[:, None, :])
            axis = apply_matrix(turn, axis)
    pivot = out[:, m - 2]
    turn = swing_rotation(out[:, -1] - pivot, targets - pivot)
    out[:, m - 2:] = pivot[:, None, :] + np.einsum("bij,bkj->bki", turn, out[:, m - 2:] - pivot[:, None, :])
    axis = apply_matrix(turn, axis)
    to_target = targets - pivot
    d = np.clip(norm(to_target), np.abs(a - c), a + c)
    dt = to_target / np.maximum(norm(to_target), 1e-300)[:, None]
    n = axis - dot(axis, dt)[:, None] * dt
    ok = norm(n) > 1e-9
    n = n / np.where(ok, norm(n), 1.0)[:, None]
    cos_alpha = np.clip((a * a + d * d - c * c) / (2.0 * a * np.maximum(d, 1e-300)), -1.0, 1.0)
    # Upper segment at -alpha from root -> target about n, so the lower one bends by a positive angle.
    upper = rotate_about_axis(dt, n, -np.arccos(cos_alpha))
    elbow = pivot + a[:, None] * upper
    lower = targets - elbow
    ln = norm(lower)
    lower = np.where((ln > 1e-300)[:, None], lower / np.maximum(ln, 1e-300)[:, None], upper)
    placed = out.copy()
    placed[:, m - 1] = elbow
    placed[:, m] = elbow + c[:, None] * lower
    good = ok & (norm(to_target) > 0.0)
    return np.where(good[:, None, None], placed, out)


def _take_limits(limits, rows):
    """JointLimits with per-frame hinge axes (and references) restricted to frames `rows`."""
    axes, ref = limits.hinge_axis, limits.hinge_reference
    return limits.derived(hinge_axis=axes[rows] if axes.ndim == 3 else axes,
                          hinge_reference=ref[rows] if ref is not None and ref.ndim == 3 else ref)


def _segment_rotations(start, joints, limits, frames):
    """World rotation deltas (b,n-1,3,3) of chain segments from `start` (b,n,3) to `joints` (b,n,3) on frames
    `frames` (a row selector of the limbs' F frames), DESIGN §2.6: each segment turns by the minimal swing
    from its old direction to its new one (its twist kept), except around a hinge (limits: LimbLimits or None)
    with joint i > 0:
      - the parent segment i-1 also turns about its new direction by the hinge's twist (the angle by which the
        bend plane left the start axis carried by the parent's swing, as the solver carries it), so the
        start hinge axis turned with the bone is the axis the child bends about;
      - the child segment i turns by the minimal swing in its parent's frame: relative to the parent it
        rotates about the hinge axis only, a pure hinge (an elbow or knee does not twist)."""
    old = np.diff(start, axis=1)
    new = np.diff(joints, axis=1)
    rot = swing_rotation(old, new)
    if limits is None:
        return rot
    lim = limits.limits
    axes = lim.hinge_axis
    for i in np.nonzero(lim.kind == HINGE)[0]:
        if i == 0:
            continue
        axis = axes[frames, i] if axes.ndim == 3 else np.broadcast_to(axes[i], (len(start), 3))
        parent = new[:, i - 1] / norm(new[:, i - 1])[:, None]
        child = new[:, i] / norm(new[:, i])[:, None]
        tau = hinge_twist_angle(parent, child, apply_matrix(rot[:, i - 1], axis))
        rot[:, i - 1] = np.einsum("bij,bjk->bik", _rotation_about(parent, tau), rot[:, i - 1])
        if i + 1 >= len(lim) or lim.kind[i + 1] != HINGE:  # a hinge parent itself keeps the solver's frame
            rot[:, i] = np.einsum("bij,bjk->bik", swing_rotation(apply_matrix(rot[:, i - 1], old[:, i]), new[:, i]),
                                  rot[:, i - 1])
    return rot


def _rotation_about(axis, angle):
    """Rotation matrices (b,3,3) about unit axes (b,3) by angles (b,) (Rodrigues)."""
    k = axis
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    kx = np.zeros(k.shape[:1] + (3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    return c * _EYE + s * kx + (1.0 - c) * (k[:, :, None] * k[:, None, :])


def _chest_rotation(trunk0, trunk_new):
    """(F,3,3) swing of the last trunk segment: the chest's world rotation delta."""
    return swing_rotation(trunk0[:, -1] - trunk0[:, -2], trunk_new[:, -1] - trunk_new[:, -2])


def _frames_array(a, label, shape):
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != shape:
        raise SolverInputError(f"{label} must have shape (F,{shape[0]},{shape[1]}), got {arr.shape}")
    if arr.shape[0] == 0:
        raise SolverInputError(f"{label} have no frames")
    if not np.all(np.isfinite(arr)):
        raise SolverInputError(f"{label} have NaN/inf")
    return arr
