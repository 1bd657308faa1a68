"""The bone map: which bones of a rig form each group of the five-group body model, and whether a map fits a
rig (``BoneMap.problems``), with the one-line MappingError that says why not."""

from dataclasses import dataclass, field
import math

import numpy as np

from ..solver.vocabulary import CHAIN_GROUPS, GROUPS, REQUIRED_GROUPS, SINGLE_BONE_GROUPS
from ..errors import AdjustError
from .rig_description import angle_between

GROUP_LABELS = {
    "root": "Root", "trunk": "Trunk", "arm.L": "Left Arm", "arm.R": "Right Arm", "hand.L": "Left Hand",
    "hand.R": "Right Hand", "leg.L": "Left Leg", "leg.R": "Right Leg", "foot.L": "Left Foot",
    "foot.R": "Right Foot", "head": "Head",
}

# Words for "no ... found" and what detection looks for, per group.

SPLIT_SEGMENT = math.radians(10.0)  # a split bone (with a "<name>.001" child) points at the next chain joint


class MappingError(AdjustError):
    """The rig cannot be mapped onto the body model, or a given map does not fit it; one line naming why."""

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
        """Required groups without bones, in GROUPS order. A hand is not missing when its arm is mapped: that arm
        has no hand bone and its wrist is the end of its last bone (``handless``)."""
        return [g for g in REQUIRED_GROUPS if not self.groups.get(g) and g not in self.handless()]

    def handless(self):
        """{hand group: the bone whose end is its wrist} of the mapped arms without a hand bone."""
        return {f"hand.{s}": self.groups[f"arm.{s}"][-1] for s in "LR"
                if self.groups.get(f"arm.{s}") and not self.groups.get(f"hand.{s}")}

    def wrists_note(self):
        """'; no hand bones: the left wrist is the end of 'X', ...' for hand-less arms, else ''."""
        ends = [f"the {'left' if h.endswith('L') else 'right'} wrist is the end of '{bone}'"
                for h, bone in self.handless().items()]
        return f"; no hand bone{'s' if len(ends) > 1 else ''}: {' and '.join(ends)}" if ends else ""

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
        for s in "LR":  # a leg goes down: its ankle is below its hip joint
            chain, tip = idx.get(f"leg.{s}"), idx.get(f"foot.{s}")
            if chain and tip and sk.heads[tip[0], 2] >= sk.heads[chain[0], 2]:
                out.append(f"foot.{s}: the ankle ('{desc.names[tip[0]]}') is not below the hip joint "
                           f"('{desc.names[chain[0]]}')")
        for group, chain in idx.items():
            if group not in CHAIN_GROUPS:
                continue
            end = idx.get({"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R"}.get(group))
            # Chain joints are heads: of the chain bones, then of the hand or foot (limbs), or the end of a hand-less
            # arm's last bone (its wrist). Where the trunk and the head end is not a joint of the map, so their last
            # bone's segment is not checked.
            wrist = [sk.ends[chain[-1]] @ desc.orientation] if not end and group.startswith("arm") else []
            joints = [desc.heads[b] for b in chain] + ([desc.heads[end[0]]] if end else wrist)
            for k, b in enumerate(chain[:len(joints) - 1]):
                segment = joints[k + 1] - joints[k]
                if np.linalg.norm(segment) <= sk.tiny:
                    nxt = (chain + (end or []))[k + 1:k + 2]
                    out.append(f"{group}: '{desc.names[b]}' has no length" + (
                        f" (its head is where '{desc.names[nxt[0]]}' starts)" if nxt else ""))
                elif self._is_split(desc, b) and angle_between(segment, desc.tails[b] - desc.heads[b]) > SPLIT_SEGMENT:
                    out.append(f"{group}: '{desc.names[b]}' is split ('{desc.names[b]}.001' follows) but the "
                               f"next joint is not along it")
        return out

    @staticmethod
    def _is_split(desc, b):
        continuation = desc.names[b] + ".001"
        return any(desc.names[c] == continuation for c in desc._skeleton.children[b])
