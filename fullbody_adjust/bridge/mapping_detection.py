"""Mapping a rig by shape: the groups found from the hierarchy, the rest positions and side markers alone (no
preset names), for rigs no preset knows."""

import math

import numpy as np

from .bone_map import BoneMap, MappingError
from .preset_matching import looked_for
from .rig_description import DOWN, UP, angle_between

_WHAT = {
    "root": "hips (root) bone", "trunk": "upright trunk", "arm.L": "left arm", "arm.R": "right arm",
    "hand.L": "left hand", "hand.R": "right hand", "leg.L": "left leg", "leg.R": "right leg",
    "foot.L": "left foot", "foot.R": "right foot",
}
_SIDE_WORDS = {"L": "left (+X)", "R": "right (-X)"}
_SHAPE = {
    "root": "a bone where two legs and a spine branch",
    "trunk": "a chain rising from the hips to where both arms branch",
    **{f"arm.{s}": f"a chain of 2+ bones reaching out from the chest on the {w} side" for s, w in _SIDE_WORDS.items()},
    **{f"hand.{s}": f"a bone at the end of the {w} arm" for s, w in _SIDE_WORDS.items()},
    **{f"leg.{s}": f"a chain of 2+ bones going down from the hips on the {w} side" for s, w in _SIDE_WORDS.items()},
    **{f"foot.{s}": f"a bone at the end of the {w} leg, turning forward" for s, w in _SIDE_WORDS.items()},
}
# Order in which missing groups are reported, and how far detection got when it failed at a group.
REPORT_ORDER = ("root", "leg.L", "leg.R", "foot.L", "foot.R", "trunk", "arm.L", "arm.R", "hand.L", "hand.R")
_STAGE = {"root": 0, "leg.L": 1, "leg.R": 1, "foot.L": 2, "foot.R": 2, "trunk": 3, "arm.L": 4, "arm.R": 4,
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
_NOT_A_HAND = 0.5  # penalty for a wrist bone with exactly one child (a hand ends the arm or branches into fingers)
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
            if best is None or _STAGE[failure.group] > _STAGE[best.group]:
                best = failure
            continue
        bone_map = BoneMap({g: [desc.names[b] for b in bones] for g, bones in groups.items()},
                           source="detected from the hierarchy")
        problems = bone_map.problems(desc)
        if not problems:
            return bone_map
        # Every group found, but they do not fit (e.g. a zero-length segment): report it with its group.
        group = problems[0].split(":")[0]
        best = NotFound(group if group in _STAGE else "trunk", problems[0])
    raise best or NotFound("leg.L", "no bone branches into legs and a spine")


def _detect_from_root(sk, root):
    names = sk.desc.names
    mid_x = sk.heads[root, 0]  # the hips are at the middle
    up = max(sk.children[root], key=lambda c: sk.top[c])
    if sk.top[up] < sk.heads[root, 2] + _UP_BRANCH_RISE * sk.height:
        up = None
    upper = set(sk.subtree(up).tolist()) if up is not None else set()

    # Legs: on each side the lowest bone hanging from the root outside the spine's branch.
    lower = [b for b in sk.subtree(root).tolist() if b != root and b not in upper]
    paths = {}
    for s in "LR":
        side_bones = [b for b in lower if sk.side(b, mid_x) == s]
        if not side_bones:
            raise NotFound(f"leg.{s}", f"no {_SIDE_WORDS[s]} bones hang from '{names[root]}' beside the spine")
        lowest = min(side_bones, key=lambda b: (sk.heads[b, 2], -sk.depth[b]))
        paths[s] = sk.path(root, lowest)[1:]
    shared = 0
    while shared < min(len(paths["L"]), len(paths["R"])) and paths["L"][shared] == paths["R"][shared]:
        shared += 1
    legs = {s: _split_leg(sk, paths[s][shared:], s) for s in "LR"}

    # Trunk: a branch rising above the root, at least half as high as the legs are long (not a neck).
    leg_length = np.mean([sk.heads[legs[s][0][0], 2] - sk.heads[legs[s][1], 2] for s in "LR"])
    above = (sk.top[up] if up is not None else sk.heads[root, 2]) - sk.heads[root, 2]
    if up is None or above < _BODY_TO_LEGS * leg_length:
        raise NotFound("trunk", f"only {above:.3g} rises above '{names[root]}', whose legs are "
                                 f"{leg_length:.3g} long")
    # Arms: the most lateral bone on each side of the spine's branch; the chest is where their paths part.
    tips = {}
    for s in "LR":
        side_bones = [b for b in upper if sk.side(b, mid_x) == s]
        if not side_bones:
            raise NotFound(f"arm.{s}", f"no {_SIDE_WORDS[s]} bones above '{names[root]}'")
        tips[s] = max(side_bones, key=lambda b: (abs(sk.heads[b, 0] - mid_x), sk.depth[b]))
    chest = sk.lca(tips["L"], tips["R"])
    if chest in tips.values():
        s = "L" if chest == tips["L"] else "R"
        raise NotFound(f"arm.{s}", f"the {_SIDE_WORDS[s]} arm does not branch from the chest")
    trunk = sk.path(up, chest)
    arm_paths = {s: sk.longest_path(sk.path(chest, tips[s])[1]) for s in "LR"}
    bases = np.mean([sk.heads[arm_paths[s][0]] for s in "LR"], axis=0)
    rise = bases[2] - sk.heads[root, 2]
    lean = float(np.linalg.norm(bases[:2] - sk.heads[root, :2]))
    if rise < _TRUNK_MIN_RISE * sk.height or rise < lean:
        raise NotFound("trunk", f"from '{names[root]}' to '{names[chest]}' the spine does not rise "
                                 f"({rise:.3g} up, {lean:.3g} across)")
    arms = {s: _split_arm(sk, arm_paths[s], s) for s in "LR"}
    knees = np.mean([sk.heads[legs[s][0][1], 2] for s in "LR"])
    for s in "LR":
        if sk.heads[arms[s][1], 2] <= knees:
            raise NotFound(f"arm.{s}", f"'{names[arm_paths[s][0]]}' hangs down to the knees (a leg?)")

    groups = {"root": [root], "trunk": _with_length(sk, trunk, sk.tails[chest])}
    for s in "LR":
        groups[f"arm.{s}"], groups[f"hand.{s}"] = _with_length(sk, arms[s][0], sk.heads[arms[s][1]]), [arms[s][1]]
        groups[f"leg.{s}"], groups[f"foot.{s}"] = legs[s][0], [legs[s][1]]
    shoulders = np.mean([sk.heads[arms[s][0][-2], 2] for s in "LR"])
    head = _find_head(sk, chest, {arm_paths[s][0] for s in "LR"}, shoulders, mid_x)
    if head:
        groups["head"] = _with_length(sk, head, sk.tails[head[-1]])
    return groups


def _with_length(sk, chain, end):
    """The chain without bones whose segment (head to the next chain joint, ``end`` after the last) has no
    length: e.g. a helper bone sharing its child's head adds no joint."""
    joints = np.concatenate([sk.heads[chain], end[None]])
    return [b for k, b in enumerate(chain) if np.linalg.norm(joints[k + 1] - joints[k]) > sk.tiny]


def _segments(sk, path):
    joints = sk.joints(path)
    segments = joints[1:] - joints[:-1]
    return joints, segments, np.linalg.norm(segments, axis=1)


def _split_leg(sk, path, s):
    """[thigh, shin] and the foot on a path from the hips down to the lowest bone of one side."""
    names, group = sk.desc.names, f"leg.{s}"
    if not path:
        raise NotFound(group, f"the {_SIDE_WORDS[s]} leg shares all its bones with the other")
    joints, seg, length = _segments(sk, path)
    total = float(length.sum())
    # Thigh: the first clearly downward segment (skips hip-joint connectors like CMU LHipJoint, Daz lButtock).
    i = 0
    while i < len(path) and (length[i] <= max(0.05 * total, sk.tiny) or angle_between(seg[i], DOWN) > _DOWNWARD):
        i += 1
    if len(path) - i < 2:
        raise NotFound(group, f"no chain of 2+ bones goes down from '{names[path[0]]}'")
    # Foot: the first bone after thigh and shin whose head (the ankle) is close to the leg's lowest point.
    low = joints[i:, 2].min()
    foot = next((k for k in range(i + 2, len(path))
                 if joints[k, 2] - low < _ANKLE_HEIGHT * (joints[i, 2] - low)), None)
    if foot is None:
        raise NotFound(f"foot.{s}", f"the {_SIDE_WORDS[s]} leg ends at '{names[path[-1]]}' without a foot")
    drop = joints[i, 2] - joints[foot, 2]
    if drop < _LEG_MIN_DROP * sk.height:
        raise NotFound(group, f"'{names[path[i]]}' reaches only {drop:.3g} down")
    # Knee: the joint that halves the way from hip joint to ankle (thigh and shin are about equally long).
    before = np.concatenate([[0.0], np.cumsum(length[i:foot])])
    knees = [k for k in range(i + 1, foot) if length[k] > sk.tiny]
    if not knees:
        raise NotFound(group, f"no knee between '{names[path[i]]}' and '{names[path[foot]]}'")
    knee = min(knees, key=lambda k: abs(before[k - i] / before[-1] - 0.5))
    return [path[i], path[knee]], path[foot]


def _split_arm(sk, path, s):
    """[clavicle?, upper arm, forearm] and the hand on the longest path out from the chest.

    Every split of the path into clavicle (optional, one bone), upper arm and forearm (each possibly several
    bones, as with twist bones) and hand + fingers is scored by how far it is from a human arm: upper arm about
    1.15 forearms, hand + fingers 0.25..1.3 forearms, and the hand bone either branching (fingers) or ending the
    path. The best split wins (on a tie the earlier wrist). When splits without a hand (the forearm ends the
    path) fit better, or nothing fits, the hand or the arm is reported missing.
    """
    names = sk.desc.names
    _, _, length = _segments(sk, path)
    after = np.concatenate([np.cumsum(length[::-1])[::-1], [0.0]])  # path length from each joint to the tip

    def arm_fit(first, elbow, wrist):
        upper = float(after[first] - after[elbow])
        fore = float(after[elbow] - after[wrist])
        if min(upper, fore) <= sk.tiny:
            return math.inf
        return abs(math.log(upper / fore / _UPPER_TO_FOREARM))

    # The upper arm starts at the first or second bone (after a clavicle).
    best = (math.inf, None)
    for wrist in range(2, len(path)):
        hand_penalty = _NOT_A_HAND if len(sk.children[path[wrist]]) == 1 else 0.0
        for first in range(min(2, wrist - 1)):
            for elbow in range(first + 1, wrist):
                fit = arm_fit(first, elbow, wrist)
                fore, hand = float(after[elbow] - after[wrist]), float(after[wrist])
                if hand <= sk.tiny or fit == math.inf:
                    continue
                score = fit + hand_penalty + _HAND_WEIGHT * max(
                    0.0, math.log(_HAND_TO_FOREARM[0] * fore / hand), math.log(hand / (_HAND_TO_FOREARM[1] * fore)))
                if score < best[0] - 1e-9:
                    best = (score, (first, elbow, wrist))
    # Without a hand the path ends with the forearm.
    handless = min((arm_fit(first, len(path) - 1, len(path)) for first in range(min(2, len(path) - 1))),
                   default=math.inf)
    if best[0] > _ARM_FIT_LIMIT or handless < best[0]:
        if handless <= _ARM_FIT_LIMIT:
            raise NotFound(f"hand.{s}", f"the {_SIDE_WORDS[s]} arm ends at '{names[path[-1]]}' without a hand")
        raise NotFound(f"arm.{s}", f"the bones from the chest to '{names[path[-1]]}' are not shaped like an arm")
    first, elbow, wrist = best[1]
    chain = ([path[0]] if first > 0 else []) + [path[first], path[elbow]]
    return chain, path[wrist]


def _find_head(sk, chest, arm_starts, shoulder_z, mid_x):
    """[neck..., head] rising from the chest through unsided bones, or None.

    Each step goes up (within 45 degrees) to a child at the middle (eyes and ears are sided, face bones that
    share the head's head are no step). A leaf further up than a neck bone is long (an end bone at the top of
    the skull, like Mixamo's HeadTop_End) is not a joint of the chain.
    """
    others = [c for c in sk.children[chest] if c not in arm_starts and sk.side(c, mid_x) is None]
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
        return (sk.side(b, mid_x) is None and sk.tiny < length and angle_between(step, UP) <= _UPWARD
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
