"""Mapping a rig by shape: the groups found from the hierarchy, the rest positions and side markers alone (no
preset names), for rigs no preset knows."""

import math

import numpy as np

from .bone_map import BoneMap, MappingError
from .preset_matching import looked_for
from . import body_sides
from .rig_description import DOWN, MIDLINE, UP, angle_between

_WHAT = {
    "root": "hips (root) bone", "trunk": "upright trunk", "arm.L": "left arm", "arm.R": "right arm",
    "hand.L": "left hand", "hand.R": "right hand", "leg.L": "left leg", "leg.R": "right leg",
    "foot.L": "left foot", "foot.R": "right foot",
}
_SIDE_WORDS = {"L": "left", "R": "right"}
_SHAPE = {
    "root": "a bone where two legs and a spine branch",
    "trunk": "a chain rising from the hips to where both arms branch",
    **{f"arm.{s}": f"a chain of 2+ bones reaching out from the chest on the {w} side" for s, w in _SIDE_WORDS.items()},
    **{f"hand.{s}": f"a bone at the end of the {w} arm" for s, w in _SIDE_WORDS.items()},
    **{f"leg.{s}": f"a chain of 2+ bones going down from the hips on the {w} side" for s, w in _SIDE_WORDS.items()},
    **{f"foot.{s}": f"a bone at the end of the {w} leg, at the ankle" for s, w in _SIDE_WORDS.items()},
}
# Order in which missing groups are reported, and how far detection got when it failed at a group.
REPORT_ORDER = ("root", "leg.L", "leg.R", "foot.L", "foot.R", "trunk", "arm.L", "arm.R", "hand.L", "hand.R")
STAGE = {"root": 0, "leg.L": 1, "leg.R": 1, "foot.L": 2, "foot.R": 2, "trunk": 3, "arm.L": 4, "arm.R": 4,
          "hand.L": 5, "hand.R": 5}

# Detection thresholds (fractions of the rig's height unless said otherwise), chosen on the rigs in the tests.
_UP_BRANCH_RISE = 0.15  # the spine branch reaches at least this far above the root's head
_LEG_MIN_DROP = 0.2  # hip joint to ankle
_TRUNK_MIN_RISE = 0.15  # root head to the arms' bases
_BODY_TO_LEGS = 0.5  # what rises above the root (trunk, head) is at least this many leg lengths high
_DOWNWARD = math.radians(40.0)  # a thigh segment is within this of straight down (hip connectors are not)
_ANKLE_HEIGHT = 0.25  # the ankle is below this fraction of the hip joint's height above the leg's lowest point
_UPWARD = math.radians(45.0)  # neck/head segments are within this of straight up
_UPPER_TO_FOREARM = 1.15  # typical upper arm / forearm length ratio
_HAND_TO_FOREARM = (0.25, 1.3)  # range of (wrist to fingertip) / forearm length
_HAND_WEIGHT = 0.5  # weight of a hand length outside that range (per unit of log ratio)
_NOT_A_HAND = 0.25  # penalty for a hand bone with one child that is not one of fingers fanning out from the wrist
_LEAF_HAND_FIT = 0.5  # worst arm score accepted with a hand bone that ends the path (its length unknown) ...
_LEAF_HAND = 0.1  # ... and the penalty for not knowing it
_CLAVICLE = 0.45  # a clavicle is at most this fraction of the upper arm and forearm together
_ARM_FIT_LIMIT = 0.7  # worst accepted arm score (0.7: upper arm / forearm twice or half the usual ratio)
_HEAD_END_STEP = 0.08  # a neck step is shorter; a leaf this far above its parent's head marks the skull top


class NotFound(Exception):
    def __init__(self, group, detail=""):
        super().__init__(group, detail)
        self.group, self.detail = group, detail


