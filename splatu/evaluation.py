"""Held-out evaluation during and after training: PSNR, SSIM, and PSNR on observed pixels where the scene
knows them."""

from __future__ import annotations

import numpy as np
import torch

from splatu.data.scene import PerView, Scene, Views
from splatu.errors import SplatuError
from splatu.losses import psnr, ssim_map
from splatu.model import GaussianModel
from splatu.train_config import TrainConfig, eval_background
from splatu.train_progress import view_progress


@torch.no_grad()
def evaluate_views(model: GaussianModel, views: Views, sh_degree: int, background: torch.Tensor, name: str = "eval",
                   progress: bool = True) -> dict[str, float]:
    """Mean per-image PSNR and SSIM; with ground-truth `observed` masks also PSNR on observed pixels. `progress`
    shows the set `name`'s views on a terminal (`view_progress`).

    Images with alpha are scored on `background` too, so render and target share one background. Pixels
    the scene's mask files exclude are left out of PSNR and SSIM: they are 0 in both images, as in training, and
    the SSIM map is averaged over the kept pixels only (two zero regions score 1, which inflated a masked view's
    SSIM by the share it masks).
    """
    psnrs, ssims, observed = [], [], []
    with view_progress(progress) as bar:
        for i, camera in enumerate(bar.track(views.cameras, description=name)):
            rgb = model.render(camera, sh_degree, background).rgb.clamp(0, 1)
            gt = views.target(i, background)
            if views.mask_files is not None:
                if not bool((views.mask_files[i] > 0).any()):
                    continue  # a view its mask file excludes entirely has nothing to score
                rgb, gt = rgb * views.mask_files[i][..., None], gt * views.mask_files[i][..., None]
            kept = None if views.mask_files is None else views.mask_files[i] > 0
            psnrs.append(psnr(rgb, gt, mask=kept))
            similarity = ssim_map(rgb, gt)
            ssims.append(float(similarity.mean() if kept is None else similarity[kept].mean()))
            if views.observed is not None:
                seen = views.observed[i] if kept is None else views.observed[i] & kept
                if bool(seen.any()):
                    observed.append(psnr(rgb, gt, mask=seen))
    if not psnrs:
        raise SplatuError("every view of an evaluated set is excluded by its mask file", "in the scene's mask files",
                          "fix the masks, or hold out other views (--eval-split)")
    metrics = {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "num_images": len(psnrs)}
    if observed:
        metrics["psnr_observed"] = float(np.mean(observed))
    return metrics


def evaluate_scene(model: GaussianModel, scene: Scene, config: TrainConfig, sh_degree: int
                   ) -> dict[str, dict[str, float]]:
    """Every held-out set: the eval split plus the scene's extra sets (e.g. interp), rendered at `sh_degree`, the
    colour SH degree the model was trained at (`training_step.trained_sh_degree`), not the schedule's cap."""
    sets = {"eval": scene.eval, **scene.extra_eval}
    return {name: evaluate_views(model, views, sh_degree, eval_background(config), name, config.progress)
            for name, views in sets.items()}


def refuse_unscorable_sets(scene: Scene) -> None:
    """A held-out set whose mask files exclude every pixel could never be scored, and training images that are
    transparent everywhere show nothing to learn (a run of them culled to a few Gaussians and scored its white
    background against white at 72 dB): refused when the scene loads, not by the final evaluation after the whole
    training (which every resume would then repeat)."""
    if scene.train.alphas is not None and not _any_positive(scene.train.alphas):
        raise SplatuError("every training image is fully transparent (alpha 0 at every pixel)", f"in {scene.source}",
                          "give images whose alpha is opaque where the scene is, or save them without alpha")
    for name, views in {"eval": scene.eval, **scene.extra_eval}.items():
        if views.mask_files is not None and not _any_positive(views.mask_files):
            raise SplatuError(f"the mask files exclude every pixel of the {name} set's views", f"in {scene.source}",
                              "fix the masks, or hold out other views (--eval-split)")


def _any_positive(per_view: PerView) -> bool:
    """Whether any view has a value above 0, view by view: views of different sizes are not one tensor."""
    return any(bool((t > 0).any()) for t in per_view)
