"""The paper's body model (§5.1): five IK groups joined by two sub-bases, built from a generic bone description.

The description is BONE-based (names, parents, per-bone head/tail), because bones are what the Blender bridge
reads and must write back; any rig whose bones are mapped to the group vocabulary below can feed it.

Groups (ordered bone lists, parent -> child; the names are solver/vocabulary.py's):
    root            [pelvis]                translates only
    trunk           [spine bones...]        chain: heads + tail of the last bone (= the SC, sterno-clavicular)
    arm.L / arm.R   [clavicle?, upper, fore] chain: heads + head of the hand bone (the wrist, end effector)
    hand.L / hand.R [hand]                  keeps its world orientation while its arm is solved. Optional: an
                                            arm without one (a robot's forearm ending in a fist, fingers hanging
                                            from the forearm) ends at its last bone's tail, the wrist; whatever
                                            hangs from the forearm rides on it
    leg.L / leg.R   [thigh, shin]           chain: heads + head of the foot bone (the ankle, end effector)
    foot.L / foot.R [foot]                  keeps its world orientation while its leg is solved
    head (optional) [neck bones..., head]   rides on the chest; with a head target it is a chain of the neck
                                            bones' heads + the head bone's head (the head keeps its world
                                            orientation, like hands and feet)
The two sub-bases: the root (trunk and legs hang from it) and the SC (arms and head hang from the chest).
Every other bone keeps its local transform and follows its parent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import any_perpendicular, cross, dot, normalize
from ..memory import SolveMemory
from ..vocabulary import EFFECTORS, GROUPS, REQUIRED_GROUPS, SINGLE_BONE_GROUPS

# Chain groups ("limbs"), in the order Algorithm 1 solves them: trunk, then arms (and head), then legs.
LIMB_NAMES = ("trunk", "arm.L", "arm.R", "head", "leg.L", "leg.R")
LIMB_OF_EFFECTOR = {"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L", "foot.R": "leg.R", "head": "head"}
# Hands may be left out: the arm then ends at its last bone's tail (the wrist; the bridge passes joint ends as tails).
OPTIONAL_HANDS = ("hand.L", "hand.R")
_MIN_BONES = {"trunk": 1, "arm.L": 2, "arm.R": 2, "leg.L": 2, "leg.R": 2, "head": 1}

# Roles of bones in the propagation pass (fullbody/adjust.py): how a bone's new head and rotation are found.
FIXED, ROOT, CHAIN, END, RIGID = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class Limb:
    """One chain group. Chain joints = heads of `bones`, then the head of `end_bone` (arms, legs, head) or, for
    the trunk, the tail of the last bone (the SC). Joint 0 is the chain's base (fixed during its solve)."""

    name: str
    bones: tuple[int, ...]
    end_bone: int | None  # whose head is the end effector; None: the tail of bones[-1] (trunk, hand-less arm)
    effector: str | None  # the effector name it serves (None for the trunk)
    hub: str  # sub-base it hangs from: 'root' (trunk, legs) or 'sc' (arms, head)

    @property
    def n_joints(self) -> int:
        return len(self.bones) + 1

    def joints(self, heads: np.ndarray, tails: np.ndarray) -> np.ndarray:
        """Chain joint positions (..., n, 3) from bone heads/tails (..., J, 3)."""
        end = self.end_point(heads, tails)
        return np.concatenate([heads[..., list(self.bones), :], end[..., None, :]], axis=-2)

    def end_point(self, heads: np.ndarray, tails: np.ndarray) -> np.ndarray:
        """The chain's last joint (..., 3): the end bone's head, else the last bone's tail."""
        return tails[..., self.bones[-1], :] if self.end_bone is None else heads[..., self.end_bone, :]