def detect_map(desc):
    """Map a rig by the shape of its hierarchy, its rest positions and side markers only (no preset names):

    1. root: a branching bone (biggest subtree first) with a branch rising above it (the spine's) and, beside
       that branch, bones on both sides (name marker, else x sign relative to the root);
    2. legs: per side the path down to the lowest bone of that side: its first clearly downward bone is the
       thigh (hip connectors like CMU's LHipJoint are skipped), the first bone after thigh and shin whose head
       is near the leg's lowest point is the foot (the ankle), the joint halving the way between is the knee;
    3. trunk: the spine branch must rise at least half a leg length above the root; the chest is where the
       paths to the most lateral bone of each side part; the trunk runs from the root's child up to it, and
       the arms' bases must be above the root (more up than across);
    4. arms: the longest path out from the chest on each side, split by limb proportions (``_split_arm``);
       the wrists must be above the knees;
    5. head (optional): the unsided chain rising from the chest (``_find_head``).

    MappingError names what is missing, from the root candidate that got furthest
    (legs, then feet, trunk, arms, hands)."""
    if not len(desc):
        raise MappingError(f"Cannot map rig '{desc.name}': it has no bones")
    try:
        return detect(desc)
    except NotFound as failure:
        raise MappingError(missing_message(desc, failure.group, failure.detail)) from None


def detect(desc):
    sk = desc._skeleton
    # Root candidates: bones that branch, the biggest subtree first (the bone with most descendants
    # where the legs and the spine branch). The failure that got furthest is reported; on a tie the first.
    candidates = sorted((b for b in range(len(desc)) if len(sk.children[b]) >= 2),
                        key=lambda b: (-(sk.tout[b] - sk.tin[b]), sk.depth[b], b))
    best = None
    for root in candidates:
        try:
            groups = _detect_from_root(sk, root)
        except NotFound as failure:
            if best is None or STAGE[failure.group] > STAGE[best.group]:
                best = failure
            continue
        bone_map = BoneMap({g: [desc.names[b] for b in bones] for g, bones in groups.items()},
                           source="detected from the hierarchy")
        problems = bone_map.problems(desc)
        if not problems:
            return bone_map
        # Every group found, but they do not fit (e.g. a zero-length segment): report it with its group.
        group = problems[0].split(":")[0]
        best = NotFound(group if group in STAGE else "trunk", problems[0])
    raise best or NotFound("leg.L", "no bone branches into legs and a spine")


