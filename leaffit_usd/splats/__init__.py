"""3DGS input/output: the GaussianCloud value, PLY and USD readers/writers, frames, the splat renderer."""
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.frame import Frame
from leaffit_usd.splats.ply import read_ply, write_ply

__all__ = ["GaussianCloud", "Frame", "read_ply", "write_ply"]
