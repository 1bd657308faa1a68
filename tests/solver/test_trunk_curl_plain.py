"""The trunk's curl chord for a few trunks (solver/trunk_curl_plain.py, plain floats) against the numpy path
(solver/trunk_curl.py): the same bits for spines of 3 and 4 segments, shared or per-row shares, targets straight
along the spine (the bend axis from the spine's own curve, or any perpendicular of a straight spine)."""

import numpy as np
import pytest

from fullbody_adjust.solver import trunk_curl, trunk_curl_plain


@pytest.mark.parametrize("segments", [3, 4])
def test_a_few_trunks_get_the_bits_of_the_numpy_path(segments):
    rng = np.random.default_rng(segments)
    seen_moved = 0
    for trial in range(120):
        b = 1 + trial % trunk_curl_plain._FEW_CHAINS
        steps = np.array([0.0, 0.0, 0.12]) + 0.04 * rng.normal(size=(b, segments, 3))
        if trial % 10 == 1:
            steps[0] = [0.0, 0.0, 0.12]  # a straight spine
        chains = np.concatenate([np.zeros((b, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
        targets = chains[:, -1] + rng.normal(size=(b, 3)) * 0.2
        if trial % 5 == 2:
            targets[0] = 1.3 * chains[0, -1]  # straight along the spine's chord
        shares = rng.uniform(0.2, 1.0, segments) if trial % 2 else rng.uniform(0.2, 1.0, (b, segments))
        expected = trunk_curl.curl_chord(chains, targets, shares)
        got = trunk_curl_plain.curl_chord(chains, targets, shares)
        np.testing.assert_array_equal(got, expected, err_msg=f"trial {trial}")
        seen_moved += int(np.any(expected != np.linalg.norm(chains[:, -1] - chains[:, 0], axis=1)))
    assert seen_moved > 100  # the chords are the bent ones, not the start's
