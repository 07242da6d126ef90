"""Leaf registration: denoising, PCA frames, control points, differentiable MLS fitting."""
