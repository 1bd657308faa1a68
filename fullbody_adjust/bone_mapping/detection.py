"""Mapping a rig by shape: the groups found from the hierarchy, the rest positions and side markers alone (no
preset names), for rigs no preset knows."""

import math

import numpy as np

from . import body_sides
from .bone_map import BoneMap, MappingError
from .limbs import LEG_MIN_DROP, SIDE_WORDS, NotFound, split_arm, split_leg
from .preset_matching import looked_for
from .rig_description import MIDLINE, UP, angle_between

_WHAT = {
    "root": "hips (root) bone", "trunk": "upright trunk", "arm.L": "left arm", "arm.R": "right arm",
    "hand.L": "left hand", "hand.R": "right hand", "leg.L": "left leg", "leg.R": "right leg",
    "foot.L": "left foot", "foot.R": "right foot",
}
_SHAPE = {
    "root": "a bone where two legs and a spine branch",
    "trunk": "a chain rising from the hips to where both arms branch",
    **{f"arm.{s}": f"a chain of 2+ bones reaching out from the chest on the {w} side" for s, w in SIDE_WORDS.items()},
    **{f"hand.{s}": f"a bone at the end of the {w} arm" for s, w in SIDE_WORDS.items()},
    **{f"leg.{s}": f"a chain of 2+ bones going down from the hips on the {w} side" for s, w in SIDE_WORDS.items()},
    **{f"foot.{s}": f"a bone at the end of the {w} leg, at the ankle" for s, w in SIDE_WORDS.items()},
}
# Order in which missing groups are reported, and how far detection got when it failed at a group.
REPORT_ORDER = ("root", "leg.L", "leg.R", "foot.L", "foot.R", "trunk", "arm.L", "arm.R", "hand.L", "hand.R")
STAGE = {"root": 0, "leg.L": 1, "leg.R": 1, "foot.L": 2, "foot.R": 2, "trunk": 3, "arm.L": 4, "arm.R": 4,
          "hand.L": 5, "hand.R": 5}

# Detection thresholds (fractions of the rig's height unless said otherwise), chosen on the rigs in the tests.
_UP_BRANCH_RISE = 0.15  # the spine branch reaches at least this far above the root's head
_TRUNK_MIN_RISE = 0.15  # hip joints to the arms' bases (which rise more than they lean away from the root)
_BODY_TO_LEGS = 0.5  # what rises above the root (trunk, head) is at least this many leg lengths high
_UPWARD = math.radians(45.0)  # neck/head segments are within this of straight up
_HEAD_END_STEP = 0.08  # a neck step is shorter; a leaf this far above its parent's head marks the skull top


