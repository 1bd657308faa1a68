"""What an adjustment did, in world units, and the lines that say so."""

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np


def missed_target_line(effectors, missed, residuals, why):
    """One line for the first effector with a target missed within reach: ``missed`` (F,E) bool, its frames
    (when F > 1), its largest residual and ``why`` (F,E) of that frame."""
    k = int(np.nonzero(missed.any(axis=0))[0][0])
    rows = np.nonzero(missed[:, k])[0]
    worst = rows[int(np.argmax(residuals[rows, k]))]
    frames = f" on {len(rows)} frames" if missed.shape[0] > 1 else ""
    return f"{effectors[k]} missed its target within reach{frames} by {residuals[worst, k]:.4g} ({why[worst, k]})"


@dataclass
class Outcome:
    """What a run did, in world units: per frame and effector (EFFECTORS order) residuals (NaN: no target)."""

    frames: np.ndarray  # (F,)
    effectors: tuple
    residuals: np.ndarray  # (F,E) world distance effector -> target (adjust_pose: as Blender evaluates the result)
    status: np.ndarray  # (F,E)
    reasons: np.ndarray  # (F,E)
    moved_bones: tuple
    # () -> ((F,) joints inside an obstacle box after the solve, (F,) bone segments crossing one): counted when first
    # asked for (joints_inside, segments_crossing); Live never asks.
    count_penetrations: Callable
    action: object = None

    @cached_property
    def _penetration_counts(self):
        return self.count_penetrations()

    @property
    def joints_inside(self):
        return self._penetration_counts[0]

    @property
    def segments_crossing(self):
        return self._penetration_counts[1]

    @property
    def constrained(self):
        return np.isfinite(self.residuals)

    @property
    def met(self):
        return self.status == "reached"

    def warning(self):
        """One line naming what went wrong although the run finished (the command line exits 1 for the same):
        a target within reach that was missed (the first effector, with its largest residual and why), or bones
        that end inside an obstacle; None when neither happened."""
        missed = self.constrained & ~self.met & (self.status != "unreachable")
        if missed.any():
            return missed_target_line(self.effectors, missed, self.residuals, self.reasons)
        inside, crossing = int(np.sum(self.joints_inside)), int(np.sum(self.segments_crossing))
        if inside or crossing:
            return f"bones end inside obstacles: {inside} joints inside, {crossing} bones crossing"
        return None

    def summary(self):
        """One line for the operator's report."""
        tasks = int(self.constrained.sum())
        met = int((self.met & self.constrained).sum())
        largest = float(np.nanmax(self.residuals)) if tasks else 0.0
        frames = len(self.frames)
        where = f" over {frames} frames" if frames > 1 else ""
        line = (f"{met} of {tasks} targets met{where}, largest residual {largest:.4g}; "
                f"{len(self.moved_bones)} bones keyed")
        inside, crossing = int(np.sum(self.joints_inside)), int(np.sum(self.segments_crossing))
        if inside or crossing:
            line += f"; obstacles: {inside} joints inside, {crossing} bones crossing"
        unmet = [(f, e) for f, e in zip(*np.nonzero(self.constrained & ~self.met))]
        if unmet:
            f, e = unmet[0]
            line += f"; {self.effectors[e]}: {self.reasons[f, e]}"
        return line
