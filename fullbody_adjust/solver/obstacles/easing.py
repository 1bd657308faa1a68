"""Where a limb's clearance (AdjustSettings.clearance: its surface's radius plus Margin) keeps its chain solve from
the target: the retries with less of it (ClearanceEasing, mixed into limb_placement.LimbPlacement, whose
_solve_stacked, _limb_boxes, settings, obstacles and limb_pole it uses), each first from the limb's clearest
swivel (obstacle_swivel), then from its own start."""

from dataclasses import replace

import numpy as np

from .swivel import intrusion, swivel_starts
from .boxes import points_inside, segments_cross

# The fractions of a limb's clearance it is solved with, in turn, where the previous one kept it from its target
# (LimbPlacement._eased): the clearance is kept where the target allows it, then as much of it as does.
_EASED = (1.0, 0.5, 0.0)


class ClearanceEasing:
    """LimbPlacement's retries of limbs their clearance kept from their targets."""

    def _eased(self, tasks, results):
        """Where a limb's clearance kept it from its target (status 'blocked'), the limb solved again with less
        (_EASED): first from the start whose middle joint swivels round to where it comes least into the
        clearance (obstacle_swivel; limbs of two or more segments, rows without a pole, whose bend plane is the
        user's), then, where that did not reach, from its own start. A retry is taken where it reaches the
        target, the last (none: the paper's joints and segments out of the boxes themselves) also where it
        comes nearer; its reason says how much clearance it kept. `results` (one ChainBatchResult per task) are
        updated in place."""
        for less in _EASED[1:]:
            if not any(self.settings.clearance_of(t.name) > 0.0 and (r.status == "blocked").any()
                       for t, r in zip(tasks, results)):
                return
            for swivel in (True, False):
                retries = []
                for t, r in zip(tasks, results):
                    clearance = self.settings.clearance_of(t.name)
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
        again = self._solve_stacked([replace(t, rows=t.rows[b], start=start, targets=t.targets[b],
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
        within = intrusion(swivels, self.obstacles.select(task.rows[rows]), np.full(len(rows), clearance))
        best = swivels[np.arange(len(rows)), np.argmin(within, axis=1)]
        boxes = self._limb_boxes([(task.name, task.rows[rows], best[:, 0], task.targets[rows])], less)
        clear = ~points_inside(best, boxes).any(axis=(1, 2)) & ~segments_cross(best[:, :-1], best[:, 1:],
                                                                                 boxes).any(axis=(1, 2))
        return rows[clear], best[clear]

    def _swivels(self, task, blocked):
        """(b,) bool: which rows `blocked` of `task` have a swivel (two or more segments, no pole)."""
        if task.start.shape[1] < 3:
            return np.zeros(len(blocked), dtype=bool)
        if task.name not in self.limb_pole:
            return np.ones(len(blocked), dtype=bool)
        return ~np.isfinite(self.limb_pole[task.name][task.rows[blocked], 0])