def _detect_from_root(sk, root):
    names = sk.desc.names
    up = max(sk.children[root], key=lambda c: sk.top[c])
    if sk.top[up] < sk.heads[root, 2] + _UP_BRANCH_RISE * sk.height:
        up = None
    upper = set(sk.subtree(up).tolist()) if up is not None else set()

    # Legs: the lowest bone hanging from the root outside the spine's branch, and the lowest one in another
    # leg (the two part well above both); sides are settled once the whole body is found.
    lower = [b for b in sk.subtree(root).tolist() if b != root and b not in upper]
    ends = _leg_ends(sk, root, lower)
    paths = [sk.path(root, e)[1:] for e in ends]
    shared = 0
    while shared < min(map(len, paths)) and paths[0][shared] == paths[1][shared]:
        shared += 1
    said = _said_sides(sk, paths[0], paths[1])
    legs = [_split_leg(sk, paths[k][shared:], said[k]) for k in (0, 1)]
    lat = body_sides.lateral(sk, *legs)
    if lat is None:
        raise NotFound(f"leg.{said[1]}", f"the legs ending at '{names[ends[0]]}' and '{names[ends[1]]}' are "
                                         f"not side by side")

    # Trunk: a branch rising above the root, at least half as high as the legs are long (not a neck).
    leg_length = np.mean([sk.heads[leg.chain[0], 2] - sk.heads[leg.end, 2] for leg in legs])
    above = (sk.top[up] if up is not None else sk.heads[root, 2]) - sk.heads[root, 2]
    if up is None or above < _BODY_TO_LEGS * leg_length:
        raise NotFound("trunk", f"only {above:.3g} rises above '{names[root]}', whose legs are "
                                 f"{leg_length:.3g} long")
    # Arms: the bone of the spine's branch furthest out on leg 0's side and on leg 1's; the chest is where
    # their paths part.
    mid = sk.heads[root]
    out = {b: float((sk.heads[b] - mid) @ lat) for b in upper}
    tips = [max(upper, key=lambda b: (out[b], sk.depth[b])), max(upper, key=lambda b: (-out[b], sk.depth[b]))]
    for k, sign in ((0, 1.0), (1, -1.0)):
        if sign * out[tips[k]] <= MIDLINE * sk.height:
            raise NotFound(f"arm.{said[k]}", f"nothing above '{names[root]}' reaches out on the side of "
                                              f"'{names[legs[k].chain[0]]}'")
    chest = sk.lca(*tips)
    if chest in tips:
        k = tips.index(chest)
        raise NotFound(f"arm.{said[k]}", f"the arm out to '{names[tips[k]]}' does not branch from the chest")
    trunk = sk.path(up, chest)
    arm_paths = [sk.longest_path(sk.path(chest, tip)[1]) for tip in tips]
    bases = np.mean([sk.heads[p[0]] for p in arm_paths], axis=0)
    hips = np.mean([sk.heads[leg.chain[0]] for leg in legs], axis=0)
    rise = bases[2] - hips[2]
    lean = float(np.linalg.norm(bases[:2] - mid[:2]))
    if rise < _TRUNK_MIN_RISE * sk.height or bases[2] - mid[2] < -lean:
        raise NotFound("trunk", f"from '{names[root]}' to '{names[chest]}' the spine does not rise "
                                 f"({rise:.3g} up from the hip joints, {lean:.3g} across)")
    # The legs say where the body faces: name the arms by the sides they are on.
    left = body_sides.left_pair(sk, legs, None).left
    said = ("L", "R") if left == 0 else ("R", "L")
    arms = [_split_arm(sk, arm_paths[k], said[k]) for k in (0, 1)]
    knees = np.mean([sk.heads[leg.chain[-1], 2] for leg in legs])
    for k in (0, 1):
        if sk.heads[arms[k].end, 2] <= knees:
            raise NotFound(f"arm.{said[k]}", f"'{names[arm_paths[k][0]]}' hangs down to the knees (a leg?)")

    sides = body_sides.left_pair(sk, legs, arms)
    shoulders = np.mean([sk.heads[arm.chain[-2], 2] for arm in arms])
    head = _find_head(sk, chest, {p[0] for p in arm_paths}, shoulders, bases, lat)
    groups = {"root": [root], "trunk": _with_length(sk, trunk) if trunk else []}
    for k in (0, 1):
        s = "L" if k == sides.left else "R"
        groups[f"arm.{s}"] = _with_length(sk, list(arms[k].chain), sk.heads[arms[k].end])
        groups[f"hand.{s}"] = [arms[k].end]
        groups[f"leg.{s}"], groups[f"foot.{s}"] = list(legs[k].chain), [legs[k].end]
    if head:
        groups["head"] = head
    return groups


def _leg_ends(sk, root, lower):
    """The lowest bones of two legs: they part at a bone well above both (toes and heels of one foot do not)."""
    names = sk.desc.names
    if not lower:
        raise NotFound("leg.L", f"no bones hang from '{names[root]}' beside the spine")
    order = sorted(lower, key=lambda b: (sk.heads[b, 2], -sk.depth[b], b))
    first = order[0]
    drop = _LEG_MIN_DROP * sk.height
    for other in order[1:]:
        top = sk.heads[sk.lca(first, other), 2]
        if top - sk.heads[first, 2] >= drop and top - sk.heads[other, 2] >= drop:
            return first, other
    side = sk.name_sides[first] or "L"
    other = "R" if side == "L" else "L"
    raise NotFound(f"leg.{other}", f"one leg goes down from '{names[root]}' to '{names[first]}', no second one")


