"""A float64 brute-force 3DGS rasterizer, used only by tests as the ground truth.

It is deliberately slow and literal: project every Gaussian with the EWA rules, sort the
visible ones by depth (ties by index), then walk them front to back for all pixels at once
with the 3DGS compositing rules (REFERENCE.md §2). No tiles, no bounds, no custom backward:
gradients come from plain autograd, so the fast rasterizer's analytic gradients can be
checked against it.

Every visible Gaussian is evaluated at every pixel, so a pixel gets a contribution exactly
when α ≥ 1/255 there: the result depends on no tiling or bounding rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
BLUR = 0.3
DET_MIN = 1e-10
FOV_CLAMP = 1.3


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities; `visible` is False for culled Gaussians."""

    means2d: Tensor  # (N, 2)
    depths: Tensor  # (N,) camera-space z
    conics: Tensor  # (N, 3) a, b, c of inv(cov2d)
    cov2d: Tensor  # (N, 2, 2)
    radii: Tensor  # (N,) int64, 0 when culled
    visible: Tensor  # (N,) bool
    antialiasing: Tensor  # (N,) sqrt(det(cov2d − blur·I) / det(cov2d)): Mip-Splatting's opacity factor


@dataclass
class ReferenceOutput:
    image: Tensor  # (H, W, C)
    alpha: Tensor  # (H, W)
    depth: Tensor  # (H, W)
    radii: Tensor  # (N,) int32
    means2d: Tensor  # (N, 2)
    depths: Tensor  # (N,)
    contrib_sum: Tensor  # (N,)
    contrib_max: Tensor  # (N,)
    num_contributing_pairs: int
    weights: Tensor  # (H, W, N) blending weight w = T·α of every pixel-Gaussian pair
    terminated: Tensor  # (H, W) bool: the pixel stopped early (T·(1−α) < 1e-4)
    per_pixel_means2d: list[Tensor | None] = field(default_factory=list)
    """For each Gaussian, the (H·W, 2) view of its 2D mean used at each pixel (None if culled);
    after backward their .grad gives per-pixel gradients, hence the absgrad."""

    def means2d_absgrad(self) -> Tensor:
        """Sum over pixels of |dL/dmean2d| per component, after backward (splatfacto's absgrad)."""
        rows = [
            torch.zeros(2, dtype=self.means2d.dtype) if m is None or m.grad is None else m.grad.abs().sum(0)
            for m in self.per_pixel_means2d
        ]
        return torch.stack(rows) if rows else torch.zeros(0, 2, dtype=self.means2d.dtype)


def quaternion_to_rotation(quats: Tensor) -> Tensor:
    """Rotation matrices (N, 3, 3) from unnormalised wxyz quaternions."""
    w, x, y, z = (quats / quats.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def project(means: Tensor, quats: Tensor, scales: Tensor, world_to_camera: Tensor, K: Tensor,
            width: int, height: int, near: float, far: float, blur: float = BLUR) -> Projection:
    """EWA splatting of every Gaussian, written as the textbook matrix products."""
    W = world_to_camera[:3, :3]
    t = means @ W.T + world_to_camera[:3, 3]
    x, y, z_true = t.unbind(-1)
    in_depth = (z_true > near) & (z_true < far)
    z = torch.where(in_depth, z_true, torch.ones_like(z_true))  # culled: never divide by ~0; values unused
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)

    # the visible x/z range widened by (FOV_CLAMP - 1) half fields of view each side (±FOV_CLAMP·tan(half-FoV) when
    # the principal point is centred)
    margin_x, margin_y = (FOV_CLAMP - 1) * 0.5 * width / fx, (FOV_CLAMP - 1) * 0.5 * height / fy
    xc = torch.minimum(torch.maximum(x / z, -cx / fx - margin_x), (width - cx) / fx + margin_x) * z
    yc = torch.minimum(torch.maximum(y / z, -cy / fy - margin_y), (height - cy) / fy + margin_y) * z
    zero = torch.zeros_like(z)
    J = torch.stack([
        torch.stack([fx / z, zero, -fx * xc / (z * z)], dim=-1),
        torch.stack([zero, fy / z, -fy * yc / (z * z)], dim=-1),
    ], dim=-2)  # (N, 2, 3)
    R = quaternion_to_rotation(quats)
    S = torch.diag_embed(scales)
    sigma3d = R @ S @ S.transpose(-1, -2) @ R.transpose(-1, -2)
    unblurred = J @ W @ sigma3d @ W.T @ J.transpose(-1, -2)
    cov = unblurred + blur * torch.eye(2, dtype=means.dtype)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = (a * c - b * b).clamp_min(DET_MIN)
    unblurred_det = (unblurred[:, 0, 0] * unblurred[:, 1, 1] - unblurred[:, 0, 1] * unblurred[:, 1, 0]).clamp_min(0.0)
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lambda_max = mid + torch.sqrt((mid * mid - det).clamp_min(0.0))
        radius = torch.ceil(3.0 * torch.sqrt(lambda_max))
        mx, my = means2d[:, 0], means2d[:, 1]
        on_screen = (mx + radius > 0) & (mx - radius < width) & (my + radius > 0) & (my - radius < height)
        visible = in_depth & on_screen
        radii = torch.where(visible, radius, torch.zeros_like(radius)).long()
    return Projection(means2d, z_true, conics, cov, radii, visible, torch.sqrt(unblurred_det / det))


