"""Splitting a limb found by detection (detection) into its groups' bones, from joint positions (bone
heads): a leg into thigh, shin and foot, an arm into clavicle, upper arm, forearm and hand. No bpy."""

import math

import numpy as np

from . import body_sides
from .rig_description import DOWN, MIDLINE, angle_between

SIDE_WORDS = {"L": "left", "R": "right"}
# Thresholds (fractions of the rig's height unless said otherwise), chosen on the rigs in the tests.
LEG_MIN_DROP = 0.2  # hip joint to ankle (thigh and shin; between the lowest joints of the two legs and the root)
_DOWNWARD = math.radians(40.0)  # a thigh segment is within this of straight down (hip connectors are not) ...
_SWUNG = math.radians(65.0)  # ... or within this when it is long:
_LONG_SEGMENT = 0.25  # at least this fraction of the path from the hips down
_ANKLE_HEIGHT = 0.25  # the ankle is below this fraction of the hip joint's height above the leg's lowest point
_UPPER_TO_FOREARM = 1.15  # typical upper arm / forearm length ratio
_HAND_TO_FOREARM = (0.25, 1.3)  # range of (wrist to fingertip) / forearm length
_HAND_WEIGHT = 0.5  # weight of a hand length outside that range (per unit of log ratio)
_NOT_A_HAND = 0.25  # penalty for a hand bone with one child that is not one of fingers fanning out from the wrist
_LEAF_HAND_FIT = 0.5  # worst arm score accepted with a hand bone that ends the path (its length unknown) ...
_LEAF_HAND = 0.1  # ... and the penalty for not knowing it
_CLAVICLE = 0.45  # a clavicle is at most this fraction of the upper arm and forearm together
_ARM_FIT_LIMIT = 0.7  # worst accepted arm score (0.7: upper arm / forearm twice or half the usual ratio)


class NotFound(Exception):
    """Detection found no bones for ``group``; ``detail`` says where it stopped; ``line``, when given, says all
    of it (``detection.missing_message``)."""

    def __init__(self, group, detail="", line=None):
        super().__init__(group, detail)
        self.group, self.detail, self.line = group, detail, line


def segments(sk, path):
    """Joints (heads) of a path, the segments between them and their lengths."""
    joints = sk.heads[path]
    segments = joints[1:] - joints[:-1]
    return joints, segments, np.linalg.norm(segments, axis=1)


def split_leg(sk, path, s):
    """Limb([thigh, shin], foot) on a path from the hips down to the lowest bone of one leg."""
    names, group = sk.desc.names, f"leg.{s}"
    if not path:
        raise NotFound(group, f"the {SIDE_WORDS[s]} leg shares all its bones with the other")
    joints, seg, length = segments(sk, path)
    total = float(length.sum())
    # Thigh: the first clearly downward segment (skips hip-joint connectors like CMU LHipJoint, Daz lButtock).
    i = 0
    # A long segment may lean further (a thigh swung forward in a rest taken mid-stride).
    while i < len(seg) and (length[i] <= max(0.05 * total, sk.tiny) or angle_between(seg[i], DOWN) > (
            _DOWNWARD if length[i] < _LONG_SEGMENT * total else _SWUNG)):
        i += 1
    if len(path) - i < 2:
        raise NotFound(group, f"no chain of 2+ bones goes down from '{names[path[0]]}'")
    # Foot: the first bone after thigh and shin whose head (the ankle) is close to the leg's lowest point, or
    # in the leg's lower half where the path turns forward (a tall foot, as on a plush toy).
    low = joints[i:, 2].min()
    hip = joints[i, 2] - low
    foot = next((k for k in range(i + 2, len(path)) if joints[k, 2] - low < _ANKLE_HEIGHT * hip or (
        k < len(seg) and joints[k, 2] - low < 0.5 * hip and angle_between(seg[k], DOWN) > _DOWNWARD)), None)
    if foot is None:
        raise NotFound(f"foot.{s}", f"the {SIDE_WORDS[s]} leg ends at '{names[path[-1]]}' with no foot below it",
                       _loose_foot(sk, path[i:], SIDE_WORDS[s]))
    reach = float(length[i:foot].sum())
    if reach < LEG_MIN_DROP * sk.height:
        raise NotFound(group, f"from '{names[path[i]]}' to '{names[path[foot]]}' is only {reach:.3g} long")
    # Knee: the joint that halves the way from hip joint to ankle (thigh and shin are about equally long).
    before = np.concatenate([[0.0], np.cumsum(length[i:foot])])
    knees = [k for k in range(i + 1, foot) if length[k] > sk.tiny]
    if not knees:
        raise NotFound(group, f"no knee between '{names[path[i]]}' and '{names[path[foot]]}'")
    knee = min(knees, key=lambda k: abs(before[k - i] / before[-1] - 0.5))
    return body_sides.Limb((path[i], path[knee]), path[foot])


