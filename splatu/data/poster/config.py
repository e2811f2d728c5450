"""Settings of the built-in poster stand-in; every field changes the generated scene's cache key."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PosterConfig:
    width: int = 144
    """Image width in pixels (portrait, like the real 1080x1920 capture scaled for 2 CPU cores)."""
    height: int = 256
    """Image height in pixels."""
    frames: int = 150
    """Frames along the video-like camera path (the real capture has 226)."""
    eval_block: int = 33
    """Consecutive frames held out as the eval split (~22%, like 50 of 226): an unseen angle."""
    interp_every: int = 8
    """Of the frames left after the block, every n-th is held out too (interpolation eval)."""
    seed: int = 0
    """Seed of the eval block position, the path jitter and the initial points."""
    points: int = 20000
    """Sparse initial points, sampled on surfaces the training cameras see, as SfM would give."""
    point_noise: float = 0.005
    """Std of the noise on initial points, as a fraction of the mean camera-to-target distance."""
    vertical_fov_degrees: float = 60.0
    """Vertical field of view of the pinhole camera."""
    arc_degrees: float = 240.0
    """Azimuth range the path sweeps around the chair, centred on its front."""
    supersample: int = 2
    """RGB is averaged over supersample x supersample rays per pixel (anti-aliasing); depth uses the centre ray."""
