"""The bone mapping (fullbody_adjust/bone_mapping) runs without Blender: in a fresh Python where importing bpy or
mathutils fails, every module of the package imports and a Mixamo rig maps by its names and by its shape, and neither bpy nor mathutils got loaded."""

import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent

_PROBE = """
import importlib, pkgutil, sys
sys.modules["bpy"] = None  # import bpy raises ImportError
sys.modules["mathutils"] = None
import fullbody_adjust.bone_mapping as bm
names = sorted(m.name for m in pkgutil.iter_modules(bm.__path__))
for name in names:
    importlib.import_module("fullbody_adjust.bone_mapping." + name)
from tests.test_mapping_rules import NAMED_RIGS
make, expected, label = NAMED_RIGS["mixamo"]
rig = make()
by_name, by_shape = bm.map_rig(rig), bm.detect_map(rig)
loaded = sorted(m for m in ("bpy", "mathutils") if sys.modules.get(m) is not None)
print(len(names), by_name == expected() and by_name.source == label, by_shape == expected(), loaded)
"""


def test_bone_mapping_imports_and_maps_without_bpy():
    done = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    modules, by_name, by_shape, loaded = done.stdout.split(maxsplit=3)
    assert int(modules) >= 8, done.stdout  # rig_description, bone_map, body_sides, presets, ... mapping
    assert (by_name, by_shape) == ("True", "True"), done.stdout  # the Mixamo preset, and detection, map it right
    assert loaded.strip() == "[]", done.stdout
