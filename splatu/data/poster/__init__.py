"""The built-in `poster` stand-in: a chair with a poster, rendered exactly, with ground truth.

It mirrors the real nerfstudio poster capture (a video path above and around a chair) and adds
what no capture has: true depth and, per pixel, whether any training camera saw the surface.
"""

from splatu.data.poster.config import PosterConfig
from splatu.data.poster.generate import build_poster_standin

__all__ = ["PosterConfig", "build_poster_standin"]
