"""Tests that run inside Blender through the bpy wheel.

Without bpy this whole directory is left out, so the solver tests still run in a plain Python.
With bpy, the real extension is registered once per session the way Blender loads extensions (a package folder
in an extensions repository, enabled as `bl_ext.<repo>.fullbody_adjust`), and every test starts from a fresh
empty file.
"""

import importlib.util
from pathlib import Path

import pytest

HAS_BPY = importlib.util.find_spec("bpy") is not None
if not HAS_BPY:
    collect_ignore_glob = ["*"]

PACKAGE_DIR = Path(__file__).resolve().parents[2] / "fullbody_adjust"
TEST_REPO = "fba_test"


def pytest_report_header(config):
    if not HAS_BPY:
        return "tests/blender: left out, bpy is not importable in this Python"


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
    """The registered extension's module (`bl_ext.fba_test.fullbody_adjust`), enabled for the whole session."""
    import bpy

    repo_dir = tmp_path_factory.mktemp("extensions")
    (repo_dir / PACKAGE_DIR.name).symlink_to(PACKAGE_DIR, target_is_directory=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    repo = add_extensions_repo(TEST_REPO, repo_dir)
    module_name = f"bl_ext.{TEST_REPO}.{PACKAGE_DIR.name}"
    module = enable_extension(module_name)
    yield module
    disable_extension(module_name)
    bpy.context.preferences.extensions.repos.remove(repo)


@pytest.fixture(scope="session")
def extension_module_name(extension):
    """The registered module's name, e.g. for importlib.import_module(f"{extension_module_name}.bridge")."""
    return extension.__name__


@pytest.fixture(autouse=True)
def empty_file():
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def extension_disabled(extension_module_name):
    """The session's extension disabled for one test (which may enable and disable it), enabled again after."""
    import addon_utils

    disable_extension(extension_module_name)
    try:
        yield extension_module_name
    finally:
        if addon_utils.check(extension_module_name)[1]:
            disable_extension(extension_module_name)
        enable_extension(extension_module_name)


@pytest.fixture
def rig():
    """Rigify's basic human metarig (29 bones), added to the empty file and active (a test module may define
    its own `rig`)."""
    import bpy

    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    return bpy.context.object
