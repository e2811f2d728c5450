"""Differentiable 3DGS rasterizer in pure torch: `rasterize(...) -> RasterOutput`."""

from splatu.rasterizer.errors import NonFiniteInputError, RasterInputError
from splatu.rasterizer.rasterize import RasterOutput, rasterize

__all__ = ["NonFiniteInputError", "RasterInputError", "RasterOutput", "rasterize"]
