"""The extension as Blender sees it: manifest, built package, registration, settings and the sidebar panel."""

import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path
from types import SimpleNamespace

import bpy  # first: it puts Blender's own modules (addon_utils) on sys.path
import addon_utils
import pytest

from .conftest import (EXTENSION_DIR, EXTENSION_ID, PACKAGE_DIR, add_extensions_repo, disable_extension,
                       enable_extension)

EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R", "head")


@pytest.fixture(scope="module")
def extension_cli():
    """Blender's own `blender --command extension` handler (validate, build), from the bundled bl_pkg."""
    sys.path.insert(0, os.path.join(bpy.utils.system_resource('SCRIPTS'), "addons_core"))
    from bl_pkg.bl_extension_cli import cli_extension_handler

    return cli_extension_handler


def new_armature(name="Rig"):
    obj = bpy.data.objects.new(name, bpy.data.armatures.new(name))
    bpy.context.scene.collection.objects.link(obj)
    return obj


# --- manifest and package -----------------------------------------------------------------------------------

def test_manifest_passes_blenders_validator(extension_cli, capsys):
    assert extension_cli(["validate", str(EXTENSION_DIR)]) == 0, capsys.readouterr().out


def test_manifest_declares_the_contract():
    manifest = tomllib.loads((EXTENSION_DIR / "blender_manifest.toml").read_text(encoding="utf-8"))
    assert manifest["id"] == EXTENSION_ID == PACKAGE_DIR.name == "fullbody_adjust"
    assert re.fullmatch(r"\d+\.\d+\.\d+", manifest["version"])
    assert manifest["blender_version_min"] == "4.2.0"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert {"Animation", "Rigging"} <= set(manifest["tags"])
    # Only file access (the command line's .blend/.json/.png); no network, clipboard, camera or microphone.
    assert set(manifest.get("permissions", {})) == {"files"}


def package_files(root):
    """Every file under `root` less Python caches and dot-files, as paths relative to it."""
    return {
        path.relative_to(root).as_posix()
        for path in root.rglob("*")
        if path.is_file()
        and "__pycache__" not in path.parts
        and not any(part.startswith(".") for part in path.relative_to(root).parts)
    }


def shipped_files():
    """What an installed copy needs: the entry point, the manifest, the licence and the package's own files."""
    package = {f"{PACKAGE_DIR.name}/{name}" for name in package_files(PACKAGE_DIR)}
    return {"__init__.py", "blender_manifest.toml", "LICENSE"} | package


# Development files a checkout may hold (beside what git tracks) that the package must leave out.
CLUTTER = ("__pycache__/__init__.cpython-311.pyc", "fullbody_adjust/__pycache__/cli.cpython-311.pyc",
           "fullbody_adjust/solver/__pycache__/tree.cpython-313.pyc", "fullbody_adjust/.notes.txt",
           ".git/HEAD", ".pytest_cache/README.md", ".hypothesis/examples/x", "dist/fullbody_adjust-0.0.9.zip",
           "old-build.zip", "scene.blend1", "sample_scenes/scene.blend", "tests/test_new.py", "bench/run.py", ".ci/new-step")


@pytest.fixture
def built_zip(extension_cli, tmp_path, capsys):
    """The zip Blender's build command makes from a copy of the repository with development clutter planted in
    it, and the files it must hold."""
    source = tmp_path / "checkout"
    shutil.copytree(EXTENSION_DIR, source, ignore=shutil.ignore_patterns("__pycache__", ".git", ".pytest_cache", ".hypothesis", "dist", "*.zip"))
    for clutter in CLUTTER:
        (source / clutter).parent.mkdir(parents=True, exist_ok=True)
        (source / clutter).write_bytes(b"x")
    out = tmp_path / "dist"
    out.mkdir()
    code = extension_cli(["build", "--source-dir", str(source), "--output-dir", str(out)])
    assert code == 0, capsys.readouterr().out
    (zip_path,) = out.glob("*.zip")
    return zip_path, shipped_files()


def test_built_zip_holds_the_entry_point_manifest_licence_and_package_only(built_zip):
    zip_path, expected = built_zip
    with zipfile.ZipFile(zip_path) as archive:
        names = {name for name in archive.namelist() if not name.endswith("/")}
    assert {"__init__.py", "blender_manifest.toml", "LICENSE", "fullbody_adjust/__init__.py",
            "fullbody_adjust/solver/fullbody/adjust.py"} <= expected
    assert names == expected


