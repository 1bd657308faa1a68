"""solver/retarget/foot_pivots.py: which point of a planted foot stays put from one frame to the next."""

from types import SimpleNamespace

import numpy as np

from fullbody_adjust.solver.retarget import foot_pivots as fp
from fullbody_adjust.solver.retarget.contacts import intervals


def _turned(points, angle, about):
    """points (P,3) turned by ``angle`` about the horizontal X axis through ``about`` (3,)."""
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return (points - about) @ r.T + about


def _rolling_foot(frames=30, seed=3):
    """A foot (ankle, heel, ball, toe tip) pitching toes-down by up to 40 degrees about points that drift, as a
    transferred pose does: (ankle (F,3), sole (F,3,3): heel, toe tip, ball; ball (F,3))."""
    rng = np.random.default_rng(seed)
    rest = np.array([[0.0, 0.0, 0.08], [0.0, -0.05, 0.0], [0.0, 0.16, 0.0], [0.0, 0.12, 0.02]])
    angles = -np.radians(np.linspace(1.0, 40.0, frames))  # toes down
    drift = np.cumsum(rng.normal(0.0, 0.004, (frames, 3)), axis=0)
    posed = np.array([_turned(rest, a, rest[3]) + d for a, d in zip(angles, drift)])
    return posed[:, 0], posed[:, 1:], posed[:, 3]


def test_the_pinned_joint_keeps_its_place_and_elsewhere_the_lowest_point_does():
    ankle, sole, ball = _rolling_foot()
    pinned = np.zeros(len(ankle), dtype=bool)
    pinned[:18] = True  # the ball held; then the foot rolls onto its toe tip
    travel = fp.roll(ankle, sole, ball, pinned, 1e-12)
    moved = travel - (ankle[:, :2] - ankle[0, :2])  # how far the path shifts the transferred foot
    ball_path = ball[:, :2] + moved
    assert np.abs(ball_path[:18] - ball_path[0]).max() < 1e-12
    assert np.abs(ball_path[18:] - ball_path[0]).max() > 1e-3  # not pinned there: the foot turns on its toes
    tip_path = sole[:, 1, :2] + moved  # the toe tip is the lowest point once the foot pitches
    lowest = sole[:, :, 2].argmin(axis=1)
    assert (lowest[17:-1] == 1).all()
    assert np.abs(np.diff(tip_path[17:], axis=0)).max() < 1e-12


def test_without_pins_the_lowest_point_is_the_pivot():
    ankle, sole, ball = _rolling_foot()
    travel = fp.roll(ankle, sole, ball, np.zeros(len(ankle), dtype=bool), 1e-12)
    moved = travel - (ankle[:, :2] - ankle[0, :2])
    lowest = sole[:-1, :, 2].argmin(axis=1)
    for f, p in enumerate(lowest):
        step = (sole[f + 1, p, :2] + moved[f + 1]) - (sole[f, p, :2] + moved[f])
        assert np.abs(step).max() < 1e-12


def test_where_only_the_ankle_is_held_the_ankle_stays():
    """A heel stand or swivel: the source holds its ankle still but not its ball; the target's ankle keeps its
    place there (the lowest point of the sole would drag it), while the ball, where held, still wins."""
    ankle, sole, ball = _rolling_foot()
    pinned = np.zeros(len(ankle), dtype=bool)
    pinned[20:] = True
    ankle_pinned = np.zeros(len(ankle), dtype=bool)
    ankle_pinned[:12] = ankle_pinned[22:] = True
    travel = fp.roll(ankle, sole, ball, pinned, 1e-12, ankle_pinned)
    assert np.abs(travel[:12]).max() < 1e-15  # the ankle's own travel from its first frame: none
    moved = travel - (ankle[:, :2] - ankle[0, :2])
    ball_path = ball[:, :2] + moved
    assert np.abs(ball_path[20:] - ball_path[20]).max() < 1e-12  # both held: the ball
    unpinned = fp.roll(ankle, sole, ball, pinned, 1e-12)
    assert np.abs(unpinned[:12]).max() > 1e-3  # the lowest point alone would have moved it
    np.testing.assert_array_equal(fp.roll(ankle, sole, ball, pinned, 1e-12, np.zeros(len(ankle), dtype=bool)),
                                  unpinned)


def test_held_still_is_slow_and_low():
    fps = 24.0
    z = np.concatenate([np.full(10, 0.02), 0.02 + 0.01 * np.arange(1, 11)])  # still, then rising 0.24 m/s
    track = np.stack([np.zeros(20), np.zeros(20), z], axis=1)
    held = fp.held_still(track, fps, speed=0.2, height=0.06)
    assert held[:10].all() and not held[10:].any()
    slow_but_high = track.copy()
    slow_but_high[10:, 2] = 0.5
    slow_but_high[10:, 1] = 0.001 * np.arange(10)
    held = fp.held_still(slow_but_high, fps, speed=0.2, height=0.06)
    assert held[:9].all() and not held[11:].any()


