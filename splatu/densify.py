"""Adaptive density control with splatfacto's semantics: clone, split, cull, opacity reset.

Statistics are accumulated over a refine window of `refine_every` steps (`observe` after every
backward), then `refine` clones, splits and culls together: none of them from an opacity reset until the
pause after it ends, and culling alone from `stop_split_at` on. It edits the model through
`Optimizers.replace_rows`, so parameters and Adam state stay aligned, `u_sh` included: clones and split
children copy their parent's `u_sh`, pruned rows lose it, and the opacity reset does not touch it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from splatu.errors import SplatuError, require_at_least
from splatu.model import GaussianModel
from splatu.optim import Optimizers
from splatu.rasterizer import RasterOutput
from splatu.rasterizer.projection import unit_quaternions

SPLIT_SCALE_DIVISOR = 1.6
"""Split children are this much smaller than their parent (3DGS: 0.8·N with N = 2)."""
NEVER_CONTRIBUTING_WEIGHT = 1.0 / 255.0
"""A Gaussian whose blend weight never reached this over a window never changed a pixel's 8-bit value."""


@dataclass
class DensifyConfig:
    warmup_length: int = 500
    """Steps before the first refinement."""
    refine_every: int = 100
    """Steps between refinements (the statistics window)."""
    densify_grad_thresh: float = 0.0008
    """Densify Gaussians whose mean 2D-mean absgrad (NDC units) over the window exceeds this."""
    densify_size_thresh: float = 0.01
    """Split (rather than clone) when the largest world scale exceeds this fraction of the scene extent."""
    n_split_samples: int = 2
    """Number of children a split Gaussian is replaced by."""
    cull_alpha_thresh: float = 0.1
    """Cull Gaussians whose opacity is below this."""
    cull_scale_thresh: float = 0.5
    """Cull Gaussians whose largest world scale exceeds this fraction of the scene extent (after the first
    opacity reset, as splatfacto); one that is split instead stays when its children are below it."""
    reset_alpha_every: int = 30
    """Reset opacities every this many refinements."""
    stop_split_at: int = 15000
    """No clone, split or opacity reset from this step on (culling continues)."""
    cull_screen_size: float = 0.15
    """Cull Gaussians whose screen radius exceeded this fraction of the image size (after the first opacity
    reset and before stop_screen_size_at, as splatfacto), unless split instead: a child's screen size is measured
    anew."""
    split_screen_size: float = 0.05
    """Split high-gradient Gaussians whose screen radius exceeded this fraction (before stop_screen_size_at)."""
    stop_screen_size_at: int = 4000
    """Screen-size split and cull rules apply only before this step."""
    max_gaussians: int = 200_000
    """Gaussian budget: densification never grows the model beyond it, keeping the largest gradients first."""
    prune_never_contributing: bool = True
    """Prune Gaussians whose blend weight stayed below 1/255 in every view of the last contribution_window steps."""
    contribution_window: int = 300
    """Steps a Gaussian may go without contributing before it is pruned; never fewer than 2N − 1 for N training
    views, the longest the per-epoch shuffle can leave a view undrawn, so that a Gaussian seen by few views is
    not pruned just because they were not drawn (0: that floor alone)."""
    pause_after_reset: int = 0
    """Steps without densification or culling after each opacity reset, for opacities to recover (splatfacto
    waits for the number of training images; the presets, at 2,000 and 3,000 steps, do not wait)."""

    def validate(self) -> None:
        """Raise a one-line SplatuError for a schedule or budget below 1, a negative or non-finite step or
        threshold (a NaN threshold would silently turn its rule off: every comparison with it is false), or a
        cull opacity outside (0, 1), which the opacity reset takes the logit of."""
        for name in ("refine_every", "reset_alpha_every", "n_split_samples", "max_gaussians"):
            require_at_least(getattr(self, name), 1, _flag(name))
        for name in ("warmup_length", "stop_split_at", "stop_screen_size_at", "contribution_window",
                     "pause_after_reset", "densify_grad_thresh", "densify_size_thresh", "cull_scale_thresh",
                     "cull_screen_size", "split_screen_size"):
            require_at_least(getattr(self, name), 0, _flag(name))
        if not 0.0 < self.cull_alpha_thresh < 1.0:
            raise SplatuError(f"--densify.cull-alpha-thresh {self.cull_alpha_thresh} is not in (0, 1)",
                              "in the densify options", "use e.g. 0.1 (splatfacto)")


