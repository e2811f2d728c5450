"""The similarity that maps the scene's normalised coordinates back to the data's own frame.

Loaders normalise poses (splatu.data.normalize) so that learning rates and densification
thresholds mean the same in every scene. An export must undo that, or splat.ply lands somewhere
other than the source cameras and points: x_world = scale · R · x_norm + translation.
A Gaussian then moves as a whole: mean transformed, log-scales shifted by log(scale), its
rotation composed with R, and every view-dependent SH (colour and uncertainty) rotated so that
it gives the same value along the rotated direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from splatu.data.scene import CameraScene, Scene
from splatu.errors import SplatuError
from splatu.model import GaussianModel
from splatu.sh import num_sh_bases, sh_basis

FLOAT32_ROUNDING = 1e-7
"""Relative error of rounding a float64 to float32 (at most 2⁻²⁴ ≈ 6e-8)."""
SAME_FRAME_TOLERANCE = 1e-6
"""Float noise between two normalisations of the same scene (`WorldTransform.matches`)."""
SAMPLE_DIRECTIONS = 64
"""Directions the SH rotation is fitted on; any ≥ 16 spread-out ones determine it exactly."""


@dataclass(frozen=True)
class WorldTransform:
    """x_world = scale · rotation @ x_norm + translation (rotation proper, scale > 0)."""

    rotation: Tensor  # (3, 3) float64
    translation: Tensor  # (3,) float64
    scale: float

    def __post_init__(self) -> None:
        finite = (self.rotation.shape == (3, 3) and self.translation.shape == (3,) and math.isfinite(self.scale)
                  and bool(self.rotation.isfinite().all()) and bool(self.translation.isfinite().all()))
        if not (finite and self.scale > 0 and abs(float(torch.linalg.det(self.rotation.double())) - 1.0) <= 1e-6):
            raise ValueError("a world transform needs a finite proper rotation (det +1), translation and positive "
                             "scale")

    @classmethod
    def from_normalization(cls, center: Tensor, scale: float) -> WorldTransform:
        """The inverse of the loaders' x_norm = (x − center) · scale."""
        return cls(torch.eye(3, dtype=torch.float64), center.detach().double().reshape(3).clone(), 1.0 / scale)

    def state_dict(self) -> dict[str, Any]:
        return {"rotation": self.rotation.double(), "translation": self.translation.double(), "scale": self.scale}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> WorldTransform:
        return cls(state["rotation"].double(), state["translation"].double(), float(state["scale"]))

    def matches(self, other: WorldTransform) -> bool:
        """Same transform up to float noise (the scene was reloaded, not changed). Runs saved before the scene's
        centre was kept in float64 recorded it rounded to float32: that rounding is noise too."""
        return (math.isclose(self.scale, other.scale, rel_tol=SAME_FRAME_TOLERANCE)
                and torch.allclose(self.rotation, other.rotation, atol=SAME_FRAME_TOLERANCE)
                and torch.allclose(self.translation, other.translation, rtol=FLOAT32_ROUNDING,
                                   atol=SAME_FRAME_TOLERANCE * (1 + self.scale)))

    def points(self, x: Tensor) -> Tensor:
        """Normalised points (N, 3) in the world frame."""
        return self.scale * x.double() @ self.rotation.double().T + self.translation.double()


def scene_frame(scene: Scene | CameraScene) -> WorldTransform:
    """The frame a model trained on `scene` lives in: the inverse of the scene's normalisation."""
    return WorldTransform.from_normalization(scene.center, scene.scale)


def normalised_world_to_camera(world_to_camera: Tensor, frame: WorldTransform) -> Tensor:
    """The same camera in the model's frame, where x_data = s·R·x + t: p_cam = Rc(s·R·x + t) + tc, divided by s
    (a camera's pixels do not change when its whole space is scaled; its depths are then in the model's units).
    Float64 (4, 4)."""
    rotation, translation = world_to_camera[:3, :3].double(), world_to_camera[:3, 3].double()
    normalised = torch.eye(4, dtype=torch.float64)
    normalised[:3, :3] = rotation @ frame.rotation.double()
    normalised[:3, 3] = (rotation @ frame.translation.double() + translation) / frame.scale
    return normalised


