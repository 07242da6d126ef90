"""Geometry shared by every stage: heat-method geodesics, farthest point sampling, kNN, PCA frames."""
