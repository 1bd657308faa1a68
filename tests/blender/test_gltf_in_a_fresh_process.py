"""On Blender 4.2 the test modules that import glTF files run here, together, in a fresh Python (see
conftest.GLTF_MODULES for why): the suite fails when they fail there."""

import os
import subprocess
import sys

import pytest

from .conftest import EXTENSION_DIR, FRESH_PROCESS, GLTF_MODULES, gltf_needs_a_fresh_process


@pytest.mark.skipif(not gltf_needs_a_fresh_process(), reason="this Blender runs them in the suite's own process")
def test_the_gltf_modules_pass_in_a_fresh_process():
    files = [str(EXTENSION_DIR / "tests" / "blender" / name) for name in GLTF_MODULES]
    done = subprocess.run([sys.executable, "-m", "pytest", *files, "-q", "-p", "no:cacheprovider"],
                          cwd=EXTENSION_DIR, env={**os.environ, FRESH_PROCESS: "1"}, capture_output=True, text=True,
                          timeout=1200)
    lines = done.stdout.strip().splitlines()
    assert done.returncode == 0, "\n".join(lines[-40:]) + done.stderr[-2000:]
    assert " passed" in lines[-1] and "skipped" not in lines[-1], lines[-1]
