# SPDX-License-Identifier: GPL-3.0-or-later
"""The extension's entry point: Blender loads the folder that holds blender_manifest.toml and wants its
__init__.py there; all the code, and register()/unregister(), live in the fullbody_adjust package beside it."""

from .fullbody_adjust import register, unregister

__all__ = ("register", "unregister")
