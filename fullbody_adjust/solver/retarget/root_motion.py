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
"""

from dataclasses import dataclass

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import affine_inverse
from ..maths.rotation_channels import quaternions_of

UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class RootTravel:
    """The root's motion per frame: ``matrices`` (F,4,4) world rigid motions M (identity at rest), ``travel``
    (F,3) the hips' horizontal shift from their rest head (z = 0), ``yaw`` (F,) radians about +Z, unwrapped."""

    matrices: np.ndarray
    travel: np.ndarray
    yaw: np.ndarray


def _rotations(matrices):
    """The rotations (…,3,3) of affine matrices (…,4,4), each column's (uniform) scale removed."""
    linear = np.asarray(matrices, dtype=np.float64)[..., :3, :3]
    return linear / np.linalg.norm(linear, axis=-2, keepdims=True)


def split_travel(hips, hips_rest):
    """RootTravel of the hips' world matrices ``hips`` (F,4,4) against their world rest matrix ``hips_rest``
    (4,4). SolverInputError on shapes that do not fit or NaN/inf."""
    hips = np.asarray(hips, dtype=np.float64)
    hips_rest = np.asarray(hips_rest, dtype=np.float64)
    if hips.ndim != 3 or hips.shape[1:] != (4, 4) or hips_rest.shape != (4, 4) or len(hips) == 0:
        raise SolverInputError(f"root motion needs hips (F,4,4) and their rest (4,4), got {hips.shape} and "
                               f"{hips_rest.shape}")
    if not (np.all(np.isfinite(hips)) and np.all(np.isfinite(hips_rest))):
        raise SolverInputError("root motion: the hips' matrices have NaN/inf")
    relative = _rotations(hips) @ _rotations(hips_rest).T  # world rotation from rest, (F,3,3)
    q = quaternions_of(relative)
    yaw = np.unwrap(2.0 * np.arctan2(q[:, 3], q[:, 0]))
    centre = hips_rest[:3, 3] * (1.0, 1.0, 0.0)
    place = hips[:, :3, 3] * (1.0, 1.0, 0.0)
    return RootTravel(matrices=turn_and_shift(yaw, centre, place), travel=place - centre, yaw=yaw)


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
