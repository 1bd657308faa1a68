"""Tests that run inside Blender through the bpy wheel.

Without bpy every test module here is reported as skipped (with the reason), so the solver tests still run in a
plain Python and the run says what it left out. With bpy, the real extension is registered once per session the
way Blender loads extensions: the repository's root folder (the one holding blender_manifest.toml) in an
extensions repository, enabled as `bl_ext.<repo>.fullbody_adjust`, whose __init__.py registers the package
`bl_ext.<repo>.fullbody_adjust.fullbody_adjust`; every test starts from a fresh empty file.
"""

import importlib.util
import os
from pathlib import Path

import pytest

HAS_BPY = importlib.util.find_spec("bpy") is not None
WITHOUT_BPY = "bpy is not importable in this Python: the Blender tests need the bpy wheel (.ci/with-bpy)"

# The extension as Blender sees it: the folder with the manifest and the root __init__.py.
EXTENSION_DIR = Path(__file__).resolve().parents[2]
EXTENSION_ID = "fullbody_adjust"
PACKAGE_DIR = EXTENSION_DIR / "fullbody_adjust"
TEST_REPO = "fba_test"


class ModuleNeedingBpy(pytest.File):
    """Stands in for a test module of this folder in a Python without bpy: collecting it skips it."""

    def collect(self):
        pytest.skip(WITHOUT_BPY)


if not HAS_BPY:
    def pytest_pycollect_makemodule(module_path, parent):
        # Importing the module would fail on `import bpy`; a skip keeps it counted and says why.
        return ModuleNeedingBpy.from_parent(parent, path=module_path)


# Test modules that import or export glTF files. On Blender 4.2 its glTF importer crashed the process (a
# segmentation fault in the view layer update of its switch to Edit Mode) after a few hundred other tests had run in
# it, at a place that moved as tests were added or reordered, and its exporter did too (in gather_tree's construct,
# CI after 137 tests); each module alone runs clean. There they are skipped in the suite's
# own process and each runs in a fresh one of its own by test_gltf_in_a_fresh_process.py (together, they
# crashed there too, after some 400 tests).
GLTF_MODULES = ("test_mapping_import.py", "test_real_rigs.py", "test_retarget_soles.py", "test_root_motion.py",
                "test_wild_clips.py", "test_export_formats.py", "test_walk_plants.py")
FRESH_PROCESS = "FBA_GLTF_FRESH_PROCESS"


def gltf_needs_a_fresh_process():
    import bpy

    return bpy.app.version < (4, 5, 0) and not os.environ.get(FRESH_PROCESS)


def pytest_collection_modifyitems(config, items):
    if not HAS_BPY or not gltf_needs_a_fresh_process():
        return
    skip = pytest.mark.skip(reason="run in a fresh process on Blender 4.2 (test_gltf_in_a_fresh_process.py)")
    for item in items:
        if item.path.parent == EXTENSION_DIR / "tests" / "blender" and item.path.name in GLTF_MODULES:
            item.add_marker(skip)


def pytest_report_header(config):
    if not HAS_BPY:
        return f"tests/blender: skipped, {WITHOUT_BPY}"


def _raise(ex):
    raise ex


def enable_extension(module_name):
    """Enable an extension (or add-on) and return its module; an error while registering raises."""
    import addon_utils

    return addon_utils.enable(module_name, default_set=True, handle_error=_raise)


def disable_extension(module_name):
    import addon_utils

    addon_utils.disable(module_name, default_set=True, handle_error=_raise)


def add_extensions_repo(name, directory):
    """A local extensions repository named `name` whose packages live in `directory`."""
    import bpy

    return bpy.context.preferences.extensions.repos.new(
        name=name, module=name, custom_directory=str(directory), source='USER',
    )


@pytest.fixture(scope="session", autouse=True)
def extension(tmp_path_factory):
    """The enabled extension's module (`bl_ext.fba_test.fullbody_adjust`, the root __init__.py), for the whole
    session."""
    import bpy

    repo_dir = tmp_path_factory.mktemp("extensions")
    (repo_dir / EXTENSION_ID).symlink_to(EXTENSION_DIR, target_is_directory=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    repo = add_extensions_repo(TEST_REPO, repo_dir)
    module_name = f"bl_ext.{TEST_REPO}.{EXTENSION_ID}"
    module = enable_extension(module_name)
    yield module
    disable_extension(module_name)
    bpy.context.preferences.extensions.repos.remove(repo)


@pytest.fixture(scope="session")
def extension_module_name(extension):
    """The name the package's code runs under in the session's extension
    (`bl_ext.fba_test.fullbody_adjust.fullbody_adjust`), e.g. for
    importlib.import_module(f"{extension_module_name}.bridge")."""
    return f"{extension.__name__}.{PACKAGE_DIR.name}"


@pytest.fixture(scope="session")
def cli(extension_module_name):
    """The package's command line (``cli.main``, ``cli.build_parser``...) as the session's extension runs it."""
    import importlib

    return importlib.import_module(f"{extension_module_name}.cli")


@pytest.fixture(autouse=True)
def empty_file():
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def extension_disabled(extension):
    """The session's extension disabled for one test (which may enable and disable it), enabled again after;
    yields the extension's module name, the one to enable and disable."""
    import addon_utils

    module_name = extension.__name__
    disable_extension(module_name)
    try:
        yield module_name
    finally:
        if addon_utils.check(module_name)[1]:
            disable_extension(module_name)
        enable_extension(module_name)


@pytest.fixture
def rig():
    """Rigify's basic human metarig (29 bones), added to the empty file and active (a test module may define
    its own `rig`)."""
    import bpy

    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    return bpy.context.object
