"""Density control and Optimizers.replace_rows: every per-Gaussian tensor and Adam state stays aligned."""

from __future__ import annotations

import math

import pytest
import torch

from splatu.densify import SPLIT_SCALE_DIVISOR, DensifyConfig, DensityController
from splatu.model import GaussianModel, ModelConfig
from splatu.optim import OptimConfig, Optimizers
from splatu.rasterizer import RasterOutput
from splatu.training_step import camera_index

N = 8
SIZE = 100  # image width = height; pixel gradients become NDC gradients × SIZE / 2
HIGH, LOW = 1e-3, 1e-6  # absgrad in pixels: 0.05 and 5e-5 in NDC, either side of 0.0008


def _tagged_model() -> tuple[GaussianModel, Optimizers]:
    """N Gaussians whose every row (and Adam row) carries its index, so moved rows can be traced."""
    cfg = ModelConfig(sh_degree=1, u_sh_degree=1)
    points = torch.arange(N, dtype=torch.float32)[:, None] * torch.tensor([1.0, 0.0, 0.0])
    model = GaussianModel.from_points(points, None, cfg, torch.Generator())
    optimizers = Optimizers(model, OptimConfig(), scene_extent=1.0, max_steps=100)
    for name in GaussianModel.PARAM_NAMES:
        getattr(model, name).grad = torch.ones_like(getattr(model, name))
    optimizers.step(0)  # creates the Adam state, overwritten with tags below
    tag = torch.arange(N, dtype=torch.float32)
    for name in GaussianModel.PARAM_NAMES:
        state = optimizers.optimizers[name].state[getattr(model, name)]
        shape = (N,) + (1,) * (state["exp_avg"].dim() - 1)
        state["exp_avg"].copy_((tag + 1).reshape(shape).expand_as(state["exp_avg"]))
        state["exp_avg_sq"].copy_((2 * tag + 1).reshape(shape).expand_as(state["exp_avg_sq"]))
    with torch.no_grad():
        model.means.copy_(points)
        model.log_scales.fill_(math.log(0.005))
        model.opacity_logits.fill_(2.0)  # opacity 0.88
        model.sh_dc[:, 0, 0] = tag
        model.sh_rest[:, :, 1] = tag[:, None]
        model.u_sh[:, :, 0] = 10.0 + tag[:, None]
    return model, optimizers


def _raster(absgrad_x: torch.Tensor, radii: torch.Tensor, contrib_max: torch.Tensor) -> RasterOutput:
    n = absgrad_x.shape[0]
    zeros = torch.zeros(n)
    return RasterOutput(
        image=torch.zeros(SIZE, SIZE, 3), alpha=torch.zeros(SIZE, SIZE), depth=torch.zeros(SIZE, SIZE),
        radii=radii.to(torch.int32), means2d=torch.zeros(n, 2), means2d_absgrad=torch.stack([absgrad_x, zeros], -1),
        contrib_sum=contrib_max.clone(), contrib_max=contrib_max, depths=torch.ones(n), num_contributing_pairs=0,
    )


def _row_of(model: GaussianModel, tag: int) -> list[int]:
    return torch.nonzero(model.sh_dc[:, 0, 0] == tag).squeeze(-1).tolist()


def _exp_avg(optimizers: Optimizers, model: GaussianModel, name: str) -> torch.Tensor:
    return optimizers.optimizers[name].state[getattr(model, name)]["exp_avg"]


def _assert_aligned(model: GaussianModel, optimizers: Optimizers) -> None:
    for name in GaussianModel.PARAM_NAMES:
        param = getattr(model, name)
        assert param.shape[0] == len(model), name
        optimizer = optimizers.optimizers[name]
        assert optimizer.param_groups[0]["params"][0] is param, name
        state = optimizer.state[param]
        assert state["exp_avg"].shape == param.shape and state["exp_avg_sq"].shape == param.shape, name