def reference_rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    features: Tensor,
    world_to_camera: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: Tensor | None = None,
    log_scales: bool = False,
    blur: float = BLUR,
    antialiased: bool = False,
) -> ReferenceOutput:
    """Render with the exact 3DGS rules, front to back, all pixels at once per Gaussian."""
    if log_scales:
        scales = scales.exp()
    proj = project(means, quats, scales, world_to_camera, K, width, height, near, far, blur)
    if antialiased:
        opacities = opacities * proj.antialiasing
    n, channels = features.shape
    dtype = means.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij")
    px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    num_pixels = px.shape[0]

    T = torch.ones(num_pixels, dtype=dtype)
    done = torch.zeros(num_pixels, dtype=torch.bool)
    color = torch.zeros(num_pixels, channels, dtype=dtype)
    depth_sum = torch.zeros(num_pixels, dtype=dtype)
    weights = torch.zeros(num_pixels, n, dtype=dtype)
    per_pixel_means2d: list[Tensor | None] = [None] * n
    num_pairs = 0

    visible_ids = [i for i in range(n) if proj.visible[i]]
    order = sorted(visible_ids, key=lambda i: (proj.depths[i].item(), i))
    for i in order:
        if done.all():  # every pixel has stopped: later Gaussians cannot contribute
            break
        mean = proj.means2d[i].unsqueeze(0).expand(num_pixels, 2)
        if mean.requires_grad:
            mean.retain_grad()
        per_pixel_means2d[i] = mean
        a, b, c = proj.conics[i]
        dx, dy = px - mean[:, 0], py - mean[:, 1]
        power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = torch.clamp_max(opacities[i] * torch.exp(-power), ALPHA_MAX)
        active = ~done & (power >= 0) & (alpha >= ALPHA_MIN)
        stop = active & (T * (1 - alpha) < T_MIN)
        done = done | stop
        add = active & ~stop
        w = torch.where(add, T * alpha, torch.zeros_like(T))
        color = color + w[:, None] * features[i]
        depth_sum = depth_sum + w * proj.depths[i]
        weights[:, i] = w.detach()
        T = torch.where(add, T * (1 - alpha), T)
        num_pairs += int(add.sum())

    bg = torch.zeros(channels, dtype=dtype) if background is None else background.to(dtype)
    image = color + T[:, None] * bg
    alpha_map = 1 - T
    depth = depth_sum / alpha_map.clamp_min(1e-10)
    return ReferenceOutput(
        image=image.reshape(height, width, channels),
        alpha=alpha_map.reshape(height, width),
        depth=depth.reshape(height, width),
        radii=proj.radii.to(torch.int32),
        means2d=proj.means2d,
        depths=proj.depths,
        contrib_sum=weights.sum(0),
        contrib_max=weights.max(0).values if num_pixels > 0 and n > 0 else weights.new_zeros(n),
        num_contributing_pairs=num_pairs,
        weights=weights.reshape(height, width, n),
        terminated=done.reshape(height, width),
        per_pixel_means2d=per_pixel_means2d,
    )


