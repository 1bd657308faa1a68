"""The body model (paper §5.1): five IK groups joined by two sub-bases, built from the joints of any rig, and where it faces."""
