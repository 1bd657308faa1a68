"""How high the body stands. rise.fold_room: a held foot nearer its hip than the leg can fold (a long shin on a short
thigh, the knee at its limit) raises the whole body, smoothly, until every held or blending foot lies at least the
folded distance from its hip; a foot blending into its hold rises partly with the body, and the rise takes that
into account."""

import numpy as np

from fullbody_adjust.solver.retarget import rise

FRAMES, STEP, INNER = 40, 0.02, 0.3


def _case():
    bases = np.zeros((FRAMES, 4, 3))
    bases[..., 2] = 1.0  # shoulders and hips 1 m up
    free = bases + [0.0, 0.0, -0.5]  # every hand and foot 0.5 below its base
    squat = 0.5 - 0.4 * np.sin(np.linspace(0.0, np.pi, FRAMES))  # the held foot up to 0.1 below its hip
    held_point = np.stack([np.full(FRAMES, 0.05), np.zeros(FRAMES), 1.0 - squat], axis=1)
    weight = np.clip(np.concatenate([np.linspace(0.0, 1.0, 8), np.ones(FRAMES - 16), np.linspace(1.0, 0.0, 8)]),
                     0.0, 1.0)  # blended in and out over 7 frames

    def held(paths):
        out = paths.copy()
        out[:, 3] = weight[:, None] * held_point + (1.0 - weight[:, None]) * paths[:, 3]  # foot.R held
        return out

    fixed = np.zeros((FRAMES, 4), dtype=bool)
    fixed[:, 3] = weight > 0.0
    return held, free, bases, fixed


def _nearest(held, free, bases, shift):
    return np.linalg.norm(held(free + shift[:, None]) - bases - shift[:, None], axis=-1)[:, 3]


def test_the_body_rises_until_the_held_foot_is_as_far_from_its_hip_as_the_leg_folds():
    held, free, bases, fixed = _case()
    shift = np.zeros((FRAMES, 3))
    shift[:, 0] = np.linspace(0.0, 0.1, FRAMES)  # a shift already found, which the rise keeps
    inner = np.full(4, INNER)
    before = _nearest(held, free, bases, shift)
    assert before[fixed[:, 3]].min() < 0.2  # the foot 0.1 below its hip at the deepest: nearer than the leg folds
    out = rise.fold_room(held, free, bases, shift, fixed, inner, STEP)
    after = _nearest(held, free, bases, out)
    assert after[fixed[:, 3]].min() >= INNER * (1.0 - 1e-6)
    np.testing.assert_array_equal(out[:, :2], shift[:, :2])  # only up
    lift = out[:, 2] - shift[:, 2]
    assert lift.min() >= 0.0 and np.abs(np.diff(lift)).max() <= STEP * (1.0 + 1e-9)  # smoothly
    assert lift[0] == 0.0 and lift[-1] == 0.0  # nothing held there
    assert lift.max() > np.sqrt(INNER ** 2 - 0.05 ** 2) - 0.1 - 1e-9  # at least what the deepest frame needs


def test_nothing_moves_where_every_held_foot_is_far_enough():
    held, free, bases, fixed = _case()
    shift = np.zeros((FRAMES, 3))
    out = rise.fold_room(held, free, bases, shift, fixed, np.full(4, 0.05), STEP)
    np.testing.assert_array_equal(out, shift)

