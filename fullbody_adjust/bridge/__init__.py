"""Blender-side code: the only layer that reads and writes Blender data."""