def _loose_foot(sk, leg, side):
    """The line that names a foot bone at the leg's end but outside it (an IK-style foot hanging from the rig's
    root, as on Quaternius' characters) and why the rig cannot be used so, or None."""
    names, hip, last = sk.desc.names, sk.heads[leg[0]], sk.heads[leg[-1]]
    length = float(np.linalg.norm(last - hip))
    # Where the ankle would be: as far below the last joint as the leg is long so far, straight down.
    ankle = last + length * DOWN
    near = [b for b in range(len(sk.desc)) if not sk.is_ancestor(leg[-1], b) and b not in leg
            and np.linalg.norm(sk.heads[b] - ankle) < 0.4 * length]
    if not near:
        return None
    foot = min(near, key=lambda b: (np.linalg.norm(sk.heads[b] - ankle), sk.depth[b]))
    parent = sk.parent[foot]
    where = f"hangs from '{names[parent]}'" if parent >= 0 else "has no parent"
    return (f"its {side} foot '{names[foot]}' {where}, not below the leg's last bone '{names[leg[-1]]}' (an "
            f"IK-style foot), so a moved leg would leave the mesh's foot behind; parent '{names[foot]}' to "
            f"'{names[leg[-1]]}' (Keep Offset) to use this rig")


def split_arm(sk, path, s, clavicle=None):
    """Limb([clavicle?, upper arm, forearm], hand) on the longest path out from the chest; the hand None when
    the arm has no hand bone (fingers fanning out of the forearm, or nothing below it: ``_handless``).

    Every split of the path into clavicle (optional, one bone), upper arm and forearm (each possibly several
    bones, as with twist bones) and hand + fingers is scored by how far it is from a human arm: upper arm about
    1.15 forearms, hand + fingers 0.25..1.3 forearms (head to head; unknown for a hand bone that ends the path,
    which then must fit the arm closer); a hand bone that is neither a branch (fingers) nor where fingers
    branch is a twist or wrist link, less likely, and so is a forearm with a branching bone inside. ``clavicle``
    (True/False) says whether the path's first bone is a clavicle, when the caller knows. The best split wins (on a
    tie the earlier wrist); when nothing fits, the arm may end at its forearm (``_handless``), else the hand or the
    arm is reported missing.
    """
    names = sk.desc.names
    _, _, length = segments(sk, path)
    # Path length from each joint (head) to the tip: the last bone's own length when it is a believable leaf.
    after = np.concatenate([np.cumsum(length[::-1])[::-1], [0.0]]) + sk.leaf_reach[path[-1]]

    def arm_fit(first, elbow, wrist):
        upper = float(after[first] - after[elbow])
        fore = float(after[elbow] - after[wrist])
        if min(upper, fore) <= sk.tiny:
            return math.inf
        return abs(math.log(upper / fore / _UPPER_TO_FOREARM))

    # The upper arm starts at the first or second bone (after a clavicle).
    best = (math.inf, None)
    for wrist in range(2, len(path)):
        if sk.end_marker[path[wrist]]:
            continue
        kids = [c for c in sk.children[path[wrist]] if not sk.end_marker[c]]
        link = len(kids) == 1 and not _fans_out(sk, path[wrist])
        ends = after[wrist] <= sk.tiny  # the hand bone ends the path, its length unknown
        for first in range(min(2, wrist - 1)):
            if clavicle is not None and first != int(clavicle):
                continue
            for elbow in range(first + 1, wrist):
                fit = arm_fit(first, elbow, wrist)
                if first and length[0] > _CLAVICLE * (after[first] - after[wrist]):
                    continue
                fore, hand = float(after[elbow] - after[wrist]), float(after[wrist])
                if fit == math.inf or (ends and fit > _LEAF_HAND_FIT):
                    continue
                # Bones branching between elbow and wrist: the split's forearm runs on into the hand's fingers.
                branched = any(len(sk.children[path[k]]) > 1 for k in range(elbow + 1, wrist))
                score = fit + (_NOT_A_HAND if link else 0.0) + (_NOT_A_HAND if branched else 0.0) + (
                    _LEAF_HAND if ends else _HAND_WEIGHT * max(
                    0.0, math.log(_HAND_TO_FOREARM[0] * fore / hand), math.log(hand / (_HAND_TO_FOREARM[1] * fore))))
                if score < best[0] - 1e-9:
                    best = (score, (first, elbow, wrist))
    if best[0] > _ARM_FIT_LIMIT:
        handless = _handless(sk, path, clavicle, after)
        if handless is not None:
            return handless
        if len(path) <= 3:
            raise NotFound(f"hand.{s}", f"the {SIDE_WORDS[s]} arm ends at '{names[path[-1]]}' with no hand "
                                        f"below it")
        raise NotFound(f"arm.{s}", f"the bones from the chest to '{names[path[-1]]}' are not shaped like an arm")
    first, elbow, wrist = best[1]
    chain = ([path[0]] if first > 0 else []) + [path[first], path[elbow]]
    # Fingers fanning out of the forearm (no hand bone, as in Quaternius' rigs): the hand is what hangs there, all
    # of it riding on the forearm, and the wrist is the forearm's end (where the fingers start).
    fingers = elbow == wrist - 1 and _fans_out(sk, path[wrist])
    return body_sides.Limb(tuple(chain), None if fingers else path[wrist])


