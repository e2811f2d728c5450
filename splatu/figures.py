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
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

from splatu.atomic import atomic_write
from splatu.ause import FRACTIONS, Curves
from splatu.errors import FREE_AND_RERUN

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


def save_panel(path: Path, rgb: np.ndarray, uncertainty: np.ndarray, u_scale: ColourScale, gt: np.ndarray | None = None,
               error: np.ndarray | None = None, e_scale: ColourScale | None = None) -> None:
    """Side by side: ground truth | render | uncertainty | error, the first and last only for views with ground truth.
    The photo beside the render shows what the error column measures, as nerfstudio's eval images pair them."""
    images = ([("ground truth", np.clip(gt, 0.0, 1.0), None)] if gt is not None else []) + [
        ("render", np.clip(rgb, 0.0, 1.0), None), (u_scale.label, uncertainty, u_scale)]
    if error is not None and e_scale is not None:
        images.append((e_scale.label, error, e_scale))
    height, width = uncertainty.shape
    fig, axes = plt.subplots(1, len(images), figsize=(len(images) * (3.2 * width / height + 0.9), 3.6))
    for ax, (title, image, scale) in zip(axes, images, strict=True):
        if scale is None:
            ax.imshow(image)
        else:
            fig.colorbar(ax.imshow(image, vmin=scale.vmin, vmax=scale.vmax, cmap=scale.cmap), ax=ax, fraction=0.046,
                         pad=0.04)
        _image_axes(ax, title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def save_orbit_gif(path: Path, rgbs: Sequence[np.ndarray], uncertainties: Sequence[np.ndarray],
                   u_scale: ColourScale, titles: Sequence[str], fps: int) -> None:
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


def distinct_oracles(curves: Mapping[str, Curves]) -> list[tuple[str, np.ndarray]]:
    """(label, oracle curve) once per distinct oracle: the first is "oracle", any other is named after
    the first method that has it, since only a method scored on other renders can have another."""
    found: list[tuple[str, np.ndarray]] = []
    for name, curve in curves.items():
        if not any(np.allclose(curve.oracle, oracle) for _, oracle in found):
            found.append(("oracle" if not found else f"oracle ({name}'s renders)", curve.oracle))
    return found


def plot_sparsification(path: Path, curves: Mapping[str, Curves], title: str, metric: str) -> None:
    """Sparsification curves of several methods on one figure, with their oracles.

    The curves come start-normalised (divided by O(0), `ause.start_normalised`), so methods
    evaluated on the same images share one oracle and their gaps read as start-normalised AUSE.
    A method scored on renders of its own (the ensemble's mean render) has its own oracle: it is
    drawn too, dotted and named, so that method's gap is read against the right curve.
    """
    fig, ax = plt.subplots(figsize=(5.5, 4.0))
    for name, curve in curves.items():
        ax.plot(FRACTIONS, curve.sparsification, label=name)
    for index, (label, oracle) in enumerate(distinct_oracles(curves)):
        ax.plot(FRACTIONS, oracle, color="k", linestyle="--" if index == 0 else ":", label=label)
    ax.set_xlabel("fraction of pixels removed (most uncertain first)")
    ax.set_ylabel(f"{metric.upper()} of kept pixels / {metric.upper()} of all")
    ax.set_title(textwrap.fill(title, 70), fontsize=8)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_whole(fig, path)


def save_whole(fig: plt.Figure, path: Path) -> None:
    """A plot beside the numbers it shows: written whole or not at all (`atomic_write`), so a full disk or a kill
    never leaves a torn PNG next to its JSON; a refused write is one line."""
    try:
        atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110), FREE_AND_RERUN)
    finally:
        plt.close(fig)


@dataclass(frozen=True)
class SpeedPoint:
    """One method at one training budget: what it cost and what it scored."""

    wall_seconds: float
    """Wall time of its training (and of its own pass, for a baseline), measured the same way for every method: the
    study times each training around the trainer call (not summary.json's train_seconds, the time inside steps)."""
    ause_ratio: float
    """AUSE-MAE ÷ the random baseline on the same images: budgets score different images, so raw AUSE does not
    compare across them."""
    psnr: float | None
    """None where the PSNR is another point's (a baseline rendered on ours' Gaussians)."""


BUDGET_MARKERS = {"quick": "o", "fast": "s", "quality": "^"}
"""A fixed marker per budget, so one budget looks the same on every figure; other names take OTHER_MARKERS."""
OTHER_MARKERS = ("D", "v", "P", "X")


def budget_markers(budgets: Sequence[str]) -> dict[str, str]:
    others = iter(OTHER_MARKERS * len(budgets))
    return {b: BUDGET_MARKERS.get(b) or next(others) for b in budgets}


def method_lines(budgets: Mapping[str, Mapping[str, SpeedPoint]], field: str) -> dict[str, list[tuple[float, float]]]:
    """Per method, its (training wall seconds, `field`) points over the budgets that have one, cheapest first."""
    lines: dict[str, list[tuple[float, float]]] = {}
    for points in budgets.values():
        for method, point in points.items():
            value = getattr(point, field)
            if value is not None:
                lines.setdefault(method, []).append((point.wall_seconds, value))
    return {method: sorted(points) for method, points in lines.items()}


def plot_speed_against_error(path: Path, budgets: Mapping[str, Mapping[str, SpeedPoint]], title: str) -> None:
    """Two panels, training wall time against AUSE ÷ random and against PSNR: a colour per method, a marker per budget
    (preset), and a line joining one method's budgets, so what more training buys each method reads directly."""
    methods = list(dict.fromkeys(m for points in budgets.values() for m in points))
    palette = [*plt.get_cmap("tab10").colors, *plt.get_cmap("Dark2").colors]  # neighbours stay distinct
    colours = {m: palette[k % len(palette)] for k, m in enumerate(methods)}
    markers = budget_markers(list(budgets))
    fig, axes = plt.subplots(1, 2, figsize=(12.0, 4.8))
    for ax, field in zip(axes, ("ause_ratio", "psnr"), strict=True):
        for method, points in method_lines(budgets, field).items():
            if len(points) > 1:
                ax.plot(*zip(*points, strict=True), color=colours[method], lw=0.8, alpha=0.6)
        for budget, points in budgets.items():
            for method, point in points.items():
                if (value := getattr(point, field)) is not None:
                    ax.scatter(point.wall_seconds, value, color=colours[method], marker=markers[budget],
                               edgecolors="black", linewidths=0.4, zorder=3)
    seconds = [p.wall_seconds for points in budgets.values() for p in points.values()]
    subs = (1.0, 2.0, 5.0) if seconds and max(seconds) <= 100.0 * min(seconds) else (1.0,)
    method_keys = [plt.Line2D([], [], color=colours[m], marker="o", ls="", label=m) for m in methods]
    budget_keys = [plt.Line2D([], [], color="white", markeredgecolor="black", marker=mk, ls="",
                              label=f"budget: {b}")
                   for b, mk in markers.items()]
    fig.legend(handles=method_keys + budget_keys, loc="center right", fontsize=7, frameon=False)
    labels = ("AUSE-MAE ÷ random, same images (lower is better)", "PSNR dB (higher is better)")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(subs=subs))  # labelled ticks only where they fit
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("training wall time, s (log)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(textwrap.fill(title, 120), fontsize=9)
    fig.tight_layout(rect=(0.0, 0.0, 0.8, 1.0))
    save_whole(fig, path)
