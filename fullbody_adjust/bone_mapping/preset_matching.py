"""Mapping a rig by name: each preset variant of ``presets`` tried on the rig's bone names."""

import re

from ..solver.vocabulary import CHAIN_GROUPS
from .bone_map import BoneMap
from .presets import PRESETS, SIDED_GROUPS


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


def looked_for(group):
    """Names the presets look for in a group (its first required slot), e.g. 'thigh.L/thigh_l/...'."""
    names = []
    for preset in PRESETS:
        for g, slots, spelling in _preset_group_names(preset):
            if g == group:
                slot = next(s for s in slots if not s.startswith("?"))
                names.append(slot.split("|")[0].format(side=spelling))
    return "/".join(dict.fromkeys(names))
