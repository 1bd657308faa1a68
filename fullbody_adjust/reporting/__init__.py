"""What a run tells its user: the JSON report, the console progress line and the before/after picture.

Pure Python + numpy (no bpy): the bridge hands over plain arrays, so all of this is testable without Blender.
"""
