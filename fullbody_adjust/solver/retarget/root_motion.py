# SPDX-License-Identifier: GPL-3.0-or-later
"""Root motion: a hips world trajectory split into the root's travel (horizontal, along the floor) and turn
(about the vertical, world +Z), and what the hips keep relative to it (height, tilt, sway). Pure numpy.

The split of one frame is a rigid motion M of the world: a turn by ``yaw`` about the vertical through the hips'
rest head, then a horizontal shift taking that head to the hips' horizontal position on the frame. M is the
identity at rest; M^-1 @ hips (the residual) has the hips' rest horizontal position and no turn about the
vertical, only the height and the tilt (the swing of a swing-twist split about +Z). Because world = M @
residual exactly, moving the root (a bone above the hips, or the armature object) by M and the body by the
residual leaves every bone where it was; dropping M (in place) leaves the body at its rest place and heading.

The turn is the twist about +Z of the hips' rotation relative to their rest (2 atan2(q_z, q_w) of its
quaternion), unwrapped over the frames so a clip that turns round several times turns the root as far.

With a smoothing ``window`` (frames; the bridge's seconds times the clip's frame rate) the root follows the hips'
ground path and heading smoothed (``smooth``): steady travel and turn, as a game engine moves a character, while
the hips keep, relative to the root, their side-to-side sway, the back-and-forth of each step and their yaw
wobble. Without one (0) the root follows them exactly and the hips keep only height and tilt.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import affine_inverse
from ..maths.rotation_channels import quaternions_of

UP = np.array([0.0, 0.0, 1.0])
# Seconds the root's path is smoothed over: a walking stride (two steps, 1-1.2 s at 100-120 steps a minute) is the
# period of the hips' side-to-side sway and yaw wobble, each step's back-and-forth its half; 1.2 s leaves under 7%
# of them on the root for strides from a run's 0.7 s to a slow walk's 2 s (``smooth``), while a turn or a change
# of speed over 4 s is 79% followed, over 6 s 95%.
DEFAULT_SMOOTHING = 1.2  # seconds


@dataclass(frozen=True)
class RootTravel:
    """The root's motion per frame: ``matrices`` (F,4,4) world rigid motions M (identity at rest), ``travel``
    (F,3) the root's horizontal shift of the hips' rest head (z = 0), ``yaw`` (F,) radians about +Z, unwrapped;
    the hips' own (smoothed, unless the window is 0)."""

    matrices: np.ndarray
    travel: np.ndarray
    yaw: np.ndarray


def _rotations(matrices):
    """The rotations (…,3,3) of affine matrices (…,4,4), each column's (uniform) scale removed."""
    linear = np.asarray(matrices, dtype=np.float64)[..., :3, :3]
    return linear / np.linalg.norm(linear, axis=-2, keepdims=True)


def split_travel(hips, hips_rest, window=0.0):
    """RootTravel of the hips' world matrices ``hips`` (F,4,4) against their world rest matrix ``hips_rest``
    (4,4): the root on the hips' ground path and heading, smoothed over ``window`` frames (``smooth``; 0: followed
    exactly). SolverInputError on shapes that do not fit, NaN/inf or a negative window."""
    hips = np.asarray(hips, dtype=np.float64)
    hips_rest = np.asarray(hips_rest, dtype=np.float64)
    if hips.ndim != 3 or hips.shape[1:] != (4, 4) or hips_rest.shape != (4, 4) or len(hips) == 0:
        raise SolverInputError(f"root motion needs hips (F,4,4) and their rest (4,4), got {hips.shape} and "
                               f"{hips_rest.shape}")
    if not (np.all(np.isfinite(hips)) and np.all(np.isfinite(hips_rest))):
        raise SolverInputError("root motion: the hips' matrices have NaN/inf")
    relative = _rotations(hips) @ _rotations(hips_rest).T  # world rotation from rest, (F,3,3)
    q = quaternions_of(relative)
    yaw = np.unwrap(2.0 * np.arctan2(q[:, 3], q[:, 0]))  # continuous through +-180 degrees, so it smooths
    centre = hips_rest[:3, 3] * (1.0, 1.0, 0.0)
    place = hips[:, :3, 3] * (1.0, 1.0, 0.0)
    steady = smooth(np.column_stack([place[:, :2], yaw]), window)
    place[:, :2], yaw = steady[:, :2], steady[:, 2]
    return RootTravel(matrices=turn_and_shift(yaw, centre, place), travel=place - centre, yaw=yaw)


