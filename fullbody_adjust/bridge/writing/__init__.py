"""Writing Blender data: solved transforms as pose bones' channels, and keyframes straight into F-Curves."""
