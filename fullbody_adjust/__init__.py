# SPDX-License-Identifier: GPL-3.0-or-later
"""Full Body Adjust: pose a whole character so its hands and feet reach targets, avoiding obstacles.

The Blender-facing modules are imported inside register()/unregister(), never at package import time:
`import fullbody_adjust.solver` runs this file first and must work in a Python without bpy.
"""

import importlib

# Modules with register()/unregister(), in registration order (unregistered in reverse):
# properties first because the others use them, the panel last because it draws them.
_MODULE_NAMES = (
    "properties",
    "bridge.live",
    "operators",
    "panel",
    "cli",
)


def _modules():
    return [importlib.import_module("." + name, __package__) for name in _MODULE_NAMES]


# What register() registered, so unregister() undoes exactly that (even if a module file appeared since).
_registered = []


def register():
    for module in _modules():
        module.register()
        _registered.append(module)


def unregister():
    while _registered:
        _registered.pop().unregister()
