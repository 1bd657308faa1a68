"""Retargeting in Blender: clips imported as source armatures, both rigs read, the result keyed, the soles from the meshes."""
