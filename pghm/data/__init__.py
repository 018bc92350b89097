"""Data: motions (BVH import, procedural clips), synthetic subjects, the on-disk subject format."""