def test_built_zip_installs_and_enables(built_zip, extension_disabled, tmp_path):
    zip_path, expected = built_zip
    install_dir = tmp_path / "installed"
    install_dir.mkdir()
    repo = add_extensions_repo("fba_zip", install_dir)
    module_name = f"bl_ext.fba_zip.{EXTENSION_ID}"
    try:
        result = bpy.ops.extensions.package_install_files(
            filepath=str(zip_path), repo=repo.module, enable_on_install=True,
        )
        assert result == {'FINISHED'}
        assert addon_utils.check(module_name) == (True, True)
        # The enabled code is the installed copy, not the session's source folder.
        installed = install_dir / EXTENSION_ID
        assert Path(sys.modules[module_name].__file__).resolve().parent == installed.resolve()
        assert package_files(installed) == expected
        rig = new_armature()
        assert rig.fullbody_adjust.variant == 'PRIORITY'
    finally:
        repos = bpy.context.preferences.extensions.repos
        bpy.ops.extensions.package_uninstall(repo_index=list(repos).index(repo), pkg_id=EXTENSION_ID)
        repos.remove(repo)
    assert addon_utils.check(module_name) == (False, False)
    assert not (install_dir / EXTENSION_ID).exists()


# --- registration -------------------------------------------------------------------------------------------

def registered_package_classes(module_name):
    """Blender classes defined anywhere in the package that are registered right now."""
    found, pending = [], [bpy.types.bpy_struct]
    while pending:
        cls = pending.pop()
        pending.extend(cls.__subclasses__())
        if cls.__module__.startswith(module_name + ".") and cls.is_registered:
            found.append(cls.__name__)
    return sorted(found)


def registry_state():
    return {
        "types": sorted(name for name in dir(bpy.types) if "fullbody_adjust" in name.lower()),
        "object properties": sorted(prop.identifier for prop in bpy.types.Object.bl_rna.properties),
        "operators": sorted(name for name in dir(bpy.ops) if "fullbody_adjust" in name.lower()),
    }


def test_enable_disable_three_times_leaves_nothing_behind(extension_disabled):
    module_name = extension_disabled
    before = registry_state()
    assert before["types"] == [] and before["operators"] == []
    assert "fullbody_adjust" not in before["object properties"]
    for _ in range(3):
        enable_extension(module_name)
        assert addon_utils.check(module_name) == (True, True)
        assert hasattr(bpy.types.Object, "fullbody_adjust")
        assert "FULLBODY_ADJUST_PT_main" in dir(bpy.types)
        assert {"FULLBODY_ADJUST_PG_settings", "FULLBODY_ADJUST_PG_target"} <= set(
            registered_package_classes(module_name))
        new_armature().fullbody_adjust.targets.add().effector = "foot.R"

        disable_extension(module_name)
        assert addon_utils.check(module_name) == (False, False)
        assert not hasattr(bpy.types.Object, "fullbody_adjust")
        assert registered_package_classes(module_name) == []
        assert dir(bpy.ops.fullbody_adjust) == []
        assert registry_state() == before


