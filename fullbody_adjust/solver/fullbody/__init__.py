"""The full-body adjustment (paper §5, Algorithm 1): sub-bases, reach balls, the trunk's curl, placing the limbs, bone rotations out."""
