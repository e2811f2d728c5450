"""Adam per parameter group, and the one place that edits parameters and Adam state together.

Density control adds and removes Gaussians; if a parameter row and its Adam moments ever went out
of step, a Gaussian would be updated with another one's momentum. `replace_rows` keeps them aligned,
and `edit_parameter` does the same for the column cuts of choosing the SH degrees mid-run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from splatu.errors import SplatuError
from splatu.model import GaussianModel

ADAM_EPS = 1e-15
"""splatfacto's Adam epsilon: the gradients of far-away Gaussians are tiny, a larger eps would freeze them."""


@dataclass
class OptimConfig:
    means_lr: float = 1.6e-4
    """Initial learning rate of the means, times the scene extent."""
    means_lr_final: float = 1.6e-6
    """Final learning rate of the means (exponential decay over training), times the scene extent."""
    sh_dc_lr: float = 2.5e-3
    """Learning rate of the colour SH DC term."""
    sh_rest_lr: float = 2.5e-3 / 20
    """Learning rate of the higher colour SH coefficients."""
    opacity_lr: float = 0.05
    """Learning rate of the opacity logits."""
    scales_lr: float = 0.005
    """Learning rate of the log-scales."""
    quats_lr: float = 0.001
    """Learning rate of the quaternions."""
    u_sh_lr: float = 1e-2
    """Learning rate of the uncertainty SH (ours): 4× the colour DC rate, because each Gaussian is supervised
    only in the views that see it and short CPU schedules must still move u from its initial 0.88."""
    means_lr_steps: int = 0
    """Steps the means' learning rate decays over, then holds its final value; 0: the run's --steps. A run trained
    on with `--resume RUN --extend-to N` keeps the decay it had, as splatfacto's scheduler holds past its max_steps."""

    def validate(self) -> None:
        """Raise a one-line SplatuError for a rate that is not positive and finite (the means decay takes
        log(lr_final / lr)), or a negative decay length."""
        if self.means_lr_steps < 0:
            raise SplatuError(f"--optim.means-lr-steps must be 0 or more (got {self.means_lr_steps})",
                              "in the training options", "pass 0 to decay over the run's --steps")
        for name, value in vars(self).items():
            if name == "means_lr_steps":
                continue
            if not (math.isfinite(value) and value > 0):
                flag = f"--optim.{name.replace('_', '-')}"
                raise SplatuError(f"{flag} must be a positive learning rate (got {value})", "in the training options",
                                  f"pass a positive {flag}")


def _learning_rates(cfg: OptimConfig, scene_extent: float) -> dict[str, float]:
    return {
        "means": cfg.means_lr * scene_extent, "quats": cfg.quats_lr, "log_scales": cfg.scales_lr,
        "opacity_logits": cfg.opacity_lr, "sh_dc": cfg.sh_dc_lr, "sh_rest": cfg.sh_rest_lr, "u_sh": cfg.u_sh_lr,
    }


