"""How far the whole body rises over a retargeted motion's planned targets (see solver/retarget/plan.py): over the
floor where no foot is held (airborne_raise), and where a held foot lies nearer its hip than the leg folds
(fold_room); both rise and fall at a bounded speed (let_go)."""

from __future__ import annotations

import numpy as np

from ..limits.human import HumanLimits
from .rig import EFFECTORS, FEET


def airborne_raise(free, soles, floor, contacts, step):
    """(F,) how far the whole body rises on the frames no foot holds a contact (a run's flight, an in-place
    clip's sliding stance) where the floor would lift a foot (``free`` (F,E,3) its ankle, ``soles`` (F,2) the
    ankles above their soles): the legs keep the source's angles, where lifting the ankle alone bends the knee
    for a few frames. It rises and falls at the blend speed (``step`` a frame) around those frames."""
    feet = [EFFECTORS.index(e) for e in FEET]
    need = np.maximum(floor + soles - free[:, feet, 2], 0.0).max(axis=1)
    need[contacts[:, feet].any(axis=1)] = 0.0
    return np.maximum(let_go(need, step), let_go(need[::-1], step)[::-1])


def folded(upper, lower, bend=HumanLimits().knee[1]):
    """The distance from the base of a limb of segments ``upper`` and ``lower`` to its end, bent by ``bend``
    (radians; by default as far as limits.human lets a knee bend) at the hinge between them."""
    return float(np.sqrt(max(upper ** 2 + lower ** 2 + 2.0 * upper * lower * np.cos(bend), 0.0)))


def fold_room(held, free, bases, shift, fixed, inner, step, rounds=8):
    """The body's shift (F,3) ``shift`` raised so that every foot held or blending to a hold (``fixed`` (F,E))
    lies at least ``inner`` (E,) from its limb's base (``bases`` (F,E,3) before the shift; its targets
    ``held(free + shift)``, free trajectories (F,E,3)): a leg folds no closer than its knee bends (folded),
    far from its hip where the shin is much longer than the thigh (Godot's robot's, twice as long, squatting on
    the climb's bar with its knee bent 159 degrees as the source's: its ankle held a little higher above its
    sole than the source's, its knee could not fold to reach it, and the leg flipped). A rise keeps the target's
    horizontal offset from its base, and rises and falls at ``step`` a frame around those frames (let_go). A
    blending target rises partly with the body: the rise is found again, ``rounds`` times at most."""
    feet = [EFFECTORS.index(e) for e in FEET]
    wanted = np.zeros(len(shift))
    out = shift
    for _ in range(rounds):
        offset = (held(free + out[:, None]) - bases - out[:, None])[:, feet]
        across = np.minimum(np.hypot(offset[..., 0], offset[..., 1]), inner[feet])
        need = np.where(fixed[:, feet], offset[..., 2] + np.sqrt(inner[feet] ** 2 - across ** 2), 0.0)
        need = np.maximum(need, 0.0).max(axis=1)  # the target below its base: the base rises away from it
        if not need.max() > 1e-6 * inner.max():
            break
        wanted += need
        out = shift.copy()
        out[:, 2] += np.maximum(let_go(wanted, step), let_go(wanted[::-1], step)[::-1])
    return out


def let_go(lift, step):
    """The least lift (F,) at least ``lift`` on every frame that falls by at most ``step`` a frame: a foot raised
    over the floor (a long foot pitched at toe-off: KayKit's ankle up to 122 mm above its free path) is let
    down at the blend's speed, not the moment its sole clears the floor (a shin turning 30.9 degrees in one
    frame). It rises as ``lift`` does."""
    frames = np.arange(len(lift)) * step
    return np.maximum.accumulate(lift + frames) - frames
