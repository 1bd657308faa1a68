"""Bone mapping: which rig bones form each group of the five-group body model (the brief's "Body model groups").

Two parts, kept apart:

* Pure (numpy + stdlib, importable without Blender): a rig is a ``RigDescription`` (bone names, parent indices,
  rest heads and tails in armature space); ``map_rig(desc)`` returns a ``BoneMap`` or raises ``MappingError``
  with one line naming what is missing. It tries the name presets of ``mapping_presets`` first, then
  ``detect_map``: detection from the shape of the hierarchy, the rest positions and side markers in the names.
* Blender (functions taking bpy objects, at the end of the file; this module never imports bpy):
  ``describe_armature``, ``store_map``, ``load_map``, ``ensure_map``. The map is stored on the armature object
  as ``obj.fullbody_adjust.bone_map`` (items with string ``group`` and ``bone``, a group's items in chain order).

Conventions. Positions are compared in the rig's world orientation (``RigDescription.orientation``, the
object's rotation: an FBX import keeps Y-up bones under a rotated object): z is up and, as in Blender's own
conventions (Rigify's ``.L`` bones, the BVH importer), the character's left is +X. A side marker in a name
wins over the x sign. Markers are whole name tokens: ``L``/``R``/``Left``/``Right`` in any case, split at
``. _ - :``, spaces, digits and camelCase, so ``hand.L``, ``thigh_l``, ``l_arm``, ``L Hand``, ``LeftUpLeg``,
``lShldr`` (Daz), ``RHipJoint`` (CMU) and ``Bip01 R Thigh`` all count, and ``leftEye`` too.

Rigify generated rigs are mapped to their deforming DEF- bones, tried before ORG-:

* DEF- limbs are split in two, ``DEF-upper_arm.L`` + ``DEF-upper_arm.L.001`` (a child continuing it). The
  first segment is the chain bone: the next chain joint (head of ``DEF-forearm.L``) lies on its line, so the
  chain joints are the real shoulder, elbow and wrist, and the ``.001`` child follows it. This is checked for
  every chain bone that has such a ``<name>.001`` child (``BoneMap.problems``); where it fails, the DEF-
  variant is rejected and ORG- is tried.
* ``DEF-shoulder.L`` hangs from ``ORG-shoulder.L``, not above ``DEF-upper_arm.L``, so it cannot lead that
  chain: an optional slot (clavicles, extra spine and neck bones) whose bone breaks the chain's ancestor
  order is left out, and the arm is [DEF-upper_arm, DEF-forearm] (the brief allows arms without clavicle).
* The ORG- bones do not form a trunk chain at all (each ORG-spine bone hangs from its own tweak bone).
"""

from dataclasses import dataclass, field
from functools import cached_property
import math
import re

import numpy as np

from ..solver.vocabulary import CHAIN_GROUPS, GROUPS, REQUIRED_GROUPS, SINGLE_BONE_GROUPS
from .errors import AdjustError
from .mapping_presets import PRESETS, SIDED_GROUPS

GROUP_LABELS = {
    "root": "Root", "trunk": "Trunk", "arm.L": "Left Arm", "arm.R": "Right Arm", "hand.L": "Left Hand",
    "hand.R": "Right Hand", "leg.L": "Left Leg", "leg.R": "Right Leg", "foot.L": "Left Foot",
    "foot.R": "Right Foot", "head": "Head",
}

# Words for "no ... found" and what detection looks for, per group.
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
_REPORT_ORDER = ("root", "leg.L", "leg.R", "foot.L", "foot.R", "trunk", "arm.L", "arm.R", "hand.L", "hand.R")
_STAGE = {"root": 0, "leg.L": 1, "leg.R": 1, "foot.L": 2, "foot.R": 2, "trunk": 3, "arm.L": 4, "arm.R": 4,
          "hand.L": 5, "hand.R": 5}

# Detection thresholds (fractions of the rig's height unless said otherwise), chosen on the rigs in the tests.
_MIDLINE = 0.01  # a bone without side marker whose head is this close to the root's x is at the middle
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
_SPLIT_SEGMENT = math.radians(10.0)  # a split bone (with a "<name>.001" child) points at the next chain joint


class MappingError(AdjustError):
    """The rig cannot be mapped onto the body model, or a given map does not fit it; one line naming why."""