def test_the_ball_is_the_farthest_bone_below_the_ankle():
    # root, shin, foot (ankle at the origin), heel 6 cm behind, toes 12 cm ahead, a toe tip below the toes
    heads = np.array([[0, 0, 1.0], [0, 0, 0.5], [0, 0, 0.08], [0, 0.06, 0.02], [0, -0.12, 0.02], [0, -0.16, 0.0]])
    rest = np.tile(np.eye(4), (len(heads), 1, 1))
    rest[:, :3, 3] = heads
    rig = SimpleNamespace(groups={"foot.L": (2,)}, parents=np.array([-1, 0, 1, 2, 2, 4]), rest=rest)
    assert fp.ball_bone(rig, "foot.L") == 4
    rig.parents = np.array([-1, 0, 1, -1, -1, -1])
    assert fp.ball_bone(rig, "foot.L") is None


def test_a_target_without_toes_holds_its_ankle_where_the_sources_ball_is_held():
    heads = np.array([[0, 0, 1.0], [0, 0, 0.5], [0, 0, 0.08], [0, -0.12, 0.02]])  # root, shin, ankle, toes
    rest = np.tile(np.eye(4), (len(heads), 1, 1))
    rest[:, :3, 3] = heads

    def rig(parents):
        return SimpleNamespace(groups={"foot.L": (2,)}, parents=np.array(parents), rest=rest)

    toes, no_toes = rig([-1, 0, 1, 2]), rig([-1, 0, 1, -1])
    assert fp.pivot_bone(toes, toes, "foot.L") == (3, 3)  # ball and ball
    assert fp.pivot_bone(toes, no_toes, "foot.L") == (3, 2)  # the source's ball, the target's ankle
    assert fp.pivot_bone(no_toes, toes, "foot.L") == (2, 2)  # the source's ankle says when: the ankles


def test_a_frame_the_joint_comes_to_rest_on_is_held():
    """The frame a ball arrives on (fast before, still after) and the one it leaves from are still as a viewer sees
    them: the mean of both steps (0.3 m/s here) would leave them out, and the foot would turn about its sole there."""
    fps = 24.0
    y = 0.025 * np.concatenate([np.arange(10), np.full(10, 10), 10 + np.arange(1, 11)])  # 0.6 m/s, still, 0.6 m/s
    track = np.stack([np.zeros(30), y, np.full(30, 0.02)], axis=1)
    held = fp.held_still(track, fps, speed=0.2, height=0.06)
    assert held[10:20].all() and not held[:10].any() and not held[20:].any()
    central = np.linalg.norm(np.gradient(track, axis=0), axis=1) * fps
    assert central[10] > 0.2 and central[19] > 0.2  # what central differences would have said


def test_a_ball_is_held_as_the_foot_pitches_onto_its_toes_but_not_on_a_heel_stand():
    """The ball held still while it rises a little over a plant's height: held where the heel lifts more (toes
    down), not where the toes are raised about a still ankle (a heel stand: the ankle is what stays), nor, within
    a plant's height, where the ball has risen over half of it more than the ankle (the toes coming up)."""
    fps, height = 24.0, 0.04
    lift = np.concatenate([np.zeros(8), np.linspace(0.0, 0.05, 8), np.full(8, 0.05)])  # 5 cm: over 4, under 6
    still = np.zeros(24)
    ball = np.stack([still, still, 0.02 + lift], axis=1)
    ball[:, 1] += 0.0005 * np.arange(24)  # creeping at 12 mm/s
    heel_up = np.stack([still, still - 0.12, 0.08 + 2.0 * lift], axis=1)
    heel_down = np.stack([still, still - 0.12, np.full(24, 0.08)], axis=1)
    toes_down = fp.pivot_held(ball, heel_up, fps, speed=0.2, height=height)
    heel_stand = fp.pivot_held(ball, heel_down, fps, speed=0.2, height=height)
    plain = fp.held_still(ball, fps, speed=0.2, height=height)
    assert toes_down.all()
    assert not plain[16:].any()  # 5 cm up: over the plant's height
    np.testing.assert_array_equal(heel_stand, plain & (lift <= fp._HEEL_STAND * height))
    assert heel_stand[:11].all() and not heel_stand[11:].any()  # the toes 2.1 cm up from frame 11


