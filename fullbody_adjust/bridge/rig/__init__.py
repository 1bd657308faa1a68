"""What an armature carries: its bone map (cached per armature), its targets, a generated Rigify rig's controls."""
