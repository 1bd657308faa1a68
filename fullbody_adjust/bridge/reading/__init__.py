"""Reading Blender data: poses, frames, obstacles, the meshes' skinning and the limbs' thickness, a rig's IK limits, the space a solve works in."""