def _handless(sk, path, clavicle, after):
    """Limb([clavicle?, upper arm, forearm], None) for an arm of 2 or 3 bones that ends at its forearm (a robot's
    arm: no hand bone, nothing below the forearm), the wrist being the forearm's end (``_Skeleton.ends``), when
    upper arm and forearm are in an arm's proportions (and a first of 3 bones is a clavicle); else None."""
    first = len(path) - 2
    if first not in (0, 1) or (clavicle is not None and first != int(clavicle)):
        return None
    fore = float(np.linalg.norm(sk.ends[path[-1]] - sk.heads[path[-1]]))
    upper = float(after[first] - after[first + 1])
    if min(upper, fore) <= sk.tiny or (first and after[0] - after[1] > _CLAVICLE * (upper + fore)):
        return None
    if abs(math.log(upper / fore / _UPPER_TO_FOREARM)) > _ARM_FIT_LIMIT:
        return None
    return body_sides.Limb(tuple(path), None)


def _fans_out(sk, b):
    """b is one of 3+ bones starting at the same point (fingers hanging straight from the forearm, as in
    Quaternius' rigs): its head is then the wrist though it has one child."""
    parent = sk.parent[b]
    if parent < 0:
        return False
    near = [c for c in sk.children[parent]
            if np.linalg.norm(sk.heads[c] - sk.heads[b]) <= MIDLINE * sk.height]
    return len(near) >= 3
