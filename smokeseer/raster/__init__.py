"""Differentiable Gaussian rasterization (pure-PyTorch CPU/any-device backend, gsplat on CUDA)."""

from smokeseer.raster.api import gsplat_available, rasterize
from smokeseer.raster.output import RasterOutput
from smokeseer.raster.ply import GaussianPly, read_ply, write_ply
from smokeseer.raster.sh import eval_sh

__all__ = ["GaussianPly", "RasterOutput", "eval_sh", "gsplat_available", "rasterize", "read_ply", "write_ply"]