def detect_map(desc):
    """Map a rig by the shape of its hierarchy and its rest joints (bone heads) only (no preset names):

    1. root: a branching bone (biggest subtree first) with a branch rising above it (the spine's);
    2. legs: the lowest bone hanging from the root beside that branch, and the lowest one whose path parts
       from the first's well above both (toes and heels of one foot do not); on each path the first clearly
       downward bone is the thigh (hip connectors like CMU's LHipJoint are skipped), the first bone after
       thigh and shin whose head is near the leg's lowest point (or where a tall foot turns forward) is the
       foot (the ankle), the joint halving the way between is the knee;
    3. trunk: the spine branch must rise at least half a leg length above the root; the chest is where the
       paths to the bones furthest out on each side of the hips' line part; the trunk runs from the root's
       child up to it, and the arms' bases must rise above the hip joints;
    4. arms: the longest path out from the chest on each side, split by limb proportions (``_split_arm``);
       the wrists must be above the knees;
    5. sides: which legs and arms are on the character's own left (``body_sides``: the skeleton's facing,
       side markers in names when it is unclear);
    6. head (optional): the chain rising from the chest at the middle (``_find_head``).

    MappingError names what is missing and the bone where it stopped, from the root candidate that got
    furthest (legs, then feet, trunk, arms, hands)."""
    if not len(desc):
        raise MappingError(f"Cannot map rig '{desc.name}': it has no bones")
    try:
        return detect(desc)
    except NotFound as failure:
        raise MappingError(missing_message(desc, failure.group, failure.detail, line=failure.line)) from None


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
        bone_map = BoneMap({g: [desc.names[b] for b in bones] for g, bones in groups.items()})
        bone_map = BoneMap(bone_map.groups, source="detected from the hierarchy" + bone_map.wrists_note())
        problems = bone_map.problems(desc)
        if not problems:
            return bone_map
        # Every group found, but they do not fit (e.g. a zero-length segment): report it with its group.
        group = problems[0].split(":")[0]
        best = NotFound(group if group in STAGE else "trunk", problems[0])
    if best is None:
        first = int(sk.order[0])
        raise NotFound("leg.L", f"no bone branches into legs and a spine (from '{desc.names[first]}' the bones "
                                f"form one chain)" if len(sk.subtree(first)) == len(desc) else
                                "no bone branches into legs and a spine")
    raise best


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
    legs = [split_leg(sk, paths[k][shared:], said[k]) for k in (0, 1)]
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
    if rise < _TRUNK_MIN_RISE * sk.height or rise < lean:
        raise NotFound("trunk", f"from '{names[root]}' to '{names[chest]}' the spine does not rise "
                                 f"({rise:.3g} up from the hip joints, {lean:.3g} across)")
    # The legs say where the body faces: name the arms by the sides they are on.
    left = body_sides.left_pair(sk, legs, None)
    said = ("L", "R") if left == 0 else ("R", "L")
    arms = [split_arm(sk, arm_paths[k], said[k], _clavicle(sk, arm_paths[k], legs, lat)) for k in (0, 1)]
    knees = np.mean([sk.heads[leg.chain[-1], 2] for leg in legs])
    for k in (0, 1):
        if body_sides.end_point(sk, arms[k])[2] <= knees:
            raise NotFound(f"arm.{said[k]}", f"'{names[arm_paths[k][0]]}' hangs down to the knees (a leg?)")

    left = body_sides.left_pair(sk, legs, arms)
    shoulders = np.mean([sk.heads[arm.chain[-2], 2] for arm in arms])
    head = _find_head(sk, chest, {p[0] for p in arm_paths}, shoulders, bases, lat)
    groups = {"root": [root], "trunk": _with_length(sk, trunk) if trunk else []}
    for k in (0, 1):
        s = "L" if k == left else "R"
        groups[f"arm.{s}"] = _with_length(sk, list(arms[k].chain), body_sides.end_point(sk, arms[k]))
        groups[f"hand.{s}"] = [] if arms[k].end is None else [arms[k].end]  # none: the wrist ends the forearm
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
    drop = LEG_MIN_DROP * sk.height
    for other in order[1:]:
        top = sk.heads[sk.lca(first, other), 2]
        if top - sk.heads[first, 2] >= drop and top - sk.heads[other, 2] >= drop:
            return first, other
    side = sk.name_sides[first] or "L"
    other = "R" if side == "L" else "L"
    raise NotFound(f"leg.{other}", f"one leg goes down from '{names[root]}' to '{names[first]}', no second one")


def _clavicle(sk, path, legs, lat):
    """Whether the arm path's first bone is a clavicle: it starts within the hips' width and the next bone
    (the upper arm) outside it (True); it starts outside (False); else None (proportions decide)."""
    hips = [sk.heads[leg.chain[0]] for leg in legs]
    middle, half = 0.5 * (hips[0] + hips[1]), 0.5 * abs(float((hips[0] - hips[1]) @ lat))
    out = [abs(float((sk.heads[b] - middle) @ lat)) for b in path[:2]]
    if out[0] >= half:
        return False
    return True if len(out) > 1 and out[1] >= half else None


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


def missing_message(desc, group, detail="", matched="", line=None):
    if line:
        return f"Cannot map rig '{desc.name}': {line}"
    looked = f"looked for {looked_for(group)}, or {_SHAPE[group]}"
    extra = "; ".join(x for x in (detail, matched) if x)
    return f"Cannot map rig '{desc.name}': no {_WHAT[group]} found ({looked}{'; ' + extra if extra else ''})"
