"""Input checks for `rasterize`: a bad tensor fails loudly with one line instead of rendering NaNs."""

from __future__ import annotations

import torch
from torch import Tensor

from splatu.errors import SplatuError


class RasterInputError(SplatuError, ValueError):
    """An input to `rasterize` has the wrong shape or size."""


class NonFiniteInputError(RasterInputError):
    """An input to `rasterize` holds NaN or Inf; rendering it would silently poison the image and gradients."""


def require_finite(name: str, tensor: Tensor) -> None:
    """Raise `NonFiniteInputError` naming `name` and the count of bad entries."""
    bad = int((~tensor.isfinite()).sum())
    if bad:
        raise NonFiniteInputError(
            f"rasterize input `{name}` has {bad} non-finite (NaN/Inf) entr{'y' if bad == 1 else 'ies'}",
            f"in a tensor of shape {tuple(tensor.shape)}",
            "find the step that produced it (often a too-high learning rate or a corrupt camera pose)",
        )


def require_float32_range(name: str, tensor: Tensor) -> None:
    """Raise `RasterInputError` if `tensor` (finite) holds values beyond float32's range, which only a float64 one can:
    the projection's float64 algebra (f·x/z², squares of the footprint) has room above float32's range, not
    beyond it."""
    if tensor.dtype != torch.float64:
        return
    bad = int((tensor.abs() > torch.finfo(torch.float32).max).sum())
    if bad:
        raise RasterInputError(
            f"rasterize input `{name}` has {bad} entr{'y' if bad == 1 else 'ies'} beyond float32's range (±3.4e38)",
            f"in a float64 tensor of shape {tuple(tensor.shape)}",
            "rescale the scene or the camera: float64 renders take float32's range, with more precision",
        )


def require_shape(name: str, tensor: Tensor, shape: tuple[int | None, ...]) -> None:
    """Raise `RasterInputError` unless `tensor` has `shape` (None matches any size)."""
    sizes = zip(shape, tensor.shape, strict=False)
    ok = tensor.dim() == len(shape) and all(want is None or want == got for want, got in sizes)
    if not ok:
        expected = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
        raise RasterInputError(
            f"rasterize input `{name}` has shape {tuple(tensor.shape)}",
            f"expected {expected}",
            "pass tensors with matching Gaussian counts and channel sizes",
        )