def _said_sides(sk, path0, path1):
    """Sides to name two legs by in messages before the body's facing is known: their names' markers, else
    the side of +X (Blender's front view)."""
    marks = [{sk.name_sides[b] for b in p} - {None} for p in (path0, path1)]
    if len(marks[0]) == 1 and marks[0] != marks[1]:
        first = marks[0].pop()
    elif len(marks[1]) == 1:
        first = "R" if marks[1].pop() == "L" else "L"
    else:
        first = "L" if sk.heads[path0[-1], 0] >= sk.heads[path1[-1], 0] else "R"
    return (first, "R" if first == "L" else "L")


def _with_length(sk, chain, end=None):
    """The chain without bones whose segment (head to the next chain joint, ``end`` after the last) has no
    length: e.g. a helper bone sharing its child's head adds no joint. Without ``end`` (the trunk: where it
    ends is the solver's to say) the last bone stays."""
    if end is None:
        return _with_length(sk, chain[:-1], sk.heads[chain[-1]]) + chain[-1:]
    joints = np.concatenate([sk.heads[chain], np.asarray(end, dtype=np.float64)[None]])
    return [b for k, b in enumerate(chain) if np.linalg.norm(joints[k + 1] - joints[k]) > sk.tiny]


def _segments(sk, path):
    """Joints (heads) of a path, the segments between them and their lengths."""
    joints = sk.heads[path]
    segments = joints[1:] - joints[:-1]
    return joints, segments, np.linalg.norm(segments, axis=1)


def _split_leg(sk, path, s):
    """Limb([thigh, shin], foot) on a path from the hips down to the lowest bone of one leg."""
    names, group = sk.desc.names, f"leg.{s}"
    if not path:
        raise NotFound(group, f"the {_SIDE_WORDS[s]} leg shares all its bones with the other")
    joints, seg, length = _segments(sk, path)
    total = float(length.sum())
    # Thigh: the first clearly downward segment (skips hip-joint connectors like CMU LHipJoint, Daz lButtock).
    i = 0
    while i < len(seg) and (length[i] <= max(0.05 * total, sk.tiny) or angle_between(seg[i], DOWN) > _DOWNWARD):
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
        raise NotFound(f"foot.{s}", f"the {_SIDE_WORDS[s]} leg ends at '{names[path[-1]]}' with no foot "
                                    f"below it{_loose_foot(sk, path[i:])}")
    drop = joints[i, 2] - joints[foot, 2]
    if drop < _LEG_MIN_DROP * sk.height:
        raise NotFound(group, f"'{names[path[i]]}' reaches only {drop:.3g} down")
    # Knee: the joint that halves the way from hip joint to ankle (thigh and shin are about equally long).
    before = np.concatenate([[0.0], np.cumsum(length[i:foot])])
    knees = [k for k in range(i + 1, foot) if length[k] > sk.tiny]
    if not knees:
        raise NotFound(group, f"no knee between '{names[path[i]]}' and '{names[path[foot]]}'")
    knee = min(knees, key=lambda k: abs(before[k - i] / before[-1] - 0.5))
    return body_sides.Limb((path[i], path[knee]), path[foot])


def _loose_foot(sk, leg):
    """', and <bone> at its end hangs from <bone>' for a foot bone outside the leg (an IK-style foot), or ''."""
    names, hip, last = sk.desc.names, sk.heads[leg[0]], sk.heads[leg[-1]]
    length = float(np.linalg.norm(last - hip))
    # Where the ankle would be: as far below the last joint as the leg is long so far, straight down.
    ankle = last + length * DOWN
    near = [b for b in range(len(sk.desc)) if not sk.is_ancestor(leg[-1], b) and b not in leg
            and np.linalg.norm(sk.heads[b] - ankle) < 0.4 * length]
    if not near:
        return ""
    foot = min(near, key=lambda b: (np.linalg.norm(sk.heads[b] - ankle), sk.depth[b]))
    parent = sk.parent[foot]
    return (f" ('{names[foot]}', at its end, hangs from '{names[parent]}' instead: the body model needs the foot "
            f"below the shin)" if parent >= 0 else f" ('{names[foot]}', at its end, has no parent)")