def smooth(values, window):
    """``values`` (F,…), one sample a frame, with the oscillations of period ``window`` frames or shorter removed
    (SolverInputError if ``window`` is negative or not finite; under 1 frame: unchanged).

    Each frame's value is a weighted parabola fit to the frames around it (a local quadratic regression), the
    weights a triangle four ``window`` wide (a moving average over two windows applied twice). No lag (symmetric);
    a steady travel, turn or acceleration kept exactly, on every frame to the clip's ends, and a steady curve
    nearly (a 1.3 m/s walk turning 20 degrees a second moved in by 4 mm, where a straight-line fit cuts 55 mm). Away from
    the ends the gain is under 7% for every period up to 1.25 windows, 22% at 2 windows, 88% at 4 windows. At the
    ends, and in a clip shorter than the window, the fit uses the frames there are (one frame: its value; two: the
    line through them)."""
    window = float(window)
    if not np.isfinite(window) or window < 0.0:
        raise SolverInputError(f"root motion: the smoothing window must be 0 or more frames, got {window}")
    values = np.asarray(values, dtype=np.float64)
    half = int(round(2.0 * window)) - 1  # the triangle reaches this many frames each side
    if half < 1 or len(values) < 2:
        return values.copy()
    degree = 2 if half >= 2 and len(values) >= 3 else 1  # every frame's fit has degree + 1 frames or more
    box = np.ones(half + 1)
    kernel = np.convolve(box, box)  # (2 half + 1,)
    offsets = np.arange(-half, half + 1, dtype=np.float64) / half  # in [-1, 1]: a well conditioned fit

    def sums(samples, weights):  # per frame t: sum over d of weights[d] * samples[t + d], out of the clip 0
        return np.convolve(np.pad(samples, half), weights[::-1], mode="valid")

    inside = np.ones(len(values))
    moments = [sums(inside, kernel * offsets ** k) for k in range(2 * degree + 1)]
    normal = np.stack([np.stack(moments[i:i + degree + 1], axis=-1) for i in range(degree + 1)], axis=-2)
    flat = values.reshape(len(values), -1)
    fitted = np.stack([np.stack([sums(flat[:, c], kernel * offsets ** k) for k in range(degree + 1)], axis=-1)
                       for c in range(flat.shape[1])], axis=-1)  # (F, degree + 1, C)
    out = np.linalg.solve(normal, fitted)[:, 0]  # the fitted parabola's value at the frame itself
    return out.reshape(values.shape)


def turn_and_shift(yaw, centre, place):
    """(F,4,4) rigid motions: a turn by ``yaw`` (F,) about the vertical through ``centre`` (3,), then the shift
    taking ``centre`` to ``place`` (F,3)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((len(yaw), 4, 4))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
    out[:, 2, 2] = out[:, 3, 3] = 1.0
    out[:, :3, 3] = np.asarray(place, dtype=np.float64) - out[:, :3, :3] @ np.asarray(centre, dtype=np.float64)
    return out


def in_armature_space(motions, matrix_world):
    """World motions M (F,4,4) as they act in an armature's space: W^-1 @ M @ W (a left factor of its
    armature-space pose matrices). W may scale (uniformly) and turn: the result stays rigid."""
    world = np.asarray(matrix_world, dtype=np.float64)
    return affine_inverse(world) @ np.asarray(motions, dtype=np.float64) @ world


def residual(motions, matrices):
    """M^-1 @ matrices: (F,4,4) motions, (F,…,4,4) matrices (world, or armature space with
    in_armature_space motions), what is left of them when the root carries M."""
    inverse = affine_inverse(np.asarray(motions, dtype=np.float64))
    matrices = np.asarray(matrices, dtype=np.float64)
    return inverse.reshape(inverse.shape[:1] + (1,) * (matrices.ndim - 3) + (4, 4)) @ matrices
