"""solver/retarget/root_motion.py: a hips trajectory split into the root's turn about the vertical and horizontal
travel, and the residual the hips keep; checked against trajectories built from a known split (exact, window 0),
and from a steady root with a sway at the stride's period on it (smoothed)."""

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


@pytest.mark.parametrize("hips, rest, window", [
    (np.zeros((0, 4, 4)), np.eye(4), 0.0), (np.zeros((3, 3, 3)), np.eye(4), 0.0),
    (np.full((2, 4, 4), np.nan), np.eye(4), 0.0), (np.stack([np.eye(4)] * 3), np.eye(4), -1.0),
    (np.stack([np.eye(4)] * 3), np.eye(4), np.nan)])
def test_bad_input_is_one_error(hips, rest, window):
    with pytest.raises(SolverInputError):
        rm.split_travel(hips, rest, window)


@pytest.mark.parametrize("frames", [1, 2, 5, 100])
@pytest.mark.parametrize("window", [0.0, 3.0, 24.0, 500.0])
def test_smoothing_keeps_a_steady_line_to_the_clip_ends(frames, window):
    rng = np.random.default_rng(frames)
    start, slope = rng.normal(size=(2, 3))
    line = start + slope * np.arange(frames)[:, None]
    assert np.abs(rm.smooth(line, window) - line).max() < 1e-9 * max(1.0, np.abs(line).max())


def sines(frames, periods, amplitudes, phases):
    t = np.arange(frames, dtype=np.float64)[:, None]
    return (np.asarray(amplitudes) * np.sin(2.0 * np.pi * t / np.asarray(periods) + np.asarray(phases))).sum(axis=1)


def test_smoothing_removes_the_periods_up_to_the_window_and_keeps_slow_ones():
    window, frames = 30.0, 900
    inner = slice(int(2 * window), frames - int(2 * window))  # the triangle whole
    rng = np.random.default_rng(7)
    for ratio in np.linspace(0.25, 1.25, 21):  # periods from a quarter of the window to 1.25 windows
        phase = rng.uniform(0.0, 2.0 * np.pi)
        left = rm.smooth(sines(frames, [ratio * window], [1.0], [phase]), window)[inner]
        assert np.abs(left).max() < 0.07, (ratio, np.abs(left).max())
    slow = sines(frames, [4.0 * window], [1.0], [0.3])
    kept = rm.smooth(slow, window)[inner]
    gain = (kept @ slow[inner]) / (slow[inner] @ slow[inner])  # the slow wave's share left
    print(f"a period of 4 windows kept at {gain:.3f} of its amplitude")
    assert gain > 0.8 and np.abs(kept - gain * slow[inner]).max() < 0.01  # scaled, not shifted (no lag)


def swaying_walk(fps=30.0, seconds=8.0, stride=1.1, start_yaw=np.radians(170.0), speed=1.3, turn=0.35,
                 sway=0.04, surge=0.015, wobble=np.radians(6.0)):
    """Hips (F,4,4) over a steady root (constant speed and turn rate, from ``start_yaw``) plus, relative to it, a
    side-to-side sway and yaw wobble at the ``stride``'s period and a back-and-forth at half of it; their rest
    (4,4); the steady root's (F,4,4) motions and the sway (F,2) built (root frame, from the rest place)."""
    t = np.arange(int(seconds * fps)) / fps
    heading = start_yaw + turn * t
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    place = np.array([0.4, -1.0]) + np.concatenate([[[0.0, 0.0]], np.cumsum(direction[1:] * speed / fps, axis=0)])
    rest = matrices(rotation([0.2, 0.1, 1.0], 0.4), np.array([0.1, -0.2, 0.95]))
    centre = rest[:3, 3] * (1, 1, 0)
    root = rm.turn_and_shift(heading - start_yaw, centre, np.column_stack([place, 0.0 * t]))
    phase = 2.0 * np.pi * t / stride
    offset = np.stack([surge * np.sin(2.0 * phase + 0.5), sway * np.sin(phase)], axis=1) @ \
        np.array([[np.cos(start_yaw), np.sin(start_yaw)], [-np.sin(start_yaw), np.cos(start_yaw)]])
    own = matrices(rotation([0.0, 0.0, 1.0], wobble * np.sin(phase + 1.0)) @ rest[:3, :3],
                   rest[:3, 3] + np.column_stack([offset, 0.03 * np.sin(2.0 * phase)]))
    return root @ own, rest, root, offset


def accelerations(path, fps):
    return np.linalg.norm(np.diff(path, 2, axis=0), axis=-1) * fps ** 2


