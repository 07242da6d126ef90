"""Template leaf mesh extraction, UVs and two-sided texture bake, stem cylinders."""
