"""The full-body adjustment (paper §5, Algorithm 1): its input checked, sub-bases, reach balls, the trunk's curl,
placing the limbs, bone rotations out, each effector's outcome."""