@pytest.mark.parametrize("turn", [0.0, 0.35])
def test_the_smoothed_root_travels_steadily_and_the_hips_keep_their_sway(turn):
    """Walking straight and on a curve (20 degrees a second): the root is the steady one the walk was built on
    (within a quarter of the sway where the window is whole, its acceleration off that root's a tenth of the
    hips'), and the hips keep the sway built, without drifting (measured where the window is whole)."""
    fps, stride = 30.0, 1.1
    hips, rest, built, sway = swaying_walk(fps, stride=stride, turn=turn)
    split = rm.split_travel(hips, rest, rm.DEFAULT_SMOOTHING * fps)
    own = rm.residual(split.matrices, hips)
    assert np.abs(split.matrices @ own - hips).max() < 1e-12  # the world motion unchanged, exactly
    inner = slice(int(2 * rm.DEFAULT_SMOOTHING * fps), len(hips) - int(2 * rm.DEFAULT_SMOOTHING * fps))
    root, steady = split.matrices[:, :2, 3], built[:, :2, 3]
    root_acc, hips_acc = accelerations(root - steady, fps), accelerations(hips[:, :2, 3] - steady, fps)
    off = np.linalg.norm(root - steady, axis=-1)
    yaw_off = np.degrees(np.abs(split.yaw - np.unwrap(np.arctan2(built[:, 1, 0], built[:, 0, 0]))))
    offset = (own[:, :2, 3] - rest[:2, 3])[inner]  # the hips' horizontal offset from their place on the root
    stride_frames = int(stride * fps)  # the mean offset over the first and the last stride
    drift = np.linalg.norm(offset[-stride_frames:].mean(axis=0) - offset[:stride_frames].mean(axis=0))
    print(f"turn {turn} rad/s: root acceleration off the steady root's rms {np.sqrt(np.mean(root_acc ** 2)):.3f} "
          f"m/s2 (the hips' {np.sqrt(np.mean(hips_acc ** 2)):.3f}); root off it max {off[inner].max() * 1e3:.2f} mm "
          f"({off.max() * 1e3:.2f} mm at the ends), heading {yaw_off[inner].max():.2f} deg ({yaw_off.max():.2f}); "
          f"the hips' offset range {np.ptp(offset, axis=0) * 1e3} mm (built {np.ptp(sway[inner], axis=0) * 1e3}), "
          f"drift "
          f"{drift * 1e3:.2f} mm")
    assert np.sqrt(np.mean(root_acc ** 2)) < 0.1 * np.sqrt(np.mean(hips_acc ** 2))
    assert off[inner].max() < 0.25 * np.abs(sway).max() and yaw_off[inner].max() < 0.5
    assert np.abs(np.ptp(offset, axis=0) - np.ptp(sway[inner], axis=0)).max() < 0.25 * np.ptp(sway, axis=0).min()
    assert drift < 0.1 * np.abs(sway).max()


def test_turning_on_the_spot_through_180_degrees():
    """Three turns on the spot from 170 degrees, a 6 degree wobble on them: the root turns steadily (no jump at
    +-180), as far as the turn built (within the wobble at the ends, 0.5 degree where the window is whole), and
    stays where it is."""
    fps, wobble = 60.0, 6.0
    hips, rest, built, _ = swaying_walk(fps, seconds=5.0, speed=0.0, turn=4.0, sway=0.0, surge=0.0,
                                        wobble=np.radians(wobble))
    split = rm.split_travel(hips, rest, rm.DEFAULT_SMOOTHING * fps)
    off = np.degrees(np.abs(split.yaw - np.unwrap(np.arctan2(built[:, 1, 0], built[:, 0, 0]))))
    inner = slice(int(2 * rm.DEFAULT_SMOOTHING * fps), len(hips) - int(2 * rm.DEFAULT_SMOOTHING * fps))
    steps = np.degrees(np.diff(split.yaw))
    print(f"on the spot: the root turns {np.degrees(split.yaw[-1] - split.yaw[0]):.1f} deg in steps of "
          f"{steps.min():.3f}..{steps.max():.3f} deg, off the turn built by {off[inner].max():.3f} deg "
          f"({off.max():.3f} at the ends), moves {np.ptp(split.travel, axis=0).max() * 1e3:.4f} mm")
    assert steps.min() > 0.0 and steps.max() < 2.0 * np.degrees(4.0) / fps
    assert off.max() < wobble and off[inner].max() < 0.5 and np.ptp(split.travel, axis=0).max() < 1e-9
    assert np.abs(split.matrices @ rm.residual(split.matrices, hips) - hips).max() < 1e-12


@pytest.mark.parametrize("frames", [1, 2, 3, 10])
def test_a_clip_shorter_than_the_window(frames):
    hips, rest, _, _ = swaying_walk(30.0, seconds=frames / 30.0)
    split = rm.split_travel(hips, rest, 100.0)
    assert np.all(np.isfinite(split.matrices))
    assert np.abs(split.matrices @ rm.residual(split.matrices, hips) - hips).max() < 1e-12
    if frames == 1:  # one frame: the root is where the exact split puts it
        assert np.abs(split.matrices - rm.split_travel(hips, rest).matrices).max() < 1e-12
