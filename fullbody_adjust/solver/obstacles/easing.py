"""Where a limb's clearance (AdjustSettings.clearance: its surface's radius plus Margin) keeps its chain solve from
the target: the retries with less of it (ClearanceEasing, owned by limb_placement.LimbPlacement, whose
_solve_stacked and _limb_boxes it calls, on the problem's settings, obstacles, limits, chain0 and limb_pole), each first from the limb's
clearest swivel (obstacle_swivel), then from its own start; and where a limb reached its target with its mesh's
surface (AdjustSettings.surface) in a box, the swivel round the target that keeps the surface out best: out of the
obstacles themselves first, then out of the Margin round them."""

from dataclasses import replace

import numpy as np

from ..maths.geometry import norm
from ..fullbody.limb_rotations import chain_rotations
from .surface import depth_in_boxes, posed_points
from .swivel import ANGLES, intrusion, swivel_starts
from .boxes import points_inside, segments_cross

# The fractions of a limb's clearance it is solved with, in turn, where the previous one kept it from its target
# (LimbPlacement._eased): the clearance is kept where the target allows it, then as much of it as does.
_EASED = (1.0, 0.5, 0.0)


class ClearanceEasing:
    """The retries of limbs their clearance kept from their targets, for the problem ``p`` (adjust._Problem),
    through its limbs' solves (``limbs``: LimbPlacement)."""

    def __init__(self, problem, limbs):
        self.p = problem
        self.limbs = limbs

    def _eased(self, tasks, results):
        """_eased_levels, then _surface_clear on what reached."""
        self._eased_levels(tasks, results)
        self._surface_clear(tasks, results)

    def _surface_clear(self, tasks, results):
        """Where a limb with a surface (settings.surface_of: its mesh as points riding on its segments) reached its
        target with some of those points in a box grown by the margin (a fist past the forearm's joint end, a
        target nearer a box than the limb's radius: no capsule round the centre line keeps such a surface out),
        the other poses that meet the target: each swivel (obstacle_swivel; limbs of two or more segments, rows
        without a pole) solved with the limb's limits and no obstacle, all in one stacked solve (the limits turn
        a swivel past the shoulder's or hip's range back within it). Of those that reach the target with every
        joint and segment out of the grown boxes, the one whose surface points lie least deep in them (their depths
        added up: surface.depth_in_boxes; then the least moved from the pose it replaces) replaces it where
        they lie less deep: among the poses that meet the target, the one whose surface keeps out best.
        `results` updated in place."""
        tries = []
        for t, r in zip(tasks, results):
            surface = self.p.settings.surface_of(t.name)
            if surface is None or t.start.shape[1] < 3:
                continue
            rows = np.nonzero(r.status == "reached")[0]
            rows = rows[self._swivels(t, rows)]
            if not rows.size:
                continue
            now = self._depths(t, rows, r.positions[rows][:, None])[:, 0]
            inside = now[:, 1] > 0  # in the margin round a box (its surface in the box itself too, if there)
            rows, now = rows[inside], now[inside]
            if rows.size:
                every = np.repeat(rows, len(ANGLES))
                starts = swivel_starts(t.start[rows], t.targets[rows]).reshape(-1, *t.start.shape[1:])
                tries.append((t, r, rows, now, replace(t, rows=t.rows[every], start=starts, targets=t.targets[every],
                                                       carry=None if t.carry is None else t.carry[every],
                                                       still=None if t.still is None else t.still[every])))
        if not tries:
            return
        kept, self.p.obstacles = self.p.obstacles, None
        try:
            solved = self.limbs._solve_stacked([task for *_t, task in tries], retry=True)
        finally:
            self.p.obstacles = kept
        for (t, r, rows, now, task), redo in zip(tries, solved):
            k = len(ANGLES)
            boxes = self._margin_boxes(t.rows[rows])
            joints = redo.positions.reshape(len(rows), k, *redo.positions.shape[1:])
            clear = (redo.status == "reached").reshape(len(rows), k) \
                & ~points_inside(joints, boxes).any(axis=(2, 3)) \
                & ~segments_cross(joints[:, :, :-1], joints[:, :, 1:], boxes).any(axis=(2, 3))
            depth = np.where(clear[..., None], self._depths(t, rows, joints), np.inf)
            moved = norm(joints - r.positions[rows][:, None]).sum(axis=-1)
            best = _first_least(depth, moved)
            chosen = depth[np.arange(len(rows)), best]
            take = np.nonzero((chosen[:, 0] < now[:, 0]) | ((chosen[:, 0] == now[:, 0]) & (chosen[:, 1] < now[:, 1])))[0]
            pick = take * k + best[take]
            r.status, r.reason = r.status.astype(object), r.reason.astype(object)
            for field in ("positions", "iterations", "residual", "reachable", "status"):
                getattr(r, field)[rows[take]] = getattr(redo, field)[pick]
            r.reason[rows[take]] = [f"{why}; turned round its target to keep its surface out of the obstacles"
                                    for why in r.reason[rows[take]]]

    def _margin_boxes(self, frames):
        """The obstacle boxes of `frames` grown by the margin (per problem)."""
        boxes = self.p.obstacles.select(frames)
        return boxes.grown(np.full((len(frames), len(boxes)), self.p.settings.chain.margin))

    def _depths(self, task, rows, chains):
        """(b,k,2): how deep the surface of `task`'s rows `rows` on chains (b,k,n,3) lies in the obstacles
        themselves, and in them grown by the margin (surface.depth_in_boxes)."""
        frames = task.rows[rows]
        points = self._surface_points(task, rows, chains)
        return np.stack([depth_in_boxes(points, self.p.obstacles.select(frames)),
                         depth_in_boxes(points, self._margin_boxes(frames))], axis=-1)

    def _surface_points(self, task, rows, chains):
        """surface.posed_points of `task`'s rows `rows` on chains (b,k,n,3), turned as the bones are written
        (from the frames' start pose chains, limb_rotations.chain_rotations)."""
        frames = task.rows[rows]
        b, k, n = chains.shape[:3]
        start = self.p.chain0[task.name][frames]
        turns = chain_rotations(np.repeat(start, k, axis=0), chains.reshape(b * k, n, 3),
                                self.p.limits.get(task.name), np.repeat(frames, k))
        return posed_points(self.p.settings.surface_of(task.name), frames, start, chains,
                            turns.reshape(b, k, n - 1, 3, 3))

    def _eased_levels(self, tasks, results):
        """Where a limb's clearance kept it from its target (status 'blocked'), the limb solved again with less
        (_EASED): first from the start whose middle joint swivels round to where it comes least into the
        clearance (obstacle_swivel; limbs of two or more segments, rows without a pole, whose bend plane is the
        user's), then, where that did not reach, from its own start. A retry is taken where it reaches the
        target, the last (none: the paper's joints and segments out of the boxes themselves) also where it
        comes nearer; its reason says how much clearance it kept. `results` (one ChainBatchResult per task) are
        updated in place."""
        for less in _EASED[1:]:
            if not any(self.p.settings.clearance_of(t.name) > 0.0 and (r.status == "blocked").any()
                       for t, r in zip(tasks, results)):
                return
            for swivel in (True, False):
                retries = []
                for t, r in zip(tasks, results):
                    clearance = self.p.settings.clearance_of(t.name)
                    blocked = np.nonzero(r.status == "blocked")[0] if clearance > 0.0 else []
                    start = None if swivel or not len(blocked) else t.start[blocked]
                    if swivel and len(blocked):
                        blocked, start = self._clear_swivels(t, blocked[self._swivels(t, blocked)], clearance, less)
                    if len(blocked):
                        retries.append((t, r, blocked, clearance, start))
                if retries:
                    self._retry(retries, less)

    def _retry(self, retries, less):
        """One stacked solve of the rows `blocked` of each (task, result, blocked, clearance, start chains) in
        `retries` with `less` of their clearance; taken as _eased says."""
        again = self.limbs._solve_stacked([replace(t, rows=t.rows[b], start=start, targets=t.targets[b],
                                             carry=None if t.carry is None else t.carry[b],
                                             still=None if t.still is None else t.still[b])
                                     for t, _r, b, _c, start in retries], less, retry=True)
        for (t, r, blocked, clearance, _start), redo in zip(retries, again):
            take = (redo.status == "reached") | ((less == 0.0) & (redo.residual < r.residual[blocked]))
            kept = f"kept {less * clearance:.3g} of its clearance {clearance:.3g} from the obstacles" if less \
                else f"its clearance {clearance:.3g} from the obstacles not kept"
            r.status, r.reason = r.status.astype(object), r.reason.astype(object)  # fixed width would cut
            redo.reason = redo.reason.astype(object)
            redo.reason[take] = [f"{why}; {kept}" for why in redo.reason[take]]
            for field in ("positions", "iterations", "residual", "reachable", "status", "reason"):
                getattr(r, field)[blocked[take]] = getattr(redo, field)[take]

    def _clear_swivels(self, task, rows, clearance, less):
        """(rows kept, their starts): of `task`'s rows `rows` (indices into the task), those whose clearest
        swivel (swivel_starts, least intrusion into `clearance`) keeps every joint and segment out of the boxes
        grown by `less` of it, and that swivel: only they are worth a solve from it."""
        if not len(rows):
            return rows, None
        swivels = swivel_starts(task.start[rows], task.targets[rows])
        within = intrusion(swivels, self.p.obstacles.select(task.rows[rows]), np.full(len(rows), clearance))
        best = swivels[np.arange(len(rows)), np.argmin(within, axis=1)]
        boxes = self.limbs._limb_boxes([(task.name, task.rows[rows], best[:, 0], task.targets[rows])], less)
        clear = ~points_inside(best, boxes).any(axis=(1, 2)) & ~segments_cross(best[:, :-1], best[:, 1:],
                                                                                 boxes).any(axis=(1, 2))
        return rows[clear], best[clear]

    def _swivels(self, task, blocked):
        """(b,) bool: which rows `blocked` of `task` have a swivel (two or more segments, no pole)."""
        if task.start.shape[1] < 3:
            return np.zeros(len(blocked), dtype=bool)
        if task.name not in self.p.limb_pole:
            return np.ones(len(blocked), dtype=bool)
        return ~np.isfinite(self.p.limb_pole[task.name][task.rows[blocked], 0])


def _first_least(depth, moved):
    """(b,): per row of depth (b,k,2: in the obstacles, in their margin) and moved (b,k), the index of the least
    depth in the obstacles, the least in their margin among equals, then the least moved."""
    least = depth[..., 0] == depth[..., 0].min(axis=1, keepdims=True)
    margin = np.where(least, depth[..., 1], np.inf)
    key = np.where(least & (margin == margin.min(axis=1, keepdims=True)), moved, np.inf)
    return np.argmin(key, axis=1)
