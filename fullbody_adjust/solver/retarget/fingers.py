"""Fingers carried over when both rigs have them (see solver/retarget/transfer.py): each finger of a target hand
pairs with the source's finger of the same name (thumb, index, middle, ring, pinky), bone k of the finger from
its base with bone k of the source's, and takes the source bone's rotation change as the limbs do (aligned by
the hand's alignment, then the minimal swing of its rest segment onto the source's). A finger the source lacks,
and bones past the end of the source's finger, keep their own local pose."""

from __future__ import annotations

import re

import numpy as np

from ..maths.geometry import norm, swing_rotation

FINGERS = {"thumb": ("thumb",), "index": ("index",), "middle": ("middle",), "ring": ("ring",),
           "pinky": ("pinky", "little")}
_WORD = {finger: re.compile("|".join(words), re.IGNORECASE) for finger, words in FINGERS.items()}


def finger_chains(rig, hand):
    """{finger: bone indices, base first} of the bones below the hand bone ``hand`` whose names say which
    finger they belong to."""
    below = rig.descendants(hand)[1:]
    out = {}
    for finger, word in _WORD.items():
        bones = [b for b in below if word.search(rig.names[b])]
        if bones:
            out[finger] = bones  # descendants come parents first
    return out


def finger_pairs(source, target, s_dirs, t_dirs, hand_alignment):
    """[(target bone, source bone, alignment (3,3))] of both hands' fingers. ``s_dirs``/``t_dirs`` (J,3): the
    rigs' world rest segment directions; ``hand_alignment`` {side: (3,3)} each hand pair's alignment."""
    out = []
    for side, alignment in hand_alignment.items():
        hand = f"hand.{side}"
        if not source.groups.get(hand) or not target.groups.get(hand):
            continue
        s_chains = finger_chains(source, source.groups[hand][0])
        for finger, t_bones in finger_chains(target, target.groups[hand][0]).items():
            for t, s in zip(t_bones, s_chains.get(finger, ())):
                turn = alignment
                if norm(t_dirs[t]) > 0.0 and norm(s_dirs[s]) > 0.0:
                    turn = swing_rotation(alignment @ t_dirs[t], s_dirs[s]) @ alignment
                out.append((t, s, np.asarray(turn, dtype=np.float64)))
    return out
