"""Every picture splatu writes: colour-mapped maps, panels, orbit GIFs and curve plots.

Matplotlib runs on the Agg backend so nothing needs a display. Colour scales are passed in,
never taken per image, so maps of different views (and methods) are comparable by eye.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter

from splatu.ause import FRACTIONS, Curves

UNCERTAINTY_CMAP = "inferno"
ERROR_CMAP = "magma"
DEPTH_CMAP = "viridis"


@dataclass(frozen=True)
class ColourScale:
    """A fixed value range and colour map shared by every view of one quantity."""

    vmin: float
    vmax: float
    cmap: str
    label: str


def _image_axes(ax: plt.Axes, title: str) -> None:
    ax.set_title(title, fontsize=9)
    ax.set_axis_off()


def colour_map(values: np.ndarray, scale: ColourScale) -> np.ndarray:
    """(H, W) values to (H, W, 3) uint8 RGB on the shared scale (values outside it saturate)."""
    span = max(scale.vmax - scale.vmin, 1e-12)
    normalised = np.clip((values - scale.vmin) / span, 0.0, 1.0)
    return (matplotlib.colormaps[scale.cmap](normalised)[..., :3] * 255.0 + 0.5).astype(np.uint8)


def save_colour_bar(path: Path, scale: ColourScale) -> None:
    """The legend every colour-mapped PNG of one quantity shares."""
    fig, ax = plt.subplots(figsize=(1.3, 4.0))
    norm = matplotlib.colors.Normalize(vmin=scale.vmin, vmax=scale.vmax)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=scale.cmap), cax=ax, label=scale.label)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def save_panel(path: Path, rgb: np.ndarray, uncertainty: np.ndarray, u_scale: ColourScale,
               error: np.ndarray | None = None, e_scale: ColourScale | None = None) -> None:
    """Side by side: render | uncertainty | error (the error only when ground truth exists)."""
    columns = 3 if error is not None else 2
    height, width = uncertainty.shape
    fig, axes = plt.subplots(1, columns, figsize=(columns * (3.2 * width / height + 0.9), 3.6))
    axes[0].imshow(np.clip(rgb, 0.0, 1.0))
    _image_axes(axes[0], "render")
    im = axes[1].imshow(uncertainty, vmin=u_scale.vmin, vmax=u_scale.vmax, cmap=u_scale.cmap)
    _image_axes(axes[1], u_scale.label)
    fig.colorbar(im, ax=axes[1], fraction=0.046, pad=0.04)
    if error is not None and e_scale is not None:
        im = axes[2].imshow(error, vmin=e_scale.vmin, vmax=e_scale.vmax, cmap=e_scale.cmap)
        _image_axes(axes[2], e_scale.label)
        fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.04)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def save_orbit_gif(path: Path, rgbs: Sequence[np.ndarray], uncertainties: Sequence[np.ndarray],
                   u_scale: ColourScale, titles: Sequence[str], fps: int = 8) -> None:
    """Animated GIF of the orbit, render beside uncertainty, on one fixed colour scale."""
    height, width = uncertainties[0].shape
    fig, axes = plt.subplots(1, 2, figsize=(2 * (3.2 * width / height + 0.9), 3.6))
    rgb_image = axes[0].imshow(np.clip(rgbs[0], 0.0, 1.0))
    u_image = axes[1].imshow(uncertainties[0], vmin=u_scale.vmin, vmax=u_scale.vmax, cmap=u_scale.cmap)
    _image_axes(axes[0], titles[0])
    _image_axes(axes[1], u_scale.label)
    fig.colorbar(u_image, ax=axes[1], fraction=0.046, pad=0.04)

    def show(frame: int) -> list:
        rgb_image.set_data(np.clip(rgbs[frame], 0.0, 1.0))
        u_image.set_data(uncertainties[frame])
        axes[0].set_title(titles[frame], fontsize=9)
        return [rgb_image, u_image]

    animation = FuncAnimation(fig, show, frames=len(rgbs), blit=False)
    animation.save(str(path), writer=PillowWriter(fps=fps))
    plt.close(fig)


def plot_sparsification(path: Path, curves: Mapping[str, Curves], title: str, metric: str) -> None:
    """Sparsification curves of several methods on one figure, with the (shared) oracle.

    The curves come start-normalised (divided by O(0), `ause.start_normalised`), so methods
    evaluated on the same images share one oracle and their gaps read as start-normalised AUSE.
    """
    fig, ax = plt.subplots(figsize=(5.5, 4.0))
    oracle_drawn = False
    for name, curve in curves.items():
        ax.plot(FRACTIONS, curve.sparsification, label=name)
        if not oracle_drawn:
            ax.plot(FRACTIONS, curve.oracle, "k--", label="oracle")
            oracle_drawn = True
    ax.set_xlabel("fraction of pixels removed (most uncertain first)")
    ax.set_ylabel(f"{metric.upper()} of kept pixels / {metric.upper()} of all")
    ax.set_title(textwrap.fill(title, 70), fontsize=8)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_speed_against_error(path: Path, train_seconds: Mapping[str, float], ause: Mapping[str, float],
                             psnr: Mapping[str, float], title: str) -> None:
    """Two panels: train time against AUSE, and train time against PSNR, one point per method."""
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.0))
    for name, seconds in train_seconds.items():
        if name in ause:
            axes[0].scatter(seconds, ause[name])
            axes[0].annotate(name, (seconds, ause[name]), fontsize=7)
        if name in psnr:
            axes[1].scatter(seconds, psnr[name])
            axes[1].annotate(name, (seconds, psnr[name]), fontsize=7)
    for ax, label in zip(axes, ("AUSE-MAE (lower is better)", "PSNR dB (higher is better)"), strict=True):
        ax.set_xscale("log")
        ax.set_xlabel("train time, s (log)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(textwrap.fill(title, 100), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