def _check_hierarchy(names, parents):
    names = tuple(names)
    if not names:
        raise SolverInputError("skeleton has no bones")
    for n in names:
        if not isinstance(n, str) or not n:
            raise SolverInputError(f"bone name {n!r} is not a non-empty string")
    seen = set()
    for n in names:
        if n in seen:
            raise SolverInputError(f"bone name {n!r} appears twice")
        seen.add(n)
    try:
        par = np.array(parents)
    except (TypeError, ValueError):
        raise SolverInputError("parents must be integers") from None
    if par.shape != (len(names),):
        raise SolverInputError(f"parents must have shape ({len(names)},), got {par.shape}")
    if par.size and not np.issubdtype(par.dtype, np.integer):
        raise SolverInputError("parents must be integers")
    par = par.astype(np.int64)
    bad = np.nonzero((par < -1) | (par >= len(names)) | (par == np.arange(len(names))))[0]
    if bad.size:
        raise SolverInputError(f"bone {names[bad[0]]!r} has an invalid parent index {par[bad[0]]}")
    # A cycle never reaches -1: walking up more than J steps proves one.
    for start in range(len(names)):
        j, steps = start, 0
        while j >= 0:
            j = par[j]
            steps += 1
            if steps > len(names):
                raise SolverInputError(f"bone {names[start]!r} is in a parent cycle")
    par.setflags(write=False)
    return names, par