@dataclass
class GaussianScene:
    """Inputs of one rasterizer call, so tests can render the same scene with both rasterizers."""

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    features: Tensor
    world_to_camera: Tensor
    K: Tensor
    width: int
    height: int
    near: float = 0.01
    far: float = 1e10
    background: Tensor | None = None

    PARAMS = ("means", "quats", "scales", "opacities", "features")

    def leaves(self, dtype: torch.dtype = torch.float64) -> dict[str, Tensor]:
        """Fresh leaf copies of the differentiable inputs, requiring grad."""
        return {name: getattr(self, name).detach().to(dtype).clone().requires_grad_(True) for name in self.PARAMS}

    def render(self, rasterize_fn, params: dict[str, Tensor] | None = None, dtype: torch.dtype = torch.float64,
               **options):
        """Call `rasterize_fn` (fast or reference) on this scene; `params` replaces the Gaussians."""
        p = params if params is not None else {name: getattr(self, name).to(dtype) for name in self.PARAMS}
        background = None if self.background is None else self.background.to(dtype)
        return rasterize_fn(p["means"], p["quats"], p["scales"], p["opacities"], p["features"],
                            self.world_to_camera.to(dtype), self.K.to(dtype), self.width, self.height,
                            near=self.near, far=self.far, background=background, **options)


def look_at_camera(center: Tensor, target: Tensor) -> Tensor:
    """World-to-camera (4, 4), OpenCV axes, looking from `center` at `target`."""
    forward = (target - center) / (target - center).norm()
    helper = torch.tensor([0.0, 0.0, 1.0], dtype=center.dtype)
    if torch.cross(forward, helper, dim=0).norm() < 1e-3:
        helper = torch.tensor([0.0, 1.0, 0.0], dtype=center.dtype)
    right = torch.cross(helper, forward, dim=0)
    right = right / right.norm()
    down = torch.cross(forward, right, dim=0)
    R = torch.stack([right, down, forward])
    w2c = torch.eye(4, dtype=center.dtype)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ center
    return w2c


def random_scene(seed: int, n: int, width: int, height: int, *, anisotropy: float = 10.0, channels: int = 3,
                 fov_spill: float = 1.6, opacity_range: tuple[float, float] = (0.02, 0.98)) -> GaussianScene:
    """Random Gaussians in front of a random camera, float64.

    Centres are drawn in camera space with |x/z| up to `fov_spill` × the half field of view,
    so some sit beyond the 1.3× Jacobian clamp and some off-screen; footprints span about
    0.3 to 6 px at these image sizes; per-axis scales differ by up to `anisotropy`.
    Opacities are uniform in `opacity_range` (near 1, pixels reach the T < 1e-4 stop).
    """
    g = torch.Generator().manual_seed(seed)
    d = torch.float64

    def uniform(lo: float, hi: float, *shape: int) -> Tensor:
        return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=d)

    fx = float(uniform(0.8, 1.5)) * max(width, height)
    fy = fx * float(uniform(0.85, 1.15))
    cx = width / 2 + float(uniform(-0.1, 0.1)) * width
    cy = height / 2 + float(uniform(-0.1, 0.1)) * height
    K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=d)
    center = torch.randn(3, generator=g, dtype=d)
    center = 4.0 * center / center.norm()
    w2c = look_at_camera(center, torch.randn(3, generator=g, dtype=d) * 0.3)

    z = uniform(1.5, 6.0, n)
    x = uniform(-1, 1, n) * fov_spill * 0.5 * width / fx * z
    y = uniform(-1, 1, n) * fov_spill * 0.5 * height / fy * z
    cam_points = torch.stack([x, y, z], dim=-1)
    means = (cam_points - w2c[:3, 3]) @ w2c[:3, :3]  # Rᵀ (t − tvec) per row
    base = torch.exp(uniform(math.log(0.1), math.log(1.2), n, 1)) * (3.0 / fx) * z[:, None]
    axis = torch.exp(uniform(-0.5, 0.5, n, 3) * math.log(anisotropy))
    return GaussianScene(
        means=means,
        quats=torch.randn(n, 4, generator=g, dtype=d),
        scales=base * axis,
        opacities=uniform(*opacity_range, n),
        features=torch.randn(n, channels, generator=g, dtype=d),
        world_to_camera=w2c,
        K=K,
        width=width,
        height=height,
        background=torch.rand(channels, generator=g, dtype=d),
    )