class Optimizers:
    """One Adam per parameter of a GaussianModel; the means' learning rate decays exponentially.

    Adam is the fused kernel: one fused loop per parameter on the CPU instead of the default implementation's
    separate elementwise ops, with the same update rule.
    """

    def __init__(self, model: GaussianModel, cfg: OptimConfig, scene_extent: float, max_steps: int) -> None:
        """`max_steps`: the run's length, which the means' rate decays over unless cfg.means_lr_steps says otherwise."""
        if not (math.isfinite(scene_extent) and scene_extent > 0):
            raise ValueError(f"scene_extent must be positive and finite, got {scene_extent}")
        cfg.validate()
        self.cfg = cfg
        self.scene_extent = scene_extent
        self.max_steps = max(1, cfg.means_lr_steps or max_steps)
        self.optimizers: dict[str, torch.optim.Adam] = {
            name: torch.optim.Adam([getattr(model, name)], lr=lr, eps=ADAM_EPS, fused=True)
            for name, lr in _learning_rates(cfg, scene_extent).items()
        }

    def means_lr(self, step: int) -> float:
        """Log-linear interpolation from means_lr to means_lr_final over max_steps (then held)."""
        t = min(max(step / self.max_steps, 0.0), 1.0)
        log_lr = (1 - t) * math.log(self.cfg.means_lr) + t * math.log(self.cfg.means_lr_final)
        return math.exp(log_lr) * self.scene_extent

    def zero_grad(self) -> None:
        for optimizer in self.optimizers.values():
            optimizer.zero_grad(set_to_none=True)

    def step(self, step: int) -> None:
        """Set the means' learning rate for `step`, then take one Adam step on every group."""
        self.optimizers["means"].param_groups[0]["lr"] = self.means_lr(step)
        for optimizer in self.optimizers.values():
            optimizer.step()

    def replace_rows(self, model: GaussianModel, keep: Tensor, append: dict[str, Tensor] | None) -> None:
        """Keep the rows where `keep` (N,) is true, then append new rows; Adam moments follow the same edit.

        `append` maps every name in PARAM_NAMES to its new rows (all with the same row count). New rows start
        with zero Adam moments, as a freshly created parameter would.
        """
        n = len(model)
        if keep.dtype != torch.bool or keep.shape != (n,):
            raise ValueError(f"keep must be a bool mask of shape ({n},), got {keep.dtype} {tuple(keep.shape)}")
        if append is not None:
            if set(append) != set(GaussianModel.PARAM_NAMES):
                raise ValueError(f"append needs exactly {GaussianModel.PARAM_NAMES}, got {sorted(append)}")
            counts = {rows.shape[0] for rows in append.values()}
            if len(counts) != 1:
                raise ValueError(f"appended rows differ in count across parameters: {counts}")
        for name in GaussianModel.PARAM_NAMES:
            extra = None if append is None else append[name].detach().to(getattr(model, name))
            zeros = None if extra is None else torch.zeros_like(extra)
            self.edit_parameter(model, name, lambda rows, extra=extra: self._edit(rows, keep, extra),
                                lambda moment, zeros=zeros: self._edit(moment, keep, zeros))

    def edit_parameter(self, model: GaussianModel, name: str, edit: Callable[[Tensor], Tensor],
                       edit_moment: Callable[[Tensor], Tensor]) -> None:
        """Replace parameter `name` by `edit(parameter)` and its Adam moments by `edit_moment(moment)`, e.g. to
        keep fewer SH coefficients, each with its own momentum. Two edits, because new values (appended rows, a
        refitted colour) need moments of their own shape but not of their value."""
        old = getattr(model, name)
        optimizer = self.optimizers[name]
        state = optimizer.state.pop(old, {})
        new = torch.nn.Parameter(edit(old.detach()).contiguous())
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key] = edit_moment(state[key]).contiguous()
        if state:
            optimizer.state[new] = state
        optimizer.param_groups[0]["params"] = [new]
        setattr(model, name, new)

    @staticmethod
    def _edit(rows: Tensor, keep: Tensor, extra: Tensor | None) -> Tensor:
        return rows[keep].contiguous() if extra is None else torch.cat([rows[keep], extra], dim=0)

    def reset_state(self, name: str) -> None:
        """Zero the Adam moments of parameter `name` (every row), so its next steps follow fresh gradients."""
        optimizer = self.optimizers[name]
        state = optimizer.state.get(optimizer.param_groups[0]["params"][0], {})
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key].zero_()

    def state_dict(self) -> dict[str, Any]:
        return {name: optimizer.state_dict() for name, optimizer in self.optimizers.items()}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        """Restore every group's Adam state; the model must already hold the checkpoint's rows."""
        missing = set(self.optimizers) - set(d)
        if missing:
            raise ValueError(f"optimizer state lacks groups {sorted(missing)}")
        for name, optimizer in self.optimizers.items():
            optimizer.load_state_dict(d[name])