def _split_arm(sk, path, s):
    """Limb([clavicle?, upper arm, forearm], hand) on the longest path out from the chest.

    Every split of the path into clavicle (optional, one bone), upper arm and forearm (each possibly several
    bones, as with twist bones) and hand + fingers is scored by how far it is from a human arm: upper arm about
    1.15 forearms, hand + fingers 0.25..1.3 forearms (head to head; unknown for a hand bone that ends the path,
    which then must fit the arm closer); a hand bone that is neither a branch (fingers) nor where fingers
    branch is a twist or wrist link, less likely, and so is a forearm with a branching bone inside. The best split wins (on a tie the earlier wrist); when
    nothing fits, the hand or the arm is reported missing.
    """
    names = sk.desc.names
    _, _, length = _segments(sk, path)
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
        if len(path) <= 3:
            raise NotFound(f"hand.{s}", f"the {_SIDE_WORDS[s]} arm ends at '{names[path[-1]]}' with no hand "
                                        f"below it")
        raise NotFound(f"arm.{s}", f"the bones from the chest to '{names[path[-1]]}' are not shaped like an arm")
    first, elbow, wrist = best[1]
    chain = ([path[0]] if first > 0 else []) + [path[first], path[elbow]]
    return body_sides.Limb(tuple(chain), path[wrist])


def _fans_out(sk, b):
    """b is one of 3+ bones starting at the same point (fingers hanging straight from the forearm, as in
    Quaternius' rigs): its head is then the wrist though it has one child."""
    parent = sk.parent[b]
    if parent < 0:
        return False
    near = [c for c in sk.children[parent]
            if np.linalg.norm(sk.heads[c] - sk.heads[b]) <= MIDLINE * sk.height]
    return len(near) >= 3


def _find_head(sk, chest, arm_starts, shoulder_z, mid, lat):
    """[neck..., head] rising from the chest through bones at the middle (``mid``, between the arms' bases,
    along ``lat``), or None.

    Each step goes up (within 45 degrees) to a child at the middle (no side marker, head on the body's middle
    plane: eyes and ears are not, face bones that share the head's head are no step). A leaf further up than a neck bone is long (an end bone at the top of
    the skull, like Mixamo's HeadTop_End) is not a joint of the chain.
    """
    def middle(b):
        return sk.name_sides[b] is None and abs(float((sk.heads[b] - mid) @ lat)) <= MIDLINE * sk.height

    others = [c for c in sk.children[chest] if c not in arm_starts and middle(c)]
    if not others:
        return None
    start = max(others, key=lambda c: sk.top[c])
    if sk.top[start] <= shoulder_z:
        return None
    step = sk.heads[start] - sk.heads[chest]
    if np.linalg.norm(step) > sk.tiny and angle_between(step, UP) > _UPWARD:
        return None

    def rises(a, b):
        step = sk.heads[b] - sk.heads[a]
        length = np.linalg.norm(step)
        return (middle(b) and sk.tiny < length and angle_between(step, UP) <= _UPWARD
                and (sk.children[b] or length <= _HEAD_END_STEP * sk.height))

    chain = [start]
    while True:
        steps = [c for c in sk.children[chain[-1]] if rises(chain[-1], c)]
        if not steps:
            return chain
        chain.append(max(steps, key=lambda c: sk.top[c]))


def missing_message(desc, group, detail="", matched=""):
    looked = f"looked for {looked_for(group)}, or {_SHAPE[group]}"
    extra = "; ".join(x for x in (detail, matched) if x)
    return f"Cannot map rig '{desc.name}': no {_WHAT[group]} found ({looked}{'; ' + extra if extra else ''})"
