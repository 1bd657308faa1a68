"""Which limbs are on the character's own left, from its skeleton (no bpy).

The facing comes from the body, never from the object's axes (solver/body/facing.py, the one calculation the
retarget's heading and the rest hinges use too): up is world z (the rig's orientation applied); the two hip
joints give the lateral line; forward is across it, on the side the toes point to (the heads of the foot's
descendants, seen from the ankle), else the side the knees bend to (a knee's offset from the line hip joint -
ankle), with the foot bones' own direction as a last hint. Left = up x forward (a character facing -Y has its
left at +X).

Side markers in names still count. When the names mark the two sides consistently (every mapped bone of one
side L, of the other R) and the skeleton's facing is unclear, the names decide. When the skeleton's facing is
clear (both feet's toes agree, or both knees and both foot bones do) and the names say the opposite, the
skeleton decides: such a rig's labels are mirrored (the Godot platformer robot's ``l-`` bones lie on its right,
its toes and knees point to -Y), and arm.L must be the arm on the character's own left for a left-hand target or
a source's left arm to drive it. Without names and without any sign of facing, the convention of Blender's front
view is kept: the body faces -Y, the side towards +X is left (towards +Y for a rig turned exactly sideways).
"""

from dataclasses import dataclass

import numpy as np

from ..solver.body.facing import UP, skeleton_facing
from ..solver.body.facing import lateral as lateral_across


@dataclass(frozen=True)
class Limb:
    """One limb's joints as bone indices: ``chain`` base first, ``end`` the hand or foot bone (None: an arm
    without a hand bone, whose wrist is the end of its last bone, ``end_point``)."""

    chain: tuple
    end: int | None


def end_point(sk, limb):
    """The limb's last joint (the wrist, the ankle): its end bone's head, else its last bone's end."""
    return sk.heads[limb.end] if limb.end is not None else sk.ends[limb.chain[-1]]


def lateral(sk, leg0, leg1):
    """Unit horizontal vector from leg 1 to leg 0 (hip joints, else knees, else ankles), or None."""
    return lateral_across(UP, [(_joint(sk, leg0, k), _joint(sk, leg1, k)) for k in range(3)], sk.tiny)


def _joint(sk, leg, k):
    """Hip joint (0), knee (1) or ankle (2) of a leg."""
    return sk.heads[leg.chain[0] if k == 0 else leg.chain[-1] if k == 1 else leg.end]


def facing(sk, legs):
    """(sign, clear): the body faces sign * (up x lat) (0: no sign of it), lat = lateral(sk, *legs); clear when
    the toes of both feet agree, or both knees and both foot bones do (solver/body/facing.py)."""
    joints = [[_joint(sk, leg, k) for leg in legs] for k in range(3)]
    below = [sk.heads[[c for c in sk.subtree(leg.end).tolist() if c != leg.end]] for leg in legs]
    feet = [sk.tails[leg.end] - sk.heads[leg.end] for leg in legs]
    found = skeleton_facing(UP, joints[0], joints[2], below, sk.tiny, knees=joints[1], feet=feet)
    return found.sign, found.clear


def _names(sk, limbs):
    """The one side marker all the limbs' bones carry ('L'/'R'), else None."""
    marks = {sk.name_sides[b] for limb in limbs for b in (*limb.chain, limb.end) if b is not None} - {None}
    return marks.pop() if len(marks) == 1 else None


def left_pair(sk, legs, arms):
    """Sides of two limb pairs: ``legs`` (leg 0, leg 1) and ``arms`` (arm 0 on leg 0's side, arm 1), each a
    Limb (``arms`` may be None). Returns which pair (0 or 1) is on the character's left (module docstring)."""
    lat = lateral(sk, *legs)
    names = [_names(sk, [legs[k]] + ([arms[k]] if arms else [])) for k in (0, 1)]
    named = names[0] is not None and names[1] is not None and names[0] != names[1]
    if lat is None:
        return names.index("L") if named else 0  # the legs are not side by side
    sign, clear = facing(sk, legs)
    # Facing sign * (up x lat): left = up x forward = -sign * lat, so pair 0 (at +lat) is left when sign < 0.
    geometric = None if sign == 0 else (0 if sign < 0 else 1)
    if named:
        by_name = names.index("L")
        if clear and geometric != by_name:
            return geometric  # the skeleton's facing, against mirrored side names
        return by_name
    if geometric is not None:
        return geometric
    return 0 if float(lat @ np.array([1.0, 1e-3, 0.0])) > 0 else 1  # no sign of facing: +X is left
