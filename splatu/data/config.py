"""Which scene to load and how: the `--data.*` options of every command that reads a scene."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from splatu.data.poster.config import PosterConfig
from splatu.errors import SplatuError, require_at_least


@dataclass
class DataConfig:
    data: str = "poster"
    """Scene: `poster` (the real capture if present, else the built-in stand-in) or a path to a scene folder or
    transforms.json (nerfstudio, COLMAP sparse/0, or NeRF-synthetic transforms_*.json)."""
    downscale: int | None = None
    """Load images at 1/N resolution, from images_N folders when present; 1 is full resolution. Not given, `train`
    picks the smallest power of two that brings every image's longer side to --max-image-size or less, as
    nerfstudio does, and records it in the run."""
    max_image_size: int = 1600
    """Without --downscale (train refuses the two typed together), images load at the smallest power-of-two fraction
    of their size whose longer side is at most this many pixels, short of a side below 8 px (nerfstudio's rule; its
    1600 px is quality's and --preset none's, fast takes 800): a phone's 12-megapixel photo would make each step on 2
    CPU cores seconds long."""
    eval_split: Literal["auto", "contiguous", "every-n", "list"] = "auto"
    """auto: the scene file's own train/eval lists when present, else contiguous."""
    eval_block: int = 0
    """Length of the contiguous eval block; 0 means 22% of the frames (the paper held out 50 of 226). Refused when
    the split does not use it (every-n, list, or auto on a scene with its own split)."""
    eval_every: int = 8
    """every-n split: hold out frames 0, n, 2n, ..."""
    eval_list: Path | None = None
    """list split: a text file naming one eval image per line, as the scene names it."""
    split_seed: int = 0
    """Seed for where the contiguous eval block starts."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB colour that RGBA images (NeRF-synthetic) are stored composited on. Their alpha is kept, and training
    and evaluation recomposite them on their own backgrounds (--train-background), so this moves results only by
    the stored images' 8- or 16-bit rounding."""
    cache_dir: Path | None = None
    """Where decoded, undistorted and resized images are cached; None means $SPLATU_CACHE or ~/.cache/splatu."""
    poster: PosterConfig = field(default_factory=PosterConfig)
    """The built-in stand-in, used by `--data poster` when the real capture is absent (refused otherwise)."""

    def validate(self) -> None:
        """Check the ranges, so a bad value fails before anything loads or is built. Only the values the split
        reads: a saved config that carried an unused out-of-range one still loads."""
        if self.downscale is not None:
            require_at_least(self.downscale, 1, "--downscale")
        else:
            require_at_least(self.max_image_size, 8, "--max-image-size")
        if self.eval_split in ("auto", "contiguous"):
            require_at_least(self.eval_block, 0, "--eval-block")
        if self.eval_split == "every-n":
            require_at_least(self.eval_every, 2, "--eval-every")
        if len(self.background) != 3 or not all(0.0 <= c <= 1.0 for c in self.background):
            raise SplatuError(f"--background must be three RGB values in [0, 1] (got {self.background})",
                              "in the options", "pass e.g. --background 1 1 1 (white) or 0 0 0 (black)")

    def refuse_unused_flags(self) -> None:
        """A new run's split flags must all shape its split. Only new runs check this (`splatu train`): a saved
        config that carried an ignored flag still loads for render, eval and resume."""
        ignored = [
            ("--eval-list", self.eval_list is not None, ("list",)),
            ("--eval-every", self.eval_every != DataConfig.eval_every, ("every-n",)),
            ("--eval-block", self.eval_block != 0, ("auto", "contiguous")),
            ("--split-seed", self.split_seed != DataConfig.split_seed, ("auto", "contiguous")),
        ]
        for flag, given, used_by in ignored:
            if given and self.eval_split not in used_by:
                raise SplatuError(f"{flag} is not used by --eval-split {self.eval_split}", "in the options",
                                  f"pass --eval-split {used_by[-1]} to use {flag}, or drop {flag}")
