"""Which scene to load and how: the `--data.*` options of every command that reads a scene."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from splatu.data.poster.config import PosterConfig


@dataclass
class DataConfig:
    data: str = "poster"
    """Scene: `poster` (the real capture if present, else the built-in stand-in) or a path to a scene folder or
    transforms.json (nerfstudio, COLMAP sparse/0, or NeRF-synthetic transforms_*.json)."""
    downscale: int | None = None
    """Load images at 1/N resolution, from images_N folders when present; None means full resolution."""
    eval_split: Literal["auto", "contiguous", "every-n", "list"] = "auto"
    """auto: the scene file's own train/eval lists when present, else contiguous."""
    eval_block: int = 0
    """Length of the contiguous eval block; 0 means 22% of the frames (the paper held out 50 of 226)."""
    eval_every: int = 8
    """every-n split: hold out frames 0, n, 2n, ..."""
    eval_list: Path | None = None
    """list split: a text file naming one eval image per line, as the scene names it."""
    split_seed: int = 0
    """Seed for where the contiguous eval block starts."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB colour that RGBA images (NeRF-synthetic) are composited on."""
    cache_dir: Path | None = None
    """Where decoded, undistorted and resized images are cached; None means $SPLATU_CACHE or ~/.cache/splatu."""
    poster: PosterConfig = field(default_factory=PosterConfig)
    """The built-in stand-in, used by `--data poster` when the real capture is absent."""