def _flag(name: str) -> str:
    return f"--densify.{name.replace('_', '-')}"


class DensityController:
    """Accumulates per-Gaussian screen-space statistics and refines the model on schedule."""

    def __init__(self, cfg: DensifyConfig, scene_extent: float, generator: torch.Generator | None = None) -> None:
        """`generator` draws the split children's positions (the global RNG when None)."""
        if not (math.isfinite(scene_extent) and scene_extent > 0):
            raise ValueError(f"scene_extent must be positive and finite, got {scene_extent}")
        cfg.validate()
        self.cfg = cfg
        self.scene_extent = scene_extent
        self.generator = generator
        self.grad_norm_sum: Tensor | None = None
        self.visible_count: Tensor | None = None
        self.max_screen_size: Tensor | None = None
        self.steps_without_contribution: Tensor | None = None  # persists across windows, edited with the rows
        self.views_per_epoch: int | None = None
        """The rotation the contribution counts were made in (`refine`'s views_per_epoch); None before any."""

    def observe(self, raster: RasterOutput, width: int, height: int) -> None:
        """Accumulate one view's statistics; call after backward, before `refine`."""
        n = raster.radii.shape[0]
        if self.grad_norm_sum is None:
            self._reset(n)
        assert self.grad_norm_sum is not None and self.visible_count is not None
        assert self.max_screen_size is not None
        if self.steps_without_contribution is None:
            self.steps_without_contribution = torch.zeros(n)
        if self.grad_norm_sum.shape[0] != n or self.steps_without_contribution.shape[0] != n:
            raise ValueError(f"observed {n} Gaussians, but the window started with {self.grad_norm_sum.shape[0]}")
        visible = raster.radii > 0
        # pixel-space gradient → NDC-space gradient (pixel = (ndc + 1)·size/2)
        scale = raster.means2d_absgrad.new_tensor([width / 2.0, height / 2.0])
        grad_norm = (raster.means2d_absgrad.detach() * scale).norm(dim=-1)
        if not torch.isfinite(grad_norm).all():
            raise ValueError("non-finite 2D-mean gradients: skip this step instead of observing it")
        self.grad_norm_sum += torch.where(visible, grad_norm, 0.0)
        self.visible_count += visible.to(self.visible_count.dtype)
        screen = raster.radii.to(torch.float32) / float(max(width, height))
        self.max_screen_size = torch.maximum(self.max_screen_size, torch.where(visible, screen, 0.0))
        contributed = raster.contrib_max.detach() >= NEVER_CONTRIBUTING_WEIGHT
        self.steps_without_contribution = torch.where(contributed, 0.0, self.steps_without_contribution + 1.0)

    def _reset(self, n: int) -> None:
        self.grad_norm_sum = torch.zeros(n)
        self.visible_count = torch.zeros(n)
        self.max_screen_size = torch.zeros(n)

    def refine(self, step: int, model: GaussianModel, optimizers: Optimizers, *, views_per_epoch: int
               ) -> dict[str, int]:
        """Refine after the optimizer step of `step` when the schedule says so; returns what changed.

        Acts when step > warmup_length and step % refine_every == 0, then starts a new window.
        `views_per_epoch` is the number of training views the steps cycle through.
        """
        cfg = self.cfg
        counts = {"cloned": 0, "split": 0, "pruned": 0, "reset": 0}
        self._follow_rotation(views_per_epoch)
        if step <= cfg.warmup_length or step % cfg.refine_every != 0:
            return counts
        if self.grad_norm_sum is None or self.grad_norm_sum.shape[0] != len(model):
            self._reset(len(model))
            self.steps_without_contribution = None
            return counts
        reset_interval = cfg.refine_every * cfg.reset_alpha_every
        with torch.no_grad():
            cull = self._cull_mask(model, views_per_epoch)
            too_big = self._oversized(step, model, 1.0) | self._too_big_on_screen(step)
            densifying = step < cfg.stop_split_at and step % reset_interval >= cfg.refine_every + cfg.pause_after_reset
            if densifying:
                # splatfacto culls after densifying: a parent too big in the world or on screen is split instead
                # when its gradient asks for it, into children that stay if small enough in the world (a child's
                # screen size is measured anew, over the next window)
                children_oversized = self._oversized(step, model, SPLIT_SCALE_DIVISOR)
                clone, split = self._densify_masks(step, model, cull | children_oversized, too_big)
                cull |= too_big & ~split
                append = self._new_rows(model, clone, split)
                keep = ~(cull | split)
                optimizers.replace_rows(model, keep, append)
                self._edit_rows(keep, append["means"].shape[0])
                counts["cloned"], counts["split"] = int(clone.sum()), int(split.sum())
            elif step < cfg.stop_split_at:  # the pause after an opacity reset: no edit at all, as splatfacto
                cull = torch.zeros_like(cull)
            else:
                cull |= too_big
                if cull.any():
                    optimizers.replace_rows(model, ~cull, None)
                    self._edit_rows(~cull, 0)
            counts["pruned"] = int(cull.sum())
            if step < cfg.stop_split_at and step % reset_interval == 0:
                counts["reset"] = self._reset_opacity(model, optimizers)
        self._reset(len(model))
        return counts

    def _follow_rotation(self, views_per_epoch: int) -> None:
        """Restart the contribution counts when the training views change in number (the degree choice adds its
        held-out block): camera_index's epochs restart at the new length, so a view drawn early in the old rotation
        can go undrawn for more than 2N − 1 steps across the change, and only counts from it keep that floor."""
        changed = self.views_per_epoch is not None and views_per_epoch != self.views_per_epoch
        if changed and self.steps_without_contribution is not None:
            self.steps_without_contribution = torch.zeros_like(self.steps_without_contribution)
        self.views_per_epoch = views_per_epoch

    def _edit_rows(self, keep: Tensor, appended: int) -> None:
        """Mirror a row edit on the statistics that outlive a window; new rows start fresh."""
        assert self.steps_without_contribution is not None
        self.steps_without_contribution = torch.cat([self.steps_without_contribution[keep], torch.zeros(appended)])

    def _cull_mask(self, model: GaussianModel, views_per_epoch: int) -> Tensor:
        """Rows culled whatever densification does: too faint, or no contribution to any view for a whole window.
        Rows too big (`_oversized`, `_too_big_on_screen`) are culled only if not split."""
        cfg = self.cfg
        assert self.steps_without_contribution is not None
        cull = torch.sigmoid(model.opacity_logits) < cfg.cull_alpha_thresh
        if cfg.prune_never_contributing:
            window = max(cfg.contribution_window, 2 * views_per_epoch - 1)
            cull |= self.steps_without_contribution >= window
        return cull

    def _too_big_on_screen(self, step: int) -> Tensor:
        """Rows that covered more than cull_screen_size of a view's larger side in this window: none until the first
        opacity reset, nor from stop_screen_size_at on."""
        cfg = self.cfg
        assert self.max_screen_size is not None
        culling = cfg.refine_every * cfg.reset_alpha_every < step < cfg.stop_screen_size_at
        return (self.max_screen_size > cfg.cull_screen_size) & culling

    def _oversized(self, step: int, model: GaussianModel, shrink: float) -> Tensor:
        """Rows whose largest world scale, divided by `shrink` (a split's), exceeds cull_scale_thresh × extent; none
        until the first opacity reset. Apart from `_cull_mask` because a split child is judged at its own scale."""
        cfg = self.cfg
        if step <= cfg.refine_every * cfg.reset_alpha_every:
            return torch.zeros(len(model), dtype=torch.bool, device=model.log_scales.device)
        return model.log_scales.exp().amax(-1) / shrink > cfg.cull_scale_thresh * self.scene_extent

    def _densify_masks(self, step: int, model: GaussianModel, cull: Tensor, too_big: Tensor
                       ) -> tuple[Tensor, Tensor]:
        """Clone and split masks over the current rows, trimmed to the Gaussian budget. `too_big` rows are culled
        unless split: one that is a candidate is split (never cloned, whose copy would keep its size), and one that
        is not frees its row.

        Budget: rows kept after this refinement + new rows ≤ max_gaussians. A clone costs 1 row, a split
        n_split_samples − 1 (its parent is removed). When the candidates do not all fit, the ones with the
        largest mean gradient are taken first, in order, while they fit.
        """
        cfg = self.cfg
        assert self.grad_norm_sum is not None and self.visible_count is not None
        assert self.max_screen_size is not None
        mean_grad = self.grad_norm_sum / self.visible_count.clamp_min(1.0)
        candidate = (mean_grad > cfg.densify_grad_thresh) & ~cull
        large = model.log_scales.exp().amax(-1) > cfg.densify_size_thresh * self.scene_extent
        if step < cfg.stop_screen_size_at:
            large |= self.max_screen_size > cfg.split_screen_size
        large |= too_big  # split, even with a cull_screen_size below split_screen_size (splatfacto's: 0.15, 0.05)
        split = candidate & large
        clone = candidate & ~large
        cost = clone.long() + split.long() * (cfg.n_split_samples - 1)
        room = cfg.max_gaussians - int((~(cull | (too_big & ~candidate))).sum())
        if int(cost.sum()) > room:
            order = torch.argsort(torch.where(candidate, mean_grad, -1.0), descending=True, stable=True)
            fits = torch.cumsum(cost[order], 0) <= max(room, 0)
            chosen = torch.zeros_like(candidate)
            chosen[order[fits]] = True
            split &= chosen
            clone &= chosen
        return clone, split

    def _new_rows(self, model: GaussianModel, clone: Tensor, split: Tensor) -> dict[str, Tensor]:
        """Clones copy every parameter; split children sample means from N(mean, Σ) with scales / 1.6."""
        samples = self.cfg.n_split_samples
        rows: dict[str, Tensor] = {}
        for name in GaussianModel.PARAM_NAMES:
            param = getattr(model, name).detach()
            rows[name] = torch.cat([param[clone], param[split].repeat_interleave(samples, dim=0)], dim=0)
        n_clone = int(clone.sum())
        scales = model.log_scales.detach()[split].exp().repeat_interleave(samples, dim=0)
        quats = model.quats.detach()[split].repeat_interleave(samples, dim=0)
        offsets = _rotate(quats, torch.randn(scales.shape, generator=self.generator) * scales)
        rows["means"][n_clone:] += offsets
        rows["log_scales"][n_clone:] -= math.log(SPLIT_SCALE_DIVISOR)  # in log space: exp underflows below −103
        return rows

    def _reset_opacity(self, model: GaussianModel, optimizers: Optimizers) -> int:
        """Cap opacity at 2× the cull threshold and zero every row's Adam moments, as splatfacto does."""
        cap = min(2.0 * self.cfg.cull_alpha_thresh, 0.99)
        cap_logit = math.log(cap / (1.0 - cap))
        capped = model.opacity_logits > cap_logit
        model.opacity_logits[capped] = cap_logit
        optimizers.reset_state("opacity_logits")
        return int(capped.sum())

    def state_dict(self) -> dict[str, Any]:
        return {
            "grad_norm_sum": self.grad_norm_sum, "visible_count": self.visible_count,
            "max_screen_size": self.max_screen_size, "steps_without_contribution": self.steps_without_contribution,
            "views_per_epoch": self.views_per_epoch,
        }

    def load_state_dict(self, d: dict[str, Any]) -> None:
        self.grad_norm_sum = d["grad_norm_sum"]
        self.visible_count = d["visible_count"]
        self.max_screen_size = d["max_screen_size"]
        self.steps_without_contribution = d["steps_without_contribution"]
        self.views_per_epoch = d.get("views_per_epoch")  # absent in checkpoints written before it was kept


def _rotate(quats: Tensor, vectors: Tensor) -> Tensor:
    """Rotate `vectors` (M, 3) by quaternions (M, 4), wxyz, of any length, normalised as the rasterizer does."""
    q = unit_quaternions(quats)
    w, xyz = q[:, :1], q[:, 1:]
    t = 2.0 * torch.cross(xyz, vectors, dim=-1)
    return vectors + w * t + torch.cross(xyz, t, dim=-1)
