"""Writing Blender data: keyframes straight into F-Curves."""