def _twist_steps(length, cycles=4, turn=30.0, frames_per_turn=4):
    """A foot of ``length`` (ankle above its heel, the ball ahead) twist-stepping sideways as a dancer does: it
    swivels by ``turn`` degrees about its ball (pinned), then back about its heel (its ball lifted, the heel its
    lowest point), ``cycles`` times. Returns (ankle (F,3), sole (F,2,3): heel, ball; ball (F,3), pinned (F,))."""
    angles, pinned = [0.0], [True]
    for _ in range(cycles):
        for k in range(1, frames_per_turn + 1):
            angles.append(np.radians(turn) * k / frames_per_turn)
            pinned.append(True)
        for k in range(1, frames_per_turn + 1):
            angles.append(np.radians(turn) * (1.0 - k / frames_per_turn))
            pinned.append(False)
    angles = np.array(angles)
    ball = np.stack([length * np.cos(angles), length * np.sin(angles), np.where(pinned, 0.0, 0.01)], axis=1)
    ankle = np.tile([0.0, 0.0, 0.05], (len(angles), 1))
    heel = np.zeros((len(angles), 3))
    return ankle, np.stack([heel, ball], axis=1), ball, np.array(pinned)


def test_a_held_foot_drifting_off_its_free_trajectory_is_held_in_pieces():
    # The free trajectory: the ankle of a source's foot a third as long, twist-stepping the same way (its ankle
    # travels with its own foot's swivels); the target's longer foot, held, travels three times as far.
    small = _twist_steps(0.05)
    free = fp.roll(small[0], small[1], small[2], small[3], 1e-12)
    ankle, sole, ball, pinned = _twist_steps(0.15)
    travel = fp.roll(ankle, sole, ball, pinned, 1e-12)
    apart = float(np.linalg.norm(np.ptp(travel - free, axis=0)))
    assert apart > 0.12  # held whole, its ends lie this far from where the body's motion puts them
    largest = 0.1
    pieces = fp.drifting_pieces(travel, free, pinned, largest)
    runs = intervals(pinned)
    assert len(runs) > 2 and len(pieces) == len(runs)
    assert pieces[0][0] == 0 and pieces[-1][1] == len(free)  # from the contact's start to its stop
    assert [p[0] for p in pieces[1:]] == [r[0] for r in runs[1:]]  # each held stretch on its own
    for a, b in pieces:  # each piece, centred on its free trajectory, stays near it
        offset = travel[a:b] - free[a:b]
        assert np.linalg.norm(np.ptp(offset, axis=0)) <= largest
    # A target foot as long as the source's follows its free trajectory: held whole.
    assert fp.drifting_pieces(free, free, pinned, largest) == [(0, len(free))]
    assert fp.drifting_pieces(travel, free, pinned, 1.1 * apart) == [(0, len(free))]


def test_a_foot_on_its_ball_whose_toes_twitch_about_a_still_ankle_keeps_its_ankle():
    """The CMU dance's left foot: heel up (the ankle 10 cm above its lowest place in the clip), the ankle still, the
    toes twitching 15 degrees about it every other frame. Its ball is not held on those frames, nor is its ankle
    low; the target's ankle stays (ankle_held at any height) instead of swinging about its sole's lowest point as
    the toes twitch."""
    fps, speed, height, frames = 30.0, 0.25, 0.08, 24
    yaw = np.zeros(frames)
    yaw[6:18:2] = np.radians(15.0)  # the twitch: every other frame
    c, s = np.cos(yaw), np.sin(yaw)
    zero, up = np.zeros(frames), np.tile([0.0, 0.0, 1.0], (frames, 1))
    turn = np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), up], 1)
    ankle = np.tile([0.0, 0.0, 0.17], (frames, 1))
    foot = np.array([[0.0, -0.05, -0.1], [0.0, 0.2, -0.17], [0.0, 0.13, -0.115]])  # heel, toe tip, ball: from the ankle
    sole = ankle[:, None] + np.einsum("fij,pj->fpi", turn, foot)
    sole[:, 0, 2] += 0.06  # the heel up: the toe tip is the lowest point
    ball = sole[:, 2]
    ankle_z = np.concatenate([ankle, np.tile([0.0, 0.0, 0.07], (frames, 1))])  # flat elsewhere in the clip
    pinned = fp.pivot_held(ball, ankle, fps, speed, height)
    held = fp.ankle_held(ankle_z, np.concatenate([pinned, np.ones(frames, dtype=bool)]), fps, speed, height, 3)[:frames]
    assert not pinned[6:17].any() and held.all()  # the ball held only from where its twitches end
    travel = fp.roll(ankle, sole, ball, pinned, 1e-12, held)
    assert np.abs(travel).max() < 1e-12
    swinging = fp.roll(ankle, sole, ball, pinned, 1e-12)  # about the sole's lowest point: the ankle swings
    assert np.abs(np.diff(swinging, axis=0)).max() > 0.03
