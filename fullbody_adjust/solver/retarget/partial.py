# SPDX-License-Identifier: GPL-3.0-or-later
"""A partial retarget: which bones belong to the body groups asked for (numpy only).

The five body groups are the paper's IK groups (solver/vocabulary.CHAIN_GROUPS but the head): the trunk carries
the root (pelvis) and the head with it, each arm its hand, each leg its foot; a bone outside the map (a finger, a
toe, a twist bone) goes with its nearest mapped ancestor."""

import numpy as np

from ..vocabulary import CHAIN_GROUPS
from .rig import basis_from_pose, forward_kinematics

BODY_GROUPS = tuple(g for g in CHAIN_GROUPS if g != "head")
_PART_OF = {"root": "trunk", "trunk": "trunk", "head": "trunk", "arm.L": "arm.L", "hand.L": "arm.L",
            "arm.R": "arm.R", "hand.R": "arm.R", "leg.L": "leg.L", "foot.L": "leg.L", "leg.R": "leg.R",
            "foot.R": "leg.R"}


def parse_groups(text):
    """The body groups named in ``text`` (comma separated, any case), in BODY_GROUPS order; ValueError (one
    line) on an unknown or missing name."""
    by_lower = {g.lower(): g for g in BODY_GROUPS}
    names = [name.strip() for name in str(text).split(",")]
    unknown = [name for name in names if name.lower() not in by_lower]
    if unknown:
        raise ValueError(f"unknown body group '{unknown[0]}' (use {', '.join(BODY_GROUPS)})")
    asked = {by_lower[name.lower()] for name in names}
    return tuple(g for g in BODY_GROUPS if g in asked)


def body_group_of_bones(rig):
    """(J,) the body group of each bone ('' above the map: a bone with no mapped ancestor)."""
    out = np.full(len(rig.names), "", dtype=object)
    for group, bones in rig.groups.items():
        out[list(bones)] = _PART_OF.get(group, "")
    for j, parent in enumerate(rig.parents):  # parents come first
        if not out[j] and parent >= 0:
            out[j] = out[parent]
    return out


def bones_in_groups(rig, groups, bones):
    """The bones among ``bones`` (indices) that belong to ``groups``, in the order given."""
    part = body_group_of_bones(rig)
    return [int(b) for b in bones if part[int(b)] in set(groups)]


def combined_pose(rig, carried_pose, own_pose, bones):
    """Armature-space pose matrices (F,J,4,4) of a partial retarget as written: ``bones`` take their local
    transform from ``carried_pose`` (the retarget's), every other bone from ``own_pose`` (the target's own
    motion), each under its parent as combined."""
    every = np.arange(len(rig.names))
    basis = np.array(basis_from_pose(rig, np.asarray(own_pose, dtype=np.float64), every))
    basis[:, list(bones)] = basis_from_pose(rig, np.asarray(carried_pose, dtype=np.float64), list(bones))
    return forward_kinematics(rig, basis)