@dataclass(frozen=True)
class BodyModel:
    """The five-group body model of one rig (topology only; poses come with each solve)."""

    names: tuple[str, ...]
    parents: np.ndarray  # (J,)
    groups: dict  # group name -> tuple of bone indices
    limbs: dict  # limb name -> Limb (the head limb only when the head group has >= 2 bones)
    order: np.ndarray  # bone indices, every parent before its children
    roles: np.ndarray  # (J,) FIXED | ROOT | CHAIN | END | RIGID
    role_limb: tuple  # (J,) limb name for CHAIN/END bones, else None
    role_index: np.ndarray  # (J,) index within the limb's bones for CHAIN bones, else -1
    root: int = 0
    # What its solves keep for the next ones (a copy made with dataclasses.replace starts with nothing kept).
    memory: SolveMemory = field(default_factory=SolveMemory, init=False, repr=False, compare=False)

    @classmethod
    def from_description(cls, names, parents, groups_by_name) -> "BodyModel":
        """Validate a rig description: bone names, parent indices (-1 for roots) and the group -> bone-name
        lists of vocabulary.GROUPS. Raises SolverInputError with a one-line reason."""
        names, parents = _check_hierarchy(names, parents)
        index = {n: i for i, n in enumerate(names)}
        if not isinstance(groups_by_name, dict):
            raise SolverInputError("groups must be a dict of group name -> list of bone names")
        unknown = [g for g in groups_by_name if g not in GROUPS]
        if unknown:
            raise SolverInputError(f"unknown group {unknown[0]!r} (known: {', '.join(GROUPS)})")
        missing = [g for g in REQUIRED_GROUPS if g not in groups_by_name and g not in OPTIONAL_HANDS]
        if missing:
            raise SolverInputError(f"group {missing[0]!r} is missing")
        groups: dict[str, tuple[int, ...]] = {}
        owner: dict[int, str] = {}
        for g in GROUPS:
            if g not in groups_by_name:
                continue
            bones = groups_by_name[g]
            if isinstance(bones, str) or not hasattr(bones, "__iter__"):
                raise SolverInputError(f"group {g!r} must be a list of bone names")
            bones = list(bones)
            if not bones:
                raise SolverInputError(f"group {g!r} is empty")
            if g in SINGLE_BONE_GROUPS and len(bones) != 1:
                raise SolverInputError(f"group {g!r} must have exactly one bone, got {len(bones)}")
            if len(bones) < _MIN_BONES.get(g, 1):
                raise SolverInputError(f"group {g!r} needs at least {_MIN_BONES[g]} bones, got {len(bones)}")
            idx = []
            for b in bones:
                if b not in index:
                    raise SolverInputError(f"group {g!r}: no bone named {b!r}")
                i = index[b]
                if i in owner:
                    raise SolverInputError(f"bone {b!r} is in both {owner[i]!r} and {g!r}")
                owner[i] = g
                idx.append(i)
            groups[g] = tuple(idx)

        def is_ancestor(a, b):  # a is a proper ancestor of b
            j = parents[b]
            while j >= 0:
                if j == a:
                    return True
                j = parents[j]
            return False

        def require_descendant(child, ancestor, what):
            if not is_ancestor(ancestor, child):
                raise SolverInputError(f"{what}: {names[child]!r} is not a descendant of {names[ancestor]!r}")

        for g, bones in groups.items():
            for a, b in zip(bones[:-1], bones[1:]):
                require_descendant(b, a, f"group {g!r} is not in parent -> child order")
        root = groups["root"][0]
        chest = groups["trunk"][-1]
        require_descendant(groups["trunk"][0], root, "trunk must hang from the root")
        for side in ("L", "R"):
            require_descendant(groups[f"arm.{side}"][0], chest, f"arm.{side} must hang from the chest")
            if f"hand.{side}" in groups:
                require_descendant(groups[f"hand.{side}"][0], groups[f"arm.{side}"][-1],
                                   f"hand.{side} must end arm.{side}")
            require_descendant(groups[f"leg.{side}"][0], root, f"leg.{side} must hang from the root")
            for t in groups["trunk"]:
                if is_ancestor(t, groups[f"leg.{side}"][0]):
                    raise SolverInputError(f"leg.{side} must hang from the root, not from trunk bone {names[t]!r}")
            require_descendant(groups[f"foot.{side}"][0], groups[f"leg.{side}"][-1], f"foot.{side} must end leg.{side}")
        if "head" in groups:
            require_descendant(groups["head"][0], chest, "head must hang from the chest")

        limbs = {"trunk": Limb("trunk", groups["trunk"], None, None, "root")}
        for side in ("L", "R"):
            hand = groups.get(f"hand.{side}", (None,))[0]  # None: the wrist is the forearm's tail
            limbs[f"arm.{side}"] = Limb(f"arm.{side}", groups[f"arm.{side}"], hand, f"hand.{side}", "sc")
        if "head" in groups and len(groups["head"]) >= 2:
            limbs["head"] = Limb("head", groups["head"][:-1], groups["head"][-1], "head", "sc")
        for side in ("L", "R"):
            limbs[f"leg.{side}"] = Limb(f"leg.{side}", groups[f"leg.{side}"], groups[f"foot.{side}"][0],
                                        f"foot.{side}", "root")
        limbs = {k: limbs[k] for k in LIMB_NAMES if k in limbs}

        depth = np.zeros(len(names), dtype=np.int64)
        for start in range(len(names)):
            j = parents[start]
            while j >= 0:
                depth[start] += 1
                j = parents[j]
        order = np.argsort(depth, kind="stable")

        roles = np.full(len(names), RIGID, dtype=np.int64)
        role_limb = [None] * len(names)
        role_index = np.full(len(names), -1, dtype=np.int64)
        for j in range(len(names)):
            if j != root and not is_ancestor(root, j):
                roles[j] = FIXED  # above or beside the pelvis (e.g. a rig's master bone): never moves
        roles[root] = ROOT
        for limb in limbs.values():
            for k, b in enumerate(limb.bones):
                roles[b], role_limb[b], role_index[b] = CHAIN, limb.name, k
            if limb.end_bone is not None:
                roles[limb.end_bone], role_limb[limb.end_bone] = END, limb.name
        for arr in (order, roles, role_index):
            arr.setflags(write=False)
        return cls(names, parents, groups, limbs, order, roles, tuple(role_limb), role_index, root)

    @property
    def effectors(self) -> tuple[str, ...]:
        """Effector names this model can serve (head only with a head chain)."""
        return tuple(e for e in EFFECTORS if LIMB_OF_EFFECTOR[e] in self.limbs)

    def sc(self, heads: np.ndarray, tails: np.ndarray) -> np.ndarray:
        """The sterno-clavicular joint (end of the trunk chain): tail of the last trunk bone, (..., 3)."""
        return tails[..., self.groups["trunk"][-1], :]

    def body_frame(self, heads: np.ndarray, tails: np.ndarray):
        """Unit (up, left, forward) per pose (..., 3): up = trunk base -> SC, left = right hip -> left hip,
        forward = left x up (right-handed). Used only for default hinge axes of straight elbows and knees."""
        trunk = self.limbs["trunk"].joints(heads, tails)
        up = normalize(trunk[..., -1, :] - trunk[..., 0, :], fallback=np.array([0.0, 0.0, 1.0]))
        left = heads[..., self.groups["leg.L"][0], :] - heads[..., self.groups["leg.R"][0], :]
        left = left - dot(left, up)[..., None] * up
        left = normalize(left, fallback=any_perpendicular(up))
        forward = cross(left, up)
        return up, left, forward