def test_clone_split_and_prune_keep_rows_and_adam_state_aligned():
    model, optimizers = _tagged_model()
    with torch.no_grad():
        model.log_scales[1] = math.log(0.05)  # row 1: large in the world → split
        model.opacity_logits[2] = -3.0  # row 2: opacity 0.05 → culled
    grads = torch.tensor([HIGH, HIGH, LOW, LOW, LOW, HIGH, LOW, LOW])  # rows 0, 1, 5 densify
    radii = torch.tensor([2, 2, 2, 2, 2, 10, 2, 2])  # row 5: 10% of the screen → split
    contrib = torch.tensor([0.5, 0.5, 0.5, 0.0, 0.5, 0.5, 0.5, 0.5])  # row 3 never contributes → pruned
    cfg = DensifyConfig(warmup_length=0, refine_every=10, contribution_window=1)
    controller = DensityController(cfg, 1.0, torch.Generator())
    controller.observe(_raster(grads, radii, contrib), SIZE, SIZE)
    u_before = model.u_sh.detach().clone()

    counts = controller.refine(10, model, optimizers, views_per_epoch=1)

    assert counts == {"cloned": 1, "split": 2, "pruned": 2, "reset": 0}
    assert len(model) == N - 2 - 2 + 1 + 2 * 2
    _assert_aligned(model, optimizers)
    assert _row_of(model, 2) == [] and _row_of(model, 3) == []
    # survivors keep their parameters and their Adam rows
    for tag in (4, 6, 7):
        (row,) = _row_of(model, tag)
        assert torch.equal(model.u_sh[row], u_before[tag])
        for name in GaussianModel.PARAM_NAMES:
            assert torch.all(_exp_avg(optimizers, model, name)[row] == tag + 1), name
    # row 0 survives with its state; its clone copies every parameter, u_sh included, with fresh Adam state
    original, clone = _row_of(model, 0)
    for name in GaussianModel.PARAM_NAMES:
        assert torch.equal(getattr(model, name)[clone], getattr(model, name)[original]), name
        assert torch.all(_exp_avg(optimizers, model, name)[original] == 1)
        assert not _exp_avg(optimizers, model, name)[clone].any()
    # split parents are replaced by two children that inherit u_sh and shrink by 1.6
    for parent in (1, 5):
        children = _row_of(model, parent)
        assert len(children) == 2
        for child in children:
            assert torch.equal(model.u_sh[child], u_before[parent])
            parent_scale = 0.05 if parent == 1 else 0.005
            child_scale = float(model.log_scales.detach()[child, 0].exp())
            assert child_scale == pytest.approx(parent_scale / SPLIT_SCALE_DIVISOR, rel=1e-5)
            assert not _exp_avg(optimizers, model, "u_sh")[child].any()
        assert not torch.equal(model.means[children[0]], model.means[children[1]])
    # training continues on the edited rows
    for name in GaussianModel.PARAM_NAMES:
        getattr(model, name).grad = torch.ones_like(getattr(model, name))
    optimizers.step(11)
    _assert_aligned(model, optimizers)


