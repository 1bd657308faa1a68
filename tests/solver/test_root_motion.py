"""solver/retarget/root_motion.py: a hips trajectory split into the root's turn about the vertical and horizontal
travel, and the residual the hips keep; checked against trajectories built from a known split."""

import numpy as np
import pytest

from fullbody_adjust.solver import SolverInputError
from fullbody_adjust.solver.retarget import root_motion as rm


def rotation(axis, angle):
    """(…,3,3) rotations by ``angle`` (…) about the unit ``axis`` (3,) (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    angle = np.asarray(angle, dtype=np.float64)[..., None, None]
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def matrices(rot, loc):
    out = np.zeros(rot.shape[:-2] + (4, 4))
    out[..., :3, :3], out[..., :3, 3], out[..., 3, 3] = rot, loc, 1.0
    return out


def walk(frames=200, turns=2.5, seed=3):
    """A hips trajectory (F,4,4) built from a known root motion (yaw about +Z, horizontal place) and a residual
    that tilts (about horizontal axes only), bobs and keeps the rest horizontal place; and its rest (4,4),
    turned and placed off the origin."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, frames)
    yaw = 2.0 * np.pi * turns * t + 0.2 * np.sin(9.0 * t)
    place = np.stack([3.0 * t + 0.05 * np.sin(20.0 * t), 2.0 * t ** 2, np.zeros_like(t)], axis=1)
    rest = matrices(rotation(rng.normal(size=3), 0.7), np.array([0.1, -0.2, 0.95]))
    tilt_axis = np.stack([np.cos(5.0 * t), np.sin(5.0 * t), np.zeros_like(t)], axis=1)
    tilt = np.stack([rotation(a, 0.3 * np.sin(7.0 * s)) for a, s in zip(tilt_axis, t)])
    residual = matrices(tilt @ rest[:3, :3], rest[:3, 3] + np.stack([0 * t, 0 * t, 0.04 * np.sin(30 * t)], 1))
    motion = rm.turn_and_shift(yaw, rest[:3, 3] * (1, 1, 0), place)
    return motion @ residual, rest, yaw, place - rest[:3, 3] * (1, 1, 0), residual


def test_the_split_recovers_the_turn_and_travel_it_was_built_from():
    hips, rest, yaw, travel, residual = walk()
    split = rm.split_travel(hips, rest)
    assert np.abs(split.yaw - yaw).max() < 1e-9  # 2.5 turns, unwrapped
    assert np.abs(split.travel - travel).max() < 1e-12
    assert np.abs(rm.residual(split.matrices, hips) - residual).max() < 1e-9
    assert np.abs(split.matrices @ rm.residual(split.matrices, hips) - hips).max() < 1e-12  # exactly the motion


def test_at_rest_the_root_does_not_move():
    _, rest, _, _, _ = walk()
    split = rm.split_travel(np.stack([rest, rest]), rest)
    assert np.abs(split.matrices - np.eye(4)).max() < 1e-12 and np.abs(split.yaw).max() < 1e-12


def test_in_armature_space_acts_as_the_world_motion_does():
    hips, rest, _, _, _ = walk(frames=20)
    world = matrices(rotation([1.0, 0.0, 0.0], np.pi / 2) * 0.01, np.array([1.0, 2.0, 0.5]))  # FBX-like
    armature_poses = np.linalg.inv(world) @ hips
    motion = rm.split_travel(hips, rest).matrices
    local = rm.in_armature_space(motion, world)
    assert np.abs(world @ rm.residual(local, armature_poses) - rm.residual(motion, hips)).max() < 1e-12
    assert np.abs(local[:, :3, :3] @ np.swapaxes(local[:, :3, :3], 1, 2) - np.eye(3)).max() < 1e-12  # rigid


@pytest.mark.parametrize("hips, rest", [(np.zeros((0, 4, 4)), np.eye(4)), (np.zeros((3, 3, 3)), np.eye(4)),
                                        (np.full((2, 4, 4), np.nan), np.eye(4))])
def test_bad_input_is_one_error(hips, rest):
    with pytest.raises(SolverInputError):
        rm.split_travel(hips, rest)