def require_same_frame(saved: WorldTransform | None, scene: WorldTransform, where: str, fix: str) -> None:
    """Refuse a scene (its `scene_frame`) normalised unlike the one a model was trained in: its cameras would
    not fit the model, and every render would be silently wrong. `saved` is None for checkpoints older than
    the record, which are let through."""
    if saved is not None and not saved.matches(scene):
        raise SplatuError("the scene's normalisation differs from the one this run was trained in "
                          "(cameras added, removed or moved, or another scene)", where, fix)


def rotation_to_quaternion(rotation: Tensor) -> Tensor:
    """wxyz unit quaternion of a proper rotation matrix (Shepperd's method: stable for any angle)."""
    m = rotation.double()
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = torch.stack([trace, m[0, 0], m[1, 1], m[2, 2]])
    i = int(candidates.argmax())
    if i == 0:
        r = torch.sqrt(1.0 + trace) * 2
        q = [0.25 * r, (m[2, 1] - m[1, 2]) / r, (m[0, 2] - m[2, 0]) / r, (m[1, 0] - m[0, 1]) / r]
    elif i == 1:
        r = torch.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / r, 0.25 * r, (m[0, 1] + m[1, 0]) / r, (m[0, 2] + m[2, 0]) / r]
    elif i == 2:
        r = torch.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / r, (m[0, 1] + m[1, 0]) / r, 0.25 * r, (m[1, 2] + m[2, 1]) / r]
    else:
        r = torch.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / r, (m[0, 2] + m[2, 0]) / r, (m[1, 2] + m[2, 1]) / r, 0.25 * r]
    return torch.stack(q)


def quaternion_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product a ⊗ b of wxyz quaternions (broadcasting): the rotation b, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


def _sphere_directions(n: int) -> Tensor:
    """n unit vectors spread evenly over the sphere (Fibonacci lattice), float64, deterministic."""
    k = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = torch.sqrt(1.0 - z * z)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


def sh_rotation(rotation: Tensor, degree: int) -> Tensor:
    """(K, K) matrix M with Σ_k (M c)_k Y_k(R d) = Σ_k c_k Y_k(d) for all unit d, K = (degree+1)².

    Each band l is mapped to itself by a rotation, Y_l(R d) = Y_l(d) A_lᵀ, so A_l is found exactly by
    least squares on a few sample directions; then M = A (block-diagonal), since Y(d) Aᵀ A c = Y(d) c.
    """
    dirs = _sphere_directions(SAMPLE_DIRECTIONS)
    before = sh_basis(dirs, degree)
    after = sh_basis(dirs @ rotation.double().T, degree)
    matrix = torch.zeros(num_sh_bases(degree), num_sh_bases(degree), dtype=torch.float64)
    for band in range(degree + 1):
        s = slice(band * band, (band + 1) ** 2)
        matrix[s, s] = torch.linalg.lstsq(before[:, s], after[:, s]).solution.T
    # Entries that are zero in exact arithmetic come out as ~1e-17 fit noise: drop them, so the identity
    # (and axis-aligned turns) leave every coefficient bit-for-bit where it was.
    return torch.where(matrix.abs() < 1e-12, 0.0, matrix)


def model_to_world(model: GaussianModel, transform: WorldTransform) -> GaussianModel:
    """A copy of `model` in the world frame (computed in float64, stored float32)."""
    with torch.no_grad():
        rotation = transform.rotation.double()
        coeffs = torch.cat([model.sh_dc, model.sh_rest], dim=1).double()
        coeffs = sh_rotation(rotation, model.cfg.sh_degree) @ coeffs
        u_sh = sh_rotation(rotation, model.cfg.u_sh_degree) @ model.u_sh.double()
        return GaussianModel(
            means=transform.points(model.means),
            quats=quaternion_multiply(rotation_to_quaternion(rotation), model.quats.double()),
            log_scales=model.log_scales.double() + math.log(transform.scale),
            opacity_logits=model.opacity_logits.detach().clone(),
            sh_dc=coeffs[:, :1],
            sh_rest=coeffs[:, 1:],
            u_sh=u_sh,
            cfg=model.cfg,
        )