# --- the rig ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class RigDescription:
    """A rig as plain data: N bones with names, parent indices (-1: none), rest heads and tails (N, 3) in
    armature space, the rig's name (for messages) and ``orientation``, the (3, 3) rotation from armature
    space to the world (z up); identity unless the armature object is rotated."""

    names: tuple
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    name: str = "Armature"
    orientation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        n = len(names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        heads = np.asarray(self.heads, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
        tails = np.asarray(self.tails, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
        orientation = np.asarray(self.orientation, dtype=np.float64)
        if len(set(names)) != n:
            duplicate = next(x for x in names if names.count(x) > 1)
            raise ValueError(f"rig '{self.name}': bone name '{duplicate}' is used twice")
        if parents.shape != (n,) or heads.shape != (n, 3) or tails.shape != (n, 3):
            raise ValueError(f"rig '{self.name}': {n} names but parents {parents.shape}, heads {heads.shape}, "
                             f"tails {tails.shape}")
        if n and (parents.min() < -1 or parents.max() >= n):
            raise ValueError(f"rig '{self.name}': parent index out of range -1..{n - 1}")
        if not (np.isfinite(heads).all() and np.isfinite(tails).all()):
            raise ValueError(f"rig '{self.name}': bone positions have NaN/inf")
        if orientation.shape != (3, 3) or not np.isfinite(orientation).all():
            raise ValueError(f"rig '{self.name}': orientation must be a finite 3x3 matrix")
        for attr, value in (("names", names), ("parents", parents), ("heads", heads), ("tails", tails),
                            ("orientation", orientation)):
            object.__setattr__(self, attr, value)
        self._skeleton  # reject cycles now rather than at first use

    @classmethod
    def from_bones(cls, bones, name="Armature", orientation=None):
        """From ``[(bone, parent name or None, head, tail), ...]`` in any order."""
        bones = list(bones)
        index = {b[0]: i for i, b in enumerate(bones)}
        missing = [b[1] for b in bones if b[1] is not None and b[1] not in index]
        if missing:
            raise ValueError(f"rig '{name}': parent '{missing[0]}' is not a bone of the rig")
        return cls(
            names=tuple(b[0] for b in bones),
            parents=[-1 if b[1] is None else index[b[1]] for b in bones],
            heads=[b[2] for b in bones] or np.zeros((0, 3)),
            tails=[b[3] for b in bones] or np.zeros((0, 3)),
            name=name,
            orientation=np.eye(3) if orientation is None else orientation,
        )

    def __len__(self):
        return len(self.names)

    def index(self, bone):
        """Index of ``bone``; KeyError naming it when the rig has no such bone."""
        try:
            return self._index_of[bone]
        except KeyError:
            raise KeyError(f"rig '{self.name}' has no bone '{bone}'") from None

    @cached_property
    def _index_of(self):
        return {n: i for i, n in enumerate(self.names)}

    @cached_property
    def _skeleton(self):
        return _Skeleton(self)


_TOKEN = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
_SIDE_TOKENS = {"l": "L", "left": "L", "r": "R", "right": "R"}


def side_of_name(name):
    """'L', 'R' or None from the side markers in a bone name (see the module docstring)."""
    sides = {_SIDE_TOKENS[t] for t in (tok.lower() for tok in _TOKEN.findall(name)) if t in _SIDE_TOKENS}
    return sides.pop() if len(sides) == 1 else None


class _Skeleton:
    """Derived data of a RigDescription: children, pre-order, world-oriented positions, sizes."""

    def __init__(self, desc):
        n = len(desc.names)
        self.desc = desc
        self.children = [[] for _ in range(n)]
        roots = []
        for i, p in enumerate(desc.parents.tolist()):
            (roots if p < 0 else self.children[p]).append(i)
        self.parent = desc.parents.tolist()
        self.tin = [-1] * n
        self.tout = [0] * n
        self.depth = [0] * n
        order = []
        for r in roots:
            stack = [(r, False)]
            while stack:
                b, done = stack.pop()
                if done:
                    self.tout[b] = len(order)
                    continue
                self.tin[b] = len(order)
                order.append(b)
                stack.append((b, True))
                for c in reversed(self.children[b]):
                    self.depth[c] = self.depth[b] + 1
                    stack.append((c, False))
        if len(order) < n:
            looped = next(i for i in range(n) if self.tin[i] < 0)
            raise ValueError(f"rig '{desc.name}': bone '{desc.names[looped]}' is its own ancestor")
        self.order = np.array(order, dtype=np.int64)
        self.heads = desc.heads @ desc.orientation.T
        self.tails = desc.tails @ desc.orientation.T
        points = np.concatenate([self.heads, self.tails]) if n else np.zeros((1, 3))
        extent = points.max(axis=0) - points.min(axis=0)
        self.size = float(np.linalg.norm(extent)) or 1.0
        self.height = float(extent[2]) or self.size
        self.tiny = 1e-6 * self.size
        self.name_sides = [side_of_name(name) for name in desc.names]
        # Highest point (heads and tails) of each bone's subtree.
        self.top = np.maximum(self.heads[:, 2], self.tails[:, 2]) if n else np.zeros(0)
        for b in reversed(order):
            for c in self.children[b]:
                self.top[b] = max(self.top[b], self.top[c])

    def subtree(self, b):
        return self.order[self.tin[b]:self.tout[b]]

    def is_ancestor(self, a, b):
        """a is a proper ancestor of b."""
        return a != b and self.tin[a] <= self.tin[b] < self.tout[a]

    def path(self, a, b):
        """Bones from a down to b, both included (a must be b or an ancestor of b)."""
        out = [b]
        while out[-1] != a:
            out.append(self.parent[out[-1]])
        return out[::-1]

    def lca(self, a, b):
        while not (a == b or self.is_ancestor(a, b)):
            a = self.parent[a]
            if a < 0:
                return -1
        return a

    def side(self, b, mid_x):
        """Name marker first, else the x sign of the head relative to the midline (+X is left), else None."""
        if self.name_sides[b]:
            return self.name_sides[b]
        dx = self.heads[b, 0] - mid_x
        if abs(dx) <= _MIDLINE * self.height:
            return None
        return "L" if dx > 0 else "R"

    def joints(self, path):
        """Heads of the bones on a path plus the tail of the last: (len+1, 3)."""
        return np.concatenate([self.heads[path], self.tails[path[-1]][None]])

    def longest_path(self, b):
        """From b to the leaf that makes the longest run of joints (fingers beat twist bones)."""
        best = {}
        for x in reversed(self.subtree(b).tolist()):
            kids = self.children[x]
            if not kids:
                best[x] = (float(np.linalg.norm(self.tails[x] - self.heads[x])), None)
                continue
            c = max(kids, key=lambda c: float(np.linalg.norm(self.heads[c] - self.heads[x])) + best[c][0])
            best[x] = (float(np.linalg.norm(self.heads[c] - self.heads[x])) + best[c][0], c)
        out = [b]
        while best[out[-1]][1] is not None:
            out.append(best[out[-1]][1])
        return out


def _angle(v, w):
    """Angle between two vectors (0 when either has no length)."""
    norm = float(np.linalg.norm(v) * np.linalg.norm(w))
    if norm == 0.0:
        return 0.0
    return math.acos(max(-1.0, min(1.0, float(np.dot(v, w)) / norm)))


_DOWN = np.array([0.0, 0.0, -1.0])
_UP = np.array([0.0, 0.0, 1.0])


# --- the map ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BoneMap:
    """Group -> bone names in chain order (parent first), ordered as GROUPS. ``source`` says where it came
    from (a preset's label, "detected from the hierarchy", "stored") and does not take part in ==."""

    groups: dict
    source: str = field(default="", compare=False)

    def __post_init__(self):
        groups = {g: tuple(str(b) for b in bones) for g, bones in dict(self.groups).items()}
        ordered = {g: groups[g] for g in GROUPS if groups.get(g)}
        ordered.update((g, bones) for g, bones in groups.items() if g not in ordered and bones)
        object.__setattr__(self, "groups", ordered)

    @classmethod
    def from_items(cls, items, source=""):
        """From ``(group, bone)`` pairs in stored order."""
        groups = {}
        for group, bone in items:
            groups.setdefault(group, []).append(bone)
        return cls(groups, source=source)

    def items(self):
        """``(group, bone)`` pairs in stored order."""
        return [(g, b) for g, bones in self.groups.items() for b in bones]

    def bones(self, group):
        """The group's bones (empty when not mapped)."""
        return self.groups.get(group, ())

    def missing(self):
        """Required groups without bones, in GROUPS order."""
        return [g for g in REQUIRED_GROUPS if not self.groups.get(g)]

    def problems(self, desc):
        """Everything that keeps this map from fitting ``desc``, one short sentence each (empty: it fits)."""
        sk = desc._skeleton
        out = [f"unknown group '{g}'" for g in self.groups if g not in GROUPS]
        missing = [f"no bones in group '{g}'" for g in self.missing()]
        used = {}
        for group, bone in self.items():
            if bone not in desc._index_of:
                out.append(f"{group}: no bone '{bone}'")
            elif bone in used:
                out.append(f"bone '{bone}' is in both {used[bone]} and {group}")
            else:
                used[bone] = group
        if out:
            return out + missing  # the checks below need known groups and distinct, known bones
        out = missing
        idx = {g: [desc._index_of[b] for b in bones] for g, bones in self.groups.items()}
        for group in SINGLE_BONE_GROUPS:
            if len(idx.get(group, ())) > 1:
                out.append(f"{group} must be one bone, not {len(idx[group])}")
        for group in CHAIN_GROUPS:
            chain = idx.get(group, [])
            for a, b in zip(chain, chain[1:]):
                if not sk.is_ancestor(a, b):
                    out.append(f"{group}: '{desc.names[b]}' does not hang below '{desc.names[a]}'")
        for limb, end in (("arm", "hand"), ("leg", "foot")):
            for s in "LR":
                chain, tip = idx.get(f"{limb}.{s}"), idx.get(f"{end}.{s}")
                if chain and tip and not sk.is_ancestor(chain[-1], tip[0]):
                    out.append(f"{end}.{s}: '{desc.names[tip[0]]}' does not hang below '{desc.names[chain[-1]]}'")
        if len(out) > len(missing):
            return out
        for group, chain in idx.items():
            if group not in CHAIN_GROUPS:
                continue
            end = idx.get({"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R"}.get(group))
            # Chain joints: heads of the chain bones + the effector's head (limbs) or the last bone's tail.
            joints = [desc.heads[b] for b in chain] + [desc.heads[end[0]] if end else desc.tails[chain[-1]]]
            for k, b in enumerate(chain):
                segment = joints[k + 1] - joints[k]
                if np.linalg.norm(segment) <= sk.tiny:
                    out.append(f"{group}: '{desc.names[b]}' ends where it starts (zero-length segment)")
                elif self._is_split(desc, b) and _angle(segment, desc.tails[b] - desc.heads[b]) > _SPLIT_SEGMENT:
                    out.append(f"{group}: '{desc.names[b]}' is split ('{desc.names[b]}.001' follows) but the "
                               f"next joint is not along it")
        return out

    @staticmethod
    def _is_split(desc, b):
        continuation = desc.names[b] + ".001"
        return any(desc.names[c] == continuation for c in desc._skeleton.children[b])

    def validate(self, desc):
        """Raise MappingError naming the first problem (and how many more) unless the map fits ``desc``."""
        problems = self.problems(desc)
        if problems:
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            raise MappingError(f"Bone map does not fit rig '{desc.name}': {problems[0]}{more}")
        return self


# --- presets ------------------------------------------------------------------------------------------------

def _preset_group_names(preset):
    """Preset table keys expanded to GROUPS names with the {side} spelling: [(group, slots, side), ...]."""
    out = []
    for key, slots in preset.table.items():
        if key in SIDED_GROUPS:
            out += [(f"{key}.{s}", slots, spelling) for s, spelling in zip("LR", preset.sides)]
        else:
            out.append((key, slots, ""))
    return out


def _match_preset(desc, preset, prefix):
    """Groups found (group -> [(bone index, optional)]) and required groups missing, for one variant."""
    pattern = re.compile(prefix, re.IGNORECASE) if prefix else None
    lookup = {}
    for i, name in enumerate(desc.names):
        if pattern is not None:
            m = pattern.match(name)
            if not m:
                continue
            name = name[m.end():]
        lookup.setdefault(name.lower(), []).append((name, i))
    found, missing = {}, []
    for group, slots, spelling in _preset_group_names(preset):
        chain = []
        for slot in slots:
            optional = slot.startswith("?")
            hit = None
            for alt in slot.lstrip("?").split("|"):
                wanted = alt.format(side=spelling)
                hits = lookup.get(wanted.lower())
                if hits:
                    hit = next((i for n, i in hits if n == wanted), hits[0][1])
                    break
            if hit is not None:
                chain.append((hit, optional))
            elif not optional:
                chain = None
                break
        if chain is None:
            if group != "head":
                missing.append(group)
        else:
            found[group] = chain
    return found, missing


def _drop_misplaced_optional(sk, found):
    """Leave out optional bones that break a chain's ancestor order (e.g. DEF-shoulder.L, see the module
    docstring) and optional trunk bones above the arms' branching point."""
    for group, chain in found.items():
        if group not in CHAIN_GROUPS:
            continue
        kept = []
        for k, (b, optional) in enumerate(chain):
            nxt = chain[k + 1][0] if k + 1 < len(chain) else None
            prev = kept[-1][0] if kept else None
            if optional and ((nxt is not None and not sk.is_ancestor(b, nxt))
                             or (prev is not None and not sk.is_ancestor(prev, b))):
                continue
            kept.append((b, optional))
        found[group] = kept
    trunk, arms = found.get("trunk"), [found.get("arm.L"), found.get("arm.R")]
    if trunk and all(arms):
        carries = [b == a[0][0] or sk.is_ancestor(b, a[0][0]) for b, _ in trunk for a in arms]
        carries_both = [all(carries[2 * k:2 * k + 2]) for k in range(len(trunk))]
        if any(carries_both):
            while trunk[-1][1] and not carries_both[len(trunk) - 1]:
                trunk.pop()


def preset_maps(desc):
    """Every preset variant's attempt, in order: ``(label, BoneMap of what was found, problems)``; problems
    lists the required groups missing, then what ``BoneMap.problems`` finds. Empty problems: a full match."""
    sk = desc._skeleton
    out = []
    for preset in PRESETS:
        for label, prefix in preset.variants:
            found, missing = _match_preset(desc, preset, prefix)
            if not found:
                continue
            _drop_misplaced_optional(sk, found)
            bone_map = BoneMap({g: [desc.names[b] for b, _ in chain] for g, chain in found.items()}, source=label)
            problems = [f"no bones in group '{g}'" for g in missing] or bone_map.problems(desc)
            out.append((label, bone_map, problems))
    return out


def _looked_for(group):
    """Names the presets look for in a group (its first required slot), e.g. 'thigh.L/thigh_l/...'."""
    names = []
    for preset in PRESETS:
        for g, slots, spelling in _preset_group_names(preset):
            if g == group:
                slot = next(s for s in slots if not s.startswith("?"))
                names.append(slot.split("|")[0].format(side=spelling))
    return "/".join(dict.fromkeys(names))


# --- detection from the shape of the hierarchy -----------------------------------------------------------

class _NotFound(Exception):
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
        return _detect(desc)
    except _NotFound as failure:
        raise MappingError(_missing_message(desc, failure.group, failure.detail)) from None


def _detect(desc):
    sk = desc._skeleton
    # Root candidates: bones that branch, the biggest subtree first (the brief: the bone with most descendants
    # where the legs and the spine branch). The failure that got furthest is reported; on a tie the first.
    candidates = sorted((b for b in range(len(desc)) if len(sk.children[b]) >= 2),
                        key=lambda b: (-(sk.tout[b] - sk.tin[b]), sk.depth[b], b))
    best = None
    for root in candidates:
        try:
            groups = _detect_from_root(sk, root)
        except _NotFound as failure:
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
        best = _NotFound(group if group in _STAGE else "trunk", problems[0])
    raise best or _NotFound("leg.L", "no bone branches into legs and a spine")


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
            raise _NotFound(f"leg.{s}", f"no {_SIDE_WORDS[s]} bones hang from '{names[root]}' beside the spine")
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
        raise _NotFound("trunk", f"only {above:.3g} rises above '{names[root]}', whose legs are "
                                 f"{leg_length:.3g} long")
    # Arms: the most lateral bone on each side of the spine's branch; the chest is where their paths part.
    tips = {}
    for s in "LR":
        side_bones = [b for b in upper if sk.side(b, mid_x) == s]
        if not side_bones:
            raise _NotFound(f"arm.{s}", f"no {_SIDE_WORDS[s]} bones above '{names[root]}'")
        tips[s] = max(side_bones, key=lambda b: (abs(sk.heads[b, 0] - mid_x), sk.depth[b]))
    chest = sk.lca(tips["L"], tips["R"])
    if chest in tips.values():
        s = "L" if chest == tips["L"] else "R"
        raise _NotFound(f"arm.{s}", f"the {_SIDE_WORDS[s]} arm does not branch from the chest")
    trunk = sk.path(up, chest)
    arm_paths = {s: sk.longest_path(sk.path(chest, tips[s])[1]) for s in "LR"}
    bases = np.mean([sk.heads[arm_paths[s][0]] for s in "LR"], axis=0)
    rise = bases[2] - sk.heads[root, 2]
    lean = float(np.linalg.norm(bases[:2] - sk.heads[root, :2]))
    if rise < _TRUNK_MIN_RISE * sk.height or rise < lean:
        raise _NotFound("trunk", f"from '{names[root]}' to '{names[chest]}' the spine does not rise "
                                 f"({rise:.3g} up, {lean:.3g} across)")
    arms = {s: _split_arm(sk, arm_paths[s], s) for s in "LR"}
    knees = np.mean([sk.heads[legs[s][0][1], 2] for s in "LR"])
    for s in "LR":
        if sk.heads[arms[s][1], 2] <= knees:
            raise _NotFound(f"arm.{s}", f"'{names[arm_paths[s][0]]}' hangs down to the knees (a leg?)")

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
        raise _NotFound(group, f"the {_SIDE_WORDS[s]} leg shares all its bones with the other")
    joints, seg, length = _segments(sk, path)
    total = float(length.sum())
    # Thigh: the first clearly downward segment (skips hip-joint connectors like CMU LHipJoint, Daz lButtock).
    i = 0
    while i < len(path) and (length[i] <= max(0.05 * total, sk.tiny) or _angle(seg[i], _DOWN) > _DOWNWARD):
        i += 1
    if len(path) - i < 2:
        raise _NotFound(group, f"no chain of 2+ bones goes down from '{names[path[0]]}'")
    # Foot: the first bone after thigh and shin whose head (the ankle) is close to the leg's lowest point.
    low = joints[i:, 2].min()
    foot = next((k for k in range(i + 2, len(path))
                 if joints[k, 2] - low < _ANKLE_HEIGHT * (joints[i, 2] - low)), None)
    if foot is None:
        raise _NotFound(f"foot.{s}", f"the {_SIDE_WORDS[s]} leg ends at '{names[path[-1]]}' without a foot")
    drop = joints[i, 2] - joints[foot, 2]
    if drop < _LEG_MIN_DROP * sk.height:
        raise _NotFound(group, f"'{names[path[i]]}' reaches only {drop:.3g} down")
    # Knee: the joint that halves the way from hip joint to ankle (thigh and shin are about equally long).
    before = np.concatenate([[0.0], np.cumsum(length[i:foot])])
    knees = [k for k in range(i + 1, foot) if length[k] > sk.tiny]
    if not knees:
        raise _NotFound(group, f"no knee between '{names[path[i]]}' and '{names[path[foot]]}'")
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
            raise _NotFound(f"hand.{s}", f"the {_SIDE_WORDS[s]} arm ends at '{names[path[-1]]}' without a hand")
        raise _NotFound(f"arm.{s}", f"the bones from the chest to '{names[path[-1]]}' are not shaped like an arm")
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
    if np.linalg.norm(step) > sk.tiny and _angle(step, _UP) > _UPWARD:
        return None

    def rises(a, b):
        step = sk.heads[b] - sk.heads[a]
        length = np.linalg.norm(step)
        return (sk.side(b, mid_x) is None and sk.tiny < length and _angle(step, _UP) <= _UPWARD
                and (sk.children[b] or length <= _HEAD_END_STEP * sk.height))

    chain = [start]
    while True:
        steps = [c for c in sk.children[chain[-1]] if rises(chain[-1], c)]
        if not steps:
            return chain
        chain.append(max(steps, key=lambda c: sk.top[c]))


# --- the whole mapping ------------------------------------------------------------------------------------

def _missing_message(desc, group, detail="", matched=""):
    looked = f"looked for {_looked_for(group)}, or {_SHAPE[group]}"
    extra = "; ".join(x for x in (detail, matched) if x)
    return f"Cannot map rig '{desc.name}': no {_WHAT[group]} found ({looked}{'; ' + extra if extra else ''})"


def map_rig(desc):
    """The rig's BoneMap: the first preset variant that maps every required group and fits the rig, else
    detection from the hierarchy. MappingError (one line) names what is missing."""
    if not len(desc):
        raise MappingError(f"Cannot map rig '{desc.name}': it has no bones")
    attempts = preset_maps(desc)
    for label, bone_map, problems in attempts:
        if not problems:
            return bone_map
    try:
        return _detect(desc)
    except _NotFound as failure:
        detected = failure
    # Report what a preset nearly found when it got at least half the groups, else detection's failure.
    nearest = max(attempts, key=lambda a: len(REQUIRED_GROUPS) - len(a[1].missing()), default=None)
    if nearest is not None and len(REQUIRED_GROUPS) - len(nearest[1].missing()) >= len(REQUIRED_GROUPS) / 2:
        label, bone_map, problems = nearest
        missing = bone_map.missing()
        if missing:
            group = min(missing, key=_REPORT_ORDER.index)
            raise MappingError(_missing_message(desc, group, matched=f"other bones have {label} names"))
        raise MappingError(f"Cannot map rig '{desc.name}': it has {label} names but {problems[0]}")
    raise MappingError(_missing_message(desc, detected.group, detected.detail))


# --- Blender ------------------------------------------------------------------------------------------------
# These take bpy objects; nothing here imports bpy.

def describe_armature(obj):
    """RigDescription of an armature object's rest bones (armature space) and its world orientation."""
    if obj is None or getattr(obj, "type", None) != 'ARMATURE':
        raise MappingError(f"Cannot map '{getattr(obj, 'name', obj)}': it is not an armature")
    bones = obj.data.bones
    n = len(bones)
    names = tuple(b.name for b in bones)
    index = {name: i for i, name in enumerate(names)}
    parents = [index[b.parent.name] if b.parent is not None else -1 for b in bones]
    if _is_control_rig(obj):
        parents = _control_rig().skeleton_parents(names, parents)
    heads = np.empty(n * 3, dtype=np.float32)
    tails = np.empty(n * 3, dtype=np.float32)
    bones.foreach_get("head_local", heads)
    bones.foreach_get("tail_local", tails)
    rotation = np.array(obj.matrix_world.to_3x3().normalized(), dtype=np.float64)
    return RigDescription(names=names, parents=parents, heads=heads.reshape(n, 3), tails=tails.reshape(n, 3),
                          name=obj.name, orientation=rotation)


def store_map(obj, bone_map):
    """Write ``bone_map`` to ``obj.fullbody_adjust.bone_map`` (replacing what was there)."""
    items = obj.fullbody_adjust.bone_map
    items.clear()
    for group, bone in bone_map.items():
        item = items.add()
        item.group = group
        item.bone = bone


def load_map(obj):
    """The map stored on ``obj`` (items with an empty bone name are skipped), or None when nothing is stored."""
    pairs = [(item.group, item.bone) for item in obj.fullbody_adjust.bone_map if item.bone]
    return BoneMap.from_items(pairs, source="stored") if pairs else None


def ensure_map(obj):
    """The stored map when it still fits the rig; otherwise the rig is mapped afresh and the new map stored.
    MappingError when the rig cannot be mapped (the stored items are then left as they were).

    A generated control rig (Rigify) is solved on its ORG- bones, so only a map of ORG- bones fits it."""
    desc = describe_armature(obj)
    control_rig = _is_control_rig(obj)
    stored = load_map(obj)
    if stored is not None and not stored.problems(desc) and (not control_rig or _all_org(stored)):
        return stored
    bone_map = _map_control_rig(desc) if control_rig else map_rig(desc)
    store_map(obj, bone_map)
    return bone_map


def _control_rig():
    from . import control_rig  # imports Blender's modules: only the Blender-side functions need it
    return control_rig


def _is_control_rig(obj):
    return _control_rig().is_generated_rigify(obj)


def _all_org(bone_map):
    return all(bone.startswith(_control_rig().ORG) for _group, bone in bone_map.items())


def _map_control_rig(desc):
    """The ORG- variant of the Rigify preset on a generated rig's skeleton, else the usual mapping."""
    for _label, bone_map, problems in preset_maps(desc):
        if not problems and _all_org(bone_map):
            return bone_map
    return map_rig(desc)
