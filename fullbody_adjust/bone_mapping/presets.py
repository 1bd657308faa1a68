"""Bone-name presets for the five-group body model (solver/vocabulary.py's groups), read from
presets.toml beside this file (data a rigger can extend without touching code).

No bpy. A preset names, per group, the chain's slots in parent → child order. A slot is a string:

- ``"spine.001"``: one bone name;
- ``"abdomenLower|abdomen"``: alternatives, the first one the rig has is taken;
- ``"?shoulder.{side}"``: optional (a leading ``?``), e.g. clavicles, extra spine and neck bones;
- ``{side}`` is replaced by the preset's left/right spelling; groups ``arm``, ``hand``, ``leg`` and ``foot``
  are sided (they become ``arm.L`` and ``arm.R``...), the others are not.

Names are compared case-insensitively (Daz spells both ``lForeArm`` and ``lForearmBend``). Each preset lists
variants: a label and a prefix pattern (a regular expression) that every bone name of that variant starts
with, e.g. Mixamo's ``mixamorig:`` (also ``mixamorig1:``, ``mixamorig_``), Rigify's ``DEF-``. The variants of
a preset are tried in order; see ``mapping.map_rig`` for how a match is accepted.
"""

from dataclasses import dataclass
from pathlib import Path
import tomllib

SIDED_GROUPS = ("arm", "hand", "leg", "foot")


@dataclass(frozen=True)
class Preset:
    name: str
    sides: tuple  # (left spelling, right spelling) substituted for {side}
    table: dict  # group ("root", "trunk", "arm", ...) -> tuple of slot strings
    variants: tuple  # ((label, prefix regex), ...), tried in order


def _load(path):
    """The presets of a TOML file laid out as presets.toml is, in its order."""
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    return tuple(Preset(name=p["name"], sides=tuple(p["sides"]),
                        table={group: tuple(slots) for group, slots in p["table"].items()},
                        variants=tuple(tuple(v) for v in p["variants"])) for p in data["preset"])


PRESETS = _load(Path(__file__).with_suffix(".toml"))