def test_opacity_reset_caps_opacity_zeroes_all_its_adam_rows_and_leaves_u_sh_alone():
    model, optimizers = _tagged_model()
    with torch.no_grad():
        model.opacity_logits[3] = math.log(0.15 / 0.85)  # below the 0.2 cap: untouched
    u_before = model.u_sh.detach().clone()
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2)
    controller = DensityController(cfg, 1.0)
    controller.observe(_raster(torch.full((N,), LOW), torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(20, model, optimizers, views_per_epoch=1)  # 20 = 2 refinements × 10 steps → reset

    assert counts == {"cloned": 0, "split": 0, "pruned": 0, "reset": N - 1}
    opacity = torch.sigmoid(model.opacity_logits.detach())
    assert torch.allclose(opacity[torch.arange(N) != 3], torch.full((N - 1,), 0.2))
    assert float(opacity[3]) == pytest.approx(0.15)
    assert torch.equal(model.u_sh, u_before)
    opacity_state = optimizers.optimizers["opacity_logits"].state[model.opacity_logits]
    assert not opacity_state["exp_avg"].any() and not opacity_state["exp_avg_sq"].any()  # all rows, as splatfacto
    assert torch.equal(_exp_avg(optimizers, model, "u_sh")[:, 0, 0], torch.arange(N, dtype=torch.float32) + 1)


def test_nothing_is_culled_during_the_pause_after_an_opacity_reset_but_culling_goes_on_after_stop_split_at():
    """splatfacto neither densifies nor culls from an opacity reset until every view has been seen again (its
    pause), so Gaussians whose opacity the reset lowered are not culled before they can recover."""
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=3, pause_after_reset=10,
                        stop_split_at=100)
    pruned = {}
    for step in (30, 40, 50, 100):  # reset at 30; 40 is in the pause (30 + 10 + 10 > 40); 50 densifies; 100 culls
        model, optimizers = _tagged_model()
        with torch.no_grad():
            model.opacity_logits[2] = -3.0  # opacity 0.05: below the cull threshold
        controller = DensityController(cfg, 1.0)
        controller.observe(_raster(torch.full((N,), LOW), torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)
        pruned[step] = controller.refine(step, model, optimizers, views_per_epoch=1)["pruned"]
    assert pruned == {30: 0, 40: 0, 50: 1, 100: 1}


def test_budget_densifies_only_the_largest_gradients_that_fit():
    model, optimizers = _tagged_model()
    grads = torch.tensor([2 * HIGH, 5 * HIGH, LOW, 3 * HIGH, LOW, HIGH, LOW, LOW])  # four clone candidates
    cfg = DensifyConfig(warmup_length=0, refine_every=10, max_gaussians=N + 2, prune_never_contributing=False)
    controller = DensityController(cfg, 1.0)
    controller.observe(_raster(grads, torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(10, model, optimizers, views_per_epoch=1)

    assert counts["cloned"] == 2 and len(model) == N + 2
    assert len(_row_of(model, 1)) == 2 and len(_row_of(model, 3)) == 2  # the two largest gradients
    assert len(_row_of(model, 0)) == 1 and len(_row_of(model, 5)) == 1
    _assert_aligned(model, optimizers)


def test_gradient_is_averaged_over_the_views_where_a_gaussian_is_visible():
    model, optimizers = _tagged_model()
    controller = DensityController(DensifyConfig(warmup_length=0, refine_every=10), 1.0)
    visible_once = torch.tensor([2, 0, 2, 2, 2, 2, 2, 2])
    # row 0: high gradient in one view of four (mean 1/4 of HIGH·50 = 0.0125 > thresh, so still cloned);
    # row 1: high gradient only where it is not visible (ignored)
    controller.observe(_raster(torch.tensor([HIGH, HIGH, 0, 0, 0, 0, 0, 0]), visible_once, torch.full((N,), 0.5)),
                       SIZE, SIZE)
    for _ in range(3):
        controller.observe(_raster(torch.zeros(N), torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)
    counts = controller.refine(10, model, optimizers, views_per_epoch=1)
    assert counts["cloned"] == 1 and len(_row_of(model, 0)) == 2 and len(_row_of(model, 1)) == 1


def test_never_contributing_gaussians_are_pruned_after_a_full_contribution_window():
    model, optimizers = _tagged_model()
    cfg = DensifyConfig(warmup_length=0, refine_every=2, contribution_window=3)
    controller = DensityController(cfg, 1.0)
    silent = torch.zeros(N)
    row1_only = torch.zeros(N)
    row1_only[1] = 0.5
    everyone = torch.full((N,), 0.5)
    quiet = torch.full((N,), LOW)
    # rows ≠ 1 are silent at steps 2, 3, 4: a silence spanning two refine windows reaches 3 at step 4
    schedule = [everyone, silent, silent, row1_only, silent, silent]
    pruned = []
    for step, contrib in enumerate(schedule, start=1):
        n = len(model)  # only the silent steps come after the prune, so the first n entries are right
        controller.observe(_raster(quiet[:n], torch.full((n,), 2), contrib[:n]), SIZE, SIZE)
        pruned.append(controller.refine(step, model, optimizers, views_per_epoch=1)["pruned"])
    assert pruned == [0, 0, 0, N - 1, 0, 0]  # row 1 spoke at step 4, so 2 silent steps by step 6 are not enough
    assert len(model) == 1 and _row_of(model, 1) == [0]
    _assert_aligned(model, optimizers)
    assert controller.steps_without_contribution is not None and controller.steps_without_contribution.shape == (1,)


def test_nothing_happens_during_warmup_or_between_refinements():
    model, optimizers = _tagged_model()
    controller = DensityController(DensifyConfig(warmup_length=500, refine_every=100), 1.0)
    raster = _raster(torch.full((N,), HIGH), torch.full((N,), 2), torch.zeros(N))
    for step in (100, 500, 650):
        controller.observe(raster, SIZE, SIZE)
        counts = controller.refine(step, model, optimizers, views_per_epoch=1)
        assert counts == {"cloned": 0, "split": 0, "pruned": 0, "reset": 0}
    assert len(model) == N


def test_optimizer_state_round_trips_after_rows_change():
    model, optimizers = _tagged_model()
    keep = torch.tensor([True, False] * (N // 2))
    append = {name: getattr(model, name).detach()[:1].clone() for name in GaussianModel.PARAM_NAMES}
    optimizers.replace_rows(model, keep, append)
    _assert_aligned(model, optimizers)
    restored = GaussianModel.empty_like_config(len(model), model.cfg)
    restored.load_state_dict(model.state_dict())
    restored_optimizers = Optimizers(restored, OptimConfig(), scene_extent=1.0, max_steps=100)
    restored_optimizers.load_state_dict(optimizers.state_dict())
    for name in GaussianModel.PARAM_NAMES:
        assert torch.equal(_exp_avg(restored_optimizers, restored, name), _exp_avg(optimizers, model, name))
    assert torch.equal(_exp_avg(optimizers, model, "sh_dc")[:, 0, 0], torch.tensor([1.0, 3.0, 5.0, 7.0, 0.0]))


def test_means_learning_rate_decays_exponentially_and_scales_with_the_scene():
    model, _ = _tagged_model()
    optimizers = Optimizers(model, OptimConfig(), scene_extent=3.0, max_steps=1000)
    assert optimizers.means_lr(0) == pytest.approx(1.6e-4 * 3)
    assert optimizers.means_lr(500) == pytest.approx(math.sqrt(1.6e-4 * 1.6e-6) * 3)
    assert optimizers.means_lr(1000) == pytest.approx(1.6e-6 * 3)


def test_fused_adam_takes_the_same_steps_as_the_reference_adam():
    model, _ = _tagged_model()
    reference = torch.nn.Parameter(model.sh_dc.detach().clone())
    reference_adam = torch.optim.Adam([reference], lr=OptimConfig().sh_dc_lr, eps=1e-15)
    optimizers = Optimizers(model, OptimConfig(), scene_extent=1.0, max_steps=100)
    g = torch.Generator().manual_seed(0)
    for step in range(3):
        grad = torch.randn(reference.shape, generator=g)
        model.sh_dc.grad, reference.grad = grad.clone(), grad.clone()
        optimizers.step(step)
        reference_adam.step()
    assert torch.allclose(model.sh_dc, reference, atol=1e-6)
    assert not torch.equal(model.sh_dc, _tagged_model()[0].sh_dc)


def test_a_gaussian_is_not_pruned_while_its_only_view_may_still_be_undrawn():
    """Views are drawn in a new order each epoch, so one view can go 2N − 1 steps undrawn (drawn first in one epoch,
    last in the next): that is the least window whatever contribution_window says."""
    views = 5
    gaps = []
    for seed in range(3):
        last_seen: dict[int, int] = {}
        for step in range(views * 40):
            view = camera_index(step, views, seed)
            if view in last_seen:
                gaps.append(step - last_seen[view])
            last_seen[view] = step
    assert max(gaps) == 2 * views - 1  # longer than N: a window of N steps would prune on the draw order alone
    model, optimizers = _tagged_model()
    controller = DensityController(DensifyConfig(warmup_length=0, refine_every=1, contribution_window=1), 1.0)
    only_row_0 = torch.zeros(N)
    only_row_0[0] = 0.5
    pruned = []
    for step in range(1, 2 * views + 1):
        n = len(model)
        controller.observe(_raster(torch.full((n,), LOW), torch.full((n,), 2), only_row_0[:n]), SIZE, SIZE)
        pruned.append(controller.refine(step, model, optimizers, views_per_epoch=views)["pruned"])
    assert pruned == [0] * (2 * views - 2) + [N - 1, 0]  # the silent rows go after 2N − 1 = 9 steps, not 1


@pytest.mark.parametrize("length", [1.0, 1e-13])
def test_split_children_are_offset_along_the_parents_rotated_long_axis(length):
    """A needle along local x, turned 90° about z, lies along world y: its children must be sampled along y. The
    quaternion's length does not matter, as in the rasterizer: at 1e-13 its norm was clamped at 1e-12, and the
    children were sampled along x."""
    model, optimizers = _tagged_model()
    with torch.no_grad():
        model.log_scales[0] = torch.tensor([0.5, 1e-4, 1e-4]).log()
        model.quats[0] = length * torch.tensor([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    grads = torch.full((N,), LOW)
    grads[0] = HIGH
    cfg = DensifyConfig(warmup_length=0, refine_every=10, n_split_samples=8)
    controller = DensityController(cfg, 1.0, torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)

    assert controller.refine(10, model, optimizers, views_per_epoch=1)["split"] == 1

    offsets = model.means.detach()[_row_of(model, 0)]  # the parent's mean is the origin
    assert offsets.shape == (8, 3)
    assert offsets[:, 1].abs().max() > 0.1  # spread like the parent's 0.5 scale
    assert (offsets[:, [0, 2]].abs() < 1e-2 * offsets.norm(dim=-1, keepdim=True)).all()


def test_a_gradient_just_above_the_threshold_in_the_only_view_that_sees_a_gaussian_densifies_it():
    """The mean is over the views where the Gaussian is visible, not over every view of the window: row 0 (seen in 1
    view of 4) is cloned, row 1 (seen in all 4, the same gradient in one) averages to half the threshold."""
    model, optimizers = _tagged_model()
    cfg = DensifyConfig(warmup_length=0, refine_every=10)
    controller = DensityController(cfg, 1.0)
    twice_threshold = 2 * cfg.densify_grad_thresh / (SIZE / 2)  # in pixels
    grads = torch.full((N,), LOW)
    grads[:2] = twice_threshold
    controller.observe(_raster(grads, torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)
    not_row_0 = torch.tensor([0, 2, 2, 2, 2, 2, 2, 2])
    quiet = torch.full((N,), LOW)
    quiet[1] = 0.0
    for _ in range(3):
        controller.observe(_raster(quiet, not_row_0, torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(10, model, optimizers, views_per_epoch=1)

    assert counts["cloned"] == 1 and len(_row_of(model, 0)) == 2 and len(_row_of(model, 1)) == 1


def test_visible_count_counts_only_the_views_where_each_gaussian_is_visible():
    controller = DensityController(DensifyConfig(), 1.0)
    grads, contrib = torch.full((2,), LOW), torch.full((2,), 0.5)
    controller.observe(_raster(grads, torch.tensor([2, 0]), contrib), SIZE, SIZE)
    controller.observe(_raster(grads, torch.tensor([0, 2]), contrib), SIZE, SIZE)
    assert controller.visible_count is not None
    assert controller.visible_count.tolist() == [1.0, 1.0]


def test_pixel_gradients_become_ndc_gradients_by_half_the_image_width_and_height():
    """pixel = (ndc + 1)·size/2, so dL/dndc = dL/dpixel · (width/2, height/2): at 200×100, (1, 0) → 100, (0, 1) → 50."""
    controller = DensityController(DensifyConfig(), 1.0)
    raster = _raster(torch.zeros(2), torch.full((2,), 2), torch.full((2,), 0.5))
    raster.means2d_absgrad = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    controller.observe(raster, 200, 100)
    assert controller.grad_norm_sum is not None
    assert controller.grad_norm_sum.tolist() == [100.0, 50.0]


def test_size_culling_starts_after_the_first_opacity_reset_not_at_it():
    """splatfacto culls too-large Gaussians (world scale or screen size) only when step > refine_every ×
    reset_alpha_every. Past stop_split_at the reset step itself culls (no pause), so the boundary is visible there."""
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2, stop_split_at=10)
    pruned = {}
    for step in (20, 30):  # 20 = refine_every × reset_alpha_every: not yet; 30: the next refinement
        model, optimizers = _tagged_model()
        with torch.no_grad():
            model.log_scales[0] = math.log(0.8)  # above cull_scale_thresh × extent = 0.5
        radii = torch.full((N,), 2)
        radii[1] = 20  # 20% of the screen: above cull_screen_size = 0.15
        controller = DensityController(cfg, 1.0)
        controller.observe(_raster(torch.full((N,), LOW), radii, torch.full((N,), 0.5)), SIZE, SIZE)
        pruned[step] = controller.refine(step, model, optimizers, views_per_epoch=1)["pruned"]
    assert pruned == {20: 0, 30: 2}


def test_a_gaussian_is_not_pruned_when_the_views_it_cycles_through_grow_mid_run():
    """The degree choice adds its held-out block to the rotation mid-run (here 5 views, then 8), which restarts
    camera_index's epochs at another length: a view drawn early in the old rotation can then go undrawn for more than
    2N − 1 steps in all. A Gaussian only one view sees must still not be pruned, for any draw order."""
    fit, everyone_views, switch, seen_by = 5, 8, 12, 0
    for seed in range(20):
        model, optimizers = _tagged_model()
        controller = DensityController(DensifyConfig(warmup_length=0, refine_every=1, contribution_window=1), 1.0)
        for step in range(40):
            views = fit if step < switch else everyone_views
            contrib = torch.zeros(len(model))
            contrib[_row_of(model, 0)] = 0.5 if camera_index(step, views, seed) == seen_by else 0.0
            n = len(model)
            controller.observe(_raster(torch.full((n,), LOW), torch.full((n,), 2), contrib), SIZE, SIZE)
            controller.refine(step, model, optimizers, views_per_epoch=views)
            assert _row_of(model, 0) == [0], f"seed {seed}: pruned at step {step}"


def test_a_large_gaussian_is_split_when_its_children_are_small_enough_to_keep():
    """splatfacto (and gsplat) densify first and cull what results: a high-gradient Gaussian above cull_scale_thresh
    × extent = 0.5 is replaced by children 1.6× smaller, which stay when they are below it (0.6 → 0.375) and go when
    they are not (0.9 → 0.5625); a low-gradient one is culled."""
    model, optimizers = _tagged_model()
    with torch.no_grad():
        model.log_scales[0] = math.log(0.6)
        model.log_scales[1] = math.log(0.9)
        model.log_scales[2] = math.log(0.6)
    grads = torch.full((N,), LOW)
    grads[:2] = HIGH
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2)  # size culling from step 21
    controller = DensityController(cfg, 1.0, torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, torch.full((N,), 2), torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(30, model, optimizers, views_per_epoch=1)

    assert (counts["split"], counts["pruned"]) == (1, 2)
    children = _row_of(model, 0)
    assert len(children) == 2 and _row_of(model, 1) == [] and _row_of(model, 2) == []
    assert torch.allclose(model.log_scales[children].exp(), torch.full((2, 3), 0.6 / SPLIT_SCALE_DIVISOR))
    _assert_aligned(model, optimizers)


def test_a_high_gradient_gaussian_too_big_on_screen_is_split_not_deleted():
    """splatfacto splits first and culls what results, and a split child's screen size starts at 0: a
    high-gradient Gaussian covering 20% of the screen (above cull_screen_size = 0.15) is replaced by its two
    children; a low-gradient one as big is culled, and neither child is judged by its parent's screen size."""
    model, optimizers = _tagged_model()
    grads = torch.full((N,), LOW)
    grads[0] = HIGH
    radii = torch.full((N,), 2)
    radii[:2] = 20
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2)  # size culling from step 21
    controller = DensityController(cfg, 1.0, torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, radii, torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(30, model, optimizers, views_per_epoch=1)

    assert (counts["split"], counts["pruned"]) == (1, 1)
    assert len(_row_of(model, 0)) == 2 and _row_of(model, 1) == [] and len(model) == N
    _assert_aligned(model, optimizers)


def test_a_split_child_of_a_minute_gaussian_keeps_a_finite_log_scale():
    """A child's log-scale is its parent's minus log 1.6, taken in log space: exp(−110) is 0 in float32, whose log
    would be −inf and stop the training as a non-finite update."""
    model, optimizers = _tagged_model()
    with torch.no_grad():
        model.log_scales[0] = torch.tensor([-1.0, -1.0, -110.0])
    grads = torch.full((N,), LOW)
    grads[0] = HIGH
    controller = DensityController(DensifyConfig(warmup_length=0, refine_every=10), 1.0,
                                   torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, torch.full((N,), 10), torch.full((N,), 0.5)), SIZE, SIZE)  # 10%: split

    assert controller.refine(10, model, optimizers, views_per_epoch=1)["split"] == 1
    children = model.log_scales.detach()[_row_of(model, 0)]
    assert torch.isfinite(children).all()
    assert torch.allclose(children[:, 2], torch.tensor(-110.0 - math.log(SPLIT_SCALE_DIVISOR)))


def test_a_row_culled_for_its_screen_size_frees_its_place_in_the_budget():
    """A low-gradient Gaussian too big on screen is culled in this refinement, so its row is room for a clone: at a
    budget of N, the high-gradient row 0 is cloned and the model stays at N."""
    model, optimizers = _tagged_model()
    grads = torch.full((N,), LOW)
    grads[0] = HIGH
    radii = torch.full((N,), 2)
    radii[1] = 20  # 20% of the screen, low gradient: culled
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2, max_gaussians=N)
    controller = DensityController(cfg, 1.0, torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, radii, torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(30, model, optimizers, views_per_epoch=1)

    assert (counts["cloned"], counts["pruned"]) == (1, 1) and len(model) == N
    _assert_aligned(model, optimizers)


def test_a_gaussian_too_big_on_screen_is_split_even_below_the_split_screen_size():
    """With cull_screen_size under split_screen_size, a high-gradient Gaussian small in the world but too big on
    screen would be a clone candidate, and its clone, whose screen size starts at 0, would outlive the cull: it is
    split instead."""
    model, optimizers = _tagged_model()
    grads = torch.full((N,), LOW)
    grads[0] = HIGH
    radii = torch.full((N,), 2)
    radii[0] = 4  # 4% of the screen: above cull_screen_size 0.03, below split_screen_size 0.05
    cfg = DensifyConfig(warmup_length=0, refine_every=10, reset_alpha_every=2, cull_screen_size=0.03)
    controller = DensityController(cfg, 1.0, torch.Generator().manual_seed(0))
    controller.observe(_raster(grads, radii, torch.full((N,), 0.5)), SIZE, SIZE)

    counts = controller.refine(30, model, optimizers, views_per_epoch=1)

    assert (counts["cloned"], counts["split"], counts["pruned"]) == (0, 1, 0)
    assert len(_row_of(model, 0)) == 2 and len(model) == N + 1
    _assert_aligned(model, optimizers)
