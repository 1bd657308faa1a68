"""The trunk's curl (solver/fullbody/trunk_curl.py): the spine bent about one axis, each joint by its share of one angle,
so that its end meets a target; the warm start of the trunk's chain solve and the lean's radius."""

import numpy as np

from fullbody_adjust.solver.fullbody.trunk_curl import curl_chord, curl_start

SHARES = np.array([1.0, 0.5, 0.25])


def spine(b=1):
    """A slightly curved four-joint spine (three segments of unequal length), repeated b times."""
    chain = np.array([[0.0, 0.0, 1.0], [0.0, 0.01, 1.14], [0.0, 0.015, 1.31], [0.0, 0.012, 1.5]])
    return np.repeat(chain[None], b, axis=0)


def segment_angles(chains):
    """(b,m) each segment's angle in the spine's plane (y, z; the spine bends about x)."""
    seg = np.diff(chains, axis=1)
    return np.arctan2(seg[..., 1], seg[..., 2])


def turn_of_segments(before, after):
    """(b,m) angle each segment turned from `before` to `after`."""
    a, b = np.diff(before, axis=1), np.diff(after, axis=1)
    cos = np.sum(a * b, axis=-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def lean_targets(chains, angles, distances):
    """Targets at `distances` from the base, turned forward by `angles` from the chains' base->end direction."""
    base, end = chains[:, 0], chains[:, -1]
    d = (end - base) / np.linalg.norm(end - base, axis=-1, keepdims=True)
    forward = np.cross(d, [1.0, 0.0, 0.0])
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    way = np.cos(angles)[:, None] * d + np.sin(angles)[:, None] * forward
    return base + distances[:, None] * way


def test_the_curl_meets_its_target_with_the_bones_kept():
    chains = spine(4)
    own = np.linalg.norm(chains[:, -1] - chains[:, 0], axis=-1)
    targets = lean_targets(chains, np.radians([5.0, 20.0, 40.0, 60.0]), own * np.array([1.0, 0.99, 0.95, 0.9]))
    out = curl_start(chains, targets, SHARES)
    np.testing.assert_allclose(out[:, -1], targets, atol=1e-9)
    np.testing.assert_array_equal(out[:, 0], chains[:, 0])
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=1), axis=-1),
                               np.linalg.norm(np.diff(chains, axis=1), axis=-1), rtol=1e-12)


def test_the_curl_shares_the_bend_as_asked():
    """Every joint bends about one axis by its share of one angle: from one segment to the next the turn grows
    by the next joint's share (the first joint's share and the turn that points the chain add up at joint 0)."""
    chains = spine(3)
    own = np.linalg.norm(chains[:, -1] - chains[:, 0], axis=-1)
    targets = lean_targets(chains, np.radians([10.0, 30.0, 50.0]), own * 0.93)
    out = curl_start(chains, targets, SHARES)
    turn = segment_angles(out) - segment_angles(chains)
    bend = np.diff(turn, axis=1)  # joints 1..
    assert np.all(np.abs(bend) > 1e-3)
    np.testing.assert_allclose(bend / bend[:, :1], np.broadcast_to(SHARES[1:] / SHARES[1], bend.shape), rtol=1e-9)


def test_leaning_at_the_curls_chord_starts_from_the_spine_as_it_is_and_moves_on_smoothly():
    """The lean's radius is the chord of the curl toward the lean point: no lean is the spine as it is, and as the
    lean grows each segment turns by an amount that grows smoothly with it (no joint jumps first)."""
    chains = spine(1)
    own = np.linalg.norm(chains[:, -1] - chains[:, 0], axis=-1)
    np.testing.assert_allclose(curl_chord(chains, chains[:, -1], SHARES), own, rtol=1e-12)
    np.testing.assert_allclose(curl_start(chains, chains[:, -1].copy(), SHARES), chains, atol=1e-12)

    angles = np.radians(np.linspace(0.0, 60.0, 61))
    many = np.repeat(chains, angles.size, axis=0)
    radius = own.copy() * np.ones(angles.size)
    for _ in range(3):  # the lean point and the chord settle together, as SubBasePlacement._place_sc does
        targets = lean_targets(many, angles, radius)
        radius = curl_chord(many, targets, SHARES)
    out = curl_start(many, lean_targets(many, angles, radius), SHARES)
    steps = turn_of_segments(out[:-1], out[1:])  # (frames-1, m): each segment's turn per degree of lean
    # A rigid lean would turn every segment by one degree per degree; a curl turns its top segment by the
    # ratio of its running share sum to the mean of them (the chord's turn), and does so on every step.
    ratio = np.cumsum(SHARES)[-1] / np.mean(np.cumsum(SHARES))
    assert np.degrees(steps.max()) <= ratio * 1.0 * 1.05
    assert np.degrees(steps[1:]).min() > 0.5  # every segment keeps turning
