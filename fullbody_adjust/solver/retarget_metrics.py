"""Measures of a retargeted motion: smoothness (pops show as spikes of the change of velocity)."""

from __future__ import annotations

import numpy as np

from .geometry import norm


def roughness(positions, scale=1.0):
    """Per joint, the largest frame-to-frame change of velocity |p[f+1] - 2 p[f] + p[f-1]| / scale over the
    frames: positions (F,J,3) -> (J,). A pop shows as a spike far above the motion's own roughness."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 3:
        return np.zeros(positions.shape[1])
    second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
    return norm(second).max(axis=0) / scale


def angular_roughness(rotations):
    """Per bone, the largest change of angular velocity between frames: the angle (radians) between
    consecutive frame-to-frame rotations, rotations (F,J,3,3) -> (J,)."""
    r = np.asarray(rotations, dtype=np.float64)
    if len(r) < 3:
        return np.zeros(r.shape[1])
    step = r[1:] @ np.swapaxes(r[:-1], -1, -2)  # (F-1,J,3,3) rotation from one frame to the next
    change = step[1:] @ np.swapaxes(step[:-1], -1, -2)
    cos = np.clip((np.trace(change, axis1=-2, axis2=-1) - 1.0) * 0.5, -1.0, 1.0)
    return np.arccos(cos).max(axis=0)
