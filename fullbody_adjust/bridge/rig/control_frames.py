"""A control rig's solved pose over frames: on each frame the controls are placed (control_match) so the bones they
drive reach the solve, and the channels of the controls that moved are returned for keying."""

import numpy as np

from . import control_match
from .control_match import read_channels


# A control counts as moved when an entry of its local matrix changed by more than this: its channels are
# float32, so an untouched control reads back bit for bit.
_CONTROL_MOVED = 1e-7

# Each rig's IK chains' stretch samples (chain_steps.record_stretch), {rig's session_uid: {chain's first bone: up to
# chain_steps._SAMPLES}}, kept across the current frame's placements (a Live update's, a click's: control_channels):
# a chain's stretch is a function of its target's distance, and a Live drag's updates stand close to each other.
# Only which scale is tried first depends on them (every sweep's closing evaluation checks), but where it lands
# within the tolerances does: frames keyed in a row (a retarget, Adjust Frames) start from none, so their keys do
# not depend on what ran before. _STRETCH_RIGS bounds how many rigs.
_STRETCH = {}
_STRETCH_RIGS = 16


def control_channels(obj, view_layer, pairs, bones, desired, tolerance, rows, start=None, evaluated=False):
    """The controls' channels that pose ``bones`` at ``desired`` (F,k,4,4 armature space) on each frame:
    {control: {property: (F,n)}} for the controls that moved on some frame, rotations continuous over frames.
    ``rows`` yields the frame rows in order (the caller may step the scene to each frame as it yields); the
    controls are left as placed for the last row. A control counts as moved when it ends a frame away from where
    it was before that frame's matching or, given ``start`` (the PoseSnapshot the solve started from), from where
    it was in that pose: Live matches from the controls it placed on the update before, and one that needs no
    further move is still part of the pose it shows. ``evaluated``: the rig is evaluated as it stands for the first
    row (match_controls)."""
    controls = list(dict.fromkeys(pair.control for pair in pairs))
    if len(_STRETCH) > _STRETCH_RIGS:
        _STRETCH.clear()
    stretch = _STRETCH.setdefault(obj.session_uid, {}) if evaluated else {}  # notes at _STRETCH
    out, moved = [], np.zeros(len(controls), dtype=bool)
    start_bases = None if start is None else start.channels["matrix_basis"][:, start.indices(controls)]
    for row in rows:
        before = _bases(obj, controls) if start_bases is None else start_bases[row]
        control_match.match_controls(obj, view_layer, pairs, dict(zip(bones, desired[row])), tolerance,
                       evaluated=evaluated and not out, stretch=stretch, predict=evaluated)
        moved |= np.abs(_bases(obj, controls) - before).max(axis=(1, 2)) > _CONTROL_MOVED
        out.append(read_channels(obj, controls, previous=out[-1] if out else None))
    return {c: {prop: np.stack([row[c][prop] for row in out]) for prop in out[0][c]}
            for c, m in zip(controls, moved) if m}


def _bases(obj, controls):
    return np.array([obj.pose.bones[c].matrix_basis for c in controls], dtype=np.float64)