def test_package_and_solver_import_in_a_python_without_bpy():
    # The solver tests run without Blender: importing the package must not need bpy (a blocked import here).
    code = ("import sys; sys.modules['bpy'] = None; "
            "import fullbody_adjust, fullbody_adjust.solver; "
            "assert callable(fullbody_adjust.register)")
    done = subprocess.run([sys.executable, "-c", code], cwd=EXTENSION_DIR, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_without_bpy_every_blender_test_module_is_reported_skipped_with_the_reason():
    # A Python without bpy (the import blocked here) collects this folder's modules as skipped, not silently
    # left out, and imports none of them.
    modules = sorted(path.name for path in Path(__file__).parent.glob("test_*.py"))
    code = ("import sys; sys.modules['bpy'] = None; import pytest; "
            "sys.exit(pytest.main(['tests/blender', '-q', '-rs', '-p', 'no:cacheprovider']))")
    done = subprocess.run([sys.executable, "-c", code], cwd=EXTENSION_DIR, capture_output=True, text=True,
                          timeout=120)
    # Nothing to run but no error either: pytest's 'no tests collected'.
    assert done.returncode == pytest.ExitCode.NO_TESTS_COLLECTED, done.stdout + done.stderr
    summary = done.stdout.strip().splitlines()[-1]
    assert re.match(rf"{len(modules)} skipped in ", summary), done.stdout
    assert f"SKIPPED [{len(modules)}]" in done.stdout and "bpy is not importable" in done.stdout


# --- settings -----------------------------------------------------------------------------------------------

def test_settings_defaults_follow_the_design():
    settings = new_armature().fullbody_adjust
    assert settings.variant == 'PRIORITY'
    assert settings.margin == pytest.approx(0.01)
    assert settings.use_joint_limits and settings.keep_hand_orientation
    assert settings.obstacles is None
    assert len(settings.targets) == 0 and len(settings.bone_map) == 0
    variants = settings.bl_rna.properties["variant"].enum_items.keys()
    assert variants == ["FABRIK", "WEIGHTED", "PRIORITY"]
    slot = settings.targets.add()
    assert tuple(slot.bl_rna.properties["effector"].enum_items.keys()) == EFFECTORS
    assert (slot.effector, slot.target, slot.enabled) == ("hand.L", None, True)


def test_settings_survive_saving_and_reopening(tmp_path):
    rig = new_armature()
    target = bpy.data.objects.new("FootTarget", None)
    bpy.context.scene.collection.objects.link(target)
    walls = bpy.data.collections.new("Walls")
    bpy.context.scene.collection.children.link(walls)
    settings = rig.fullbody_adjust
    slot = settings.targets.add()
    slot.effector, slot.target, slot.priority, slot.enabled = "foot.R", target, 5, False
    settings.obstacles = walls
    for group, bone in (("trunk", "spine.001"), ("trunk", "spine.002"), ("arm.L", "upper_arm.L")):
        item = settings.bone_map.add()
        item.group, item.bone = group, bone
    settings.variant, settings.margin, settings.max_iterations = 'WEIGHTED', 0.05, 50
    settings.use_joint_limits = False

    path = tmp_path / "settings.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert "Rig" not in bpy.data.objects
    bpy.ops.wm.open_mainfile(filepath=str(path))

    settings = bpy.data.objects["Rig"].fullbody_adjust
    (slot,) = settings.targets
    assert (slot.effector, slot.target.name, slot.priority, slot.enabled) == ("foot.R", "FootTarget", 5, False)
    assert settings.obstacles.name == "Walls"
    assert [(item.group, item.bone) for item in settings.bone_map] == [
        ("trunk", "spine.001"), ("trunk", "spine.002"), ("arm.L", "upper_arm.L")]
    assert (settings.variant, settings.max_iterations, settings.use_joint_limits) == ('WEIGHTED', 50, False)
    assert settings.margin == pytest.approx(0.05)


# --- sidebar panel ------------------------------------------------------------------------------------------

class LayoutRecorder:
    """Stands in for a UILayout: records what a draw() call asks for (no window exists in background mode)."""

    def __init__(self):
        self.enabled = True
        self.active = True
        self.use_property_split = False
        self.children = []
        self.props = []
        self.labels = []
        self.lists = []
        self.operators = []
        self.searches = []

    def _child(self, **_):
        child = LayoutRecorder()
        self.children.append(child)
        return child

    row = column = box = split = _child

    def prop(self, data, name, **_):
        self.props.append((data, name))

    def label(self, *, text="", **_):
        self.labels.append(text)

    def operator(self, idname, **_):
        self.operators.append(idname)

    def prop_search(self, data, name, search_data, search_name, **_):
        self.props.append((data, name))
        self.searches.append((search_data, search_name))

    def template_list(self, list_type, list_id, data, prop, active_data, active_prop, **_):
        self.lists.append((list_type, data, prop, active_data, active_prop))

    def walk(self):
        yield self
        for child in self.children:
            yield from child.walk()

    def all_props(self):
        return [(data, name) for layout in self.walk() for (data, name) in layout.props]

    def all_operators(self):
        return [idname for layout in self.walk() for idname in layout.operators]

    def all_labels(self):
        return [text for layout in self.walk() for text in layout.labels]


def draw_panel(panel_name, active_object):
    layout = LayoutRecorder()
    panel_class = getattr(bpy.types, panel_name)
    panel_class.draw(SimpleNamespace(layout=layout), SimpleNamespace(active_object=active_object))
    return layout


def test_panel_is_a_full_body_tab_in_the_viewport_sidebar():
    panel = bpy.types.FULLBODY_ADJUST_PT_main
    assert (panel.bl_space_type, panel.bl_region_type, panel.bl_category) == ('VIEW_3D', 'UI', "Full Body")
    assert bpy.types.FULLBODY_ADJUST_PT_solver.bl_parent_id == "FULLBODY_ADJUST_PT_main"


def test_panel_draws_the_armatures_targets_obstacles_and_variant():
    rig = new_armature()
    settings = rig.fullbody_adjust
    for effector in EFFECTORS:
        settings.targets.add().effector = effector
    layout = draw_panel("FULLBODY_ADJUST_PT_main", rig)
    assert layout.enabled
    # Every button runs a registered operator of ours.
    assert set(layout.all_operators()) == {"fullbody_adjust.map_bones", "fullbody_adjust.create_targets",
                                           "fullbody_adjust.adjust_pose", "fullbody_adjust.adjust_frames",
                                           "fullbody_adjust.retarget", "fullbody_adjust.mirror_pose"}
    for idname in layout.all_operators():
        module, name = idname.split(".")
        assert getattr(getattr(bpy.ops, module), name).get_rna_type() is not None

    (list_type, data, prop, active_data, active_prop), = layout.lists
    assert getattr(bpy.types, list_type).bl_rna.identifier == list_type
    assert data == settings and prop == "targets"
    assert active_data == settings and active_prop in settings.bl_rna.properties
    drawn = {name for data, name in layout.all_props() if data == settings}
    assert {"obstacles", "variant"} <= drawn

    # Each list row draws the slot's own properties (Blender would only print an error for a wrong name).
    row = LayoutRecorder()
    getattr(bpy.types, list_type).draw_item(
        None, None, row, settings, settings.targets[0], 0, settings, active_prop, 0)
    row_props = row.all_props()
    assert {name for _, name in row_props} == {"enabled", "effector", "target", "priority", "use_rotation", "pole"}
    for panel_name in ("FULLBODY_ADJUST_PT_main", "FULLBODY_ADJUST_PT_solver"):
        for data, name in draw_panel(panel_name, rig).all_props() + row_props:
            assert name in data.bl_rna.properties, f"{panel_name} draws unknown property {name!r}"


def test_panel_shows_the_stored_bone_map_and_lets_each_bone_be_picked_from_the_rig():
    rig = new_armature()
    settings = rig.fullbody_adjust
    assert "Not mapped yet" in draw_panel("FULLBODY_ADJUST_PT_main", rig).all_labels()
    for group, bone in (("trunk", "spine.001"), ("arm.L", "upper_arm.L")):
        item = settings.bone_map.add()
        item.group, item.bone = group, bone
    assert "Mapped: 2 bones" in draw_panel("FULLBODY_ADJUST_PT_main", rig).all_labels()

    (list_type, data, prop, active_data, active_prop), = draw_panel("FULLBODY_ADJUST_PT_mapping", rig).lists
    assert (data, prop) == (settings, "bone_map") and active_prop in settings.bl_rna.properties
    row = LayoutRecorder()
    getattr(bpy.types, list_type).draw_item(None, None, row, settings, settings.bone_map[1], 0, settings,
                                            active_prop, 0)
    assert row.all_labels() == ["Left Arm"]
    assert row.all_props() == [(settings.bone_map[1], "bone")]
    assert row.searches == [] and row.children[0].searches == [(rig.data, "bones")]


def test_panel_is_greyed_out_and_solver_settings_hidden_without_an_active_armature():
    rig = new_armature()
    mesh_object = bpy.data.objects.new("Box", bpy.data.meshes.new("Box"))
    for active in (mesh_object, None):
        layout = draw_panel("FULLBODY_ADJUST_PT_main", active)
        assert not layout.enabled
        assert layout.labels[0] == ("Select an armature" if active is None
                                    else "'Box' is not an armature: select an armature")
        assert layout.all_props() == [] and layout.all_operators() == []
        for sub_panel in (bpy.types.FULLBODY_ADJUST_PT_solver, bpy.types.FULLBODY_ADJUST_PT_mapping):
            assert not sub_panel.poll(SimpleNamespace(active_object=active))
    assert "Targets" in draw_panel("FULLBODY_ADJUST_PT_main", rig).all_labels()
    assert bpy.types.FULLBODY_ADJUST_PT_solver.poll(SimpleNamespace(active_object=rig))
