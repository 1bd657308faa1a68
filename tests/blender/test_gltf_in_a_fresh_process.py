"""On Blender 4.2 the test modules that import or export glTF files run here, each in a fresh Python of its own
(see conftest.GLTF_MODULES for why): the suite fails when one fails there. Verbose, so that a crash names the
test it happened in."""

import os
import subprocess
import sys

import pytest

from .conftest import EXTENSION_DIR, FRESH_PROCESS, GLTF_MODULES, gltf_needs_a_fresh_process


@pytest.mark.skipif(not gltf_needs_a_fresh_process(), reason="this Blender runs them in the suite's own process")
@pytest.mark.parametrize("name", GLTF_MODULES)
def test_the_gltf_module_passes_in_a_fresh_process(name):
    path = str(EXTENSION_DIR / "tests" / "blender" / name)
    done = subprocess.run([sys.executable, "-m", "pytest", path, "-v", "-p", "no:cacheprovider"],
                          cwd=EXTENSION_DIR, env={**os.environ, FRESH_PROCESS: "1"}, capture_output=True, text=True,
                          timeout=1200)
    lines = done.stdout.strip().splitlines()
    crash = done.stderr[done.stderr.find("Fatal Python error"):][:1500] if "Fatal Python error" in done.stderr else ""
    assert done.returncode == 0, "\n".join(lines[-30:]) + "\n" + (crash or done.stderr[-2000:])
    assert " passed" in lines[-1] and "skipped" not in lines[-1], lines[-1]
