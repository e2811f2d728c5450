"""Choosing the colour and u-SH degrees per scene on a held-out block (`--degree-choice.on`)."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from splatu import interrupts, run_records, train_command, trainer, training_step
from splatu.checkpoint import load_run
from splatu.data.scene import Views
from splatu.degree_choice import (
    FIT_RIDGE,
    DegreeChoiceConfig,
    DegreeScores,
    apply_choice,
    decision_step,
    held_out_block,
    normal_equations,
    refit_colour,
    score_degrees,
    seen_normal_equations,
    smallest_within,
    training_views,
    with_choice_heads,
)
from splatu.errors import SplatuError
from splatu.losses import UncertaintyLossConfig, uncertainty_heads
from splatu.model import GaussianModel, ModelConfig
from splatu.optim import OptimConfig, Optimizers
from splatu.sh import C0, safe_normalize, sh_basis
from tests.unit.test_trainer import (
    ctrl_c_on_the_first_call,
    logged_events,
    losses_of,
    serve_scene,
    tiny_config,
    tiny_scene,
)


def choice_config(tmp_path, **changes):
    """A tiny run that chooses among colour degrees 0-2 and u-SH degrees 0-2 after step 9 of 16."""
    config = tiny_config(tmp_path, steps=16, checkpoint_every=0,
                         model=ModelConfig(sh_degree=2, u_sh_degree=2, sh_degree_interval=3),
                         degree_choice=DegreeChoiceConfig(on=True, held_out=0.25, at=0.55))
    return dataclasses.replace(config, **changes)


@pytest.fixture
def scene(monkeypatch):
    scene = tiny_scene(n_train=8)
    serve_scene(monkeypatch, lambda data_config: scene)
    return scene


def test_the_held_out_block_is_contiguous_in_the_middle_and_leaves_views_to_train_on():
    assert held_out_block(16, 0.125) == [7, 8]
    assert held_out_block(10, 0.05) == [4, 5]  # never fewer than two views
    assert held_out_block(67, 0.25) == list(range(25, 42))
    with pytest.raises(SplatuError, match="holds out 2 of only 2 training views"):
        held_out_block(2, 0.125)


def test_the_smallest_degree_within_tolerance_of_the_best_is_kept():
    psnr = {0: 20.0, 1: 21.0, 2: 21.05, 3: 20.9}
    assert smallest_within(psnr, 0.1, higher_is_better=True) == 1
    assert smallest_within(psnr, 0.0, higher_is_better=True) == 2
    ause = {0: 0.50, 1: 0.40, 2: 0.39, 3: 0.395}
    assert smallest_within(ause, 0.02, higher_is_better=False) == 2  # 0.40 is 2.6% above the best
    assert smallest_within(ause, 0.03, higher_is_better=False) == 1


def test_choice_settings_are_validated_before_the_scene_loads(tmp_path, monkeypatch):
    def no_scene(data_config):
        raise AssertionError("the scene was loaded before the settings were checked")

    serve_scene(monkeypatch, no_scene)
    for changes, message in (({"ensemble": 2}, "members must differ only in seed"),
                             ({"steps": 8}, "before colour SH reaches degree 2")):
        with pytest.raises(SplatuError, match=message):
            train_command.train(choice_config(tmp_path, **changes))


def test_bad_choice_settings_are_one_line_errors(tmp_path):
    with pytest.raises(SplatuError, match="must both be in"):
        DegreeChoiceConfig(at=1.0)
    with pytest.raises(SplatuError, match="tolerances"):
        DegreeChoiceConfig(psnr_tolerance=float("nan"))
    late = choice_config(tmp_path, model=ModelConfig(sh_degree=2, sh_degree_interval=5))
    with pytest.raises(SplatuError, match="before colour SH reaches degree 2"):
        with_choice_heads(late)
    own = choice_config(tmp_path)
    own = dataclasses.replace(own, uncertainty=dataclasses.replace(own.uncertainty, extra_heads=("lam=0.1",)))
    with pytest.raises(SplatuError, match="trains its own uncertainty heads"):
        with_choice_heads(own)


def test_one_head_per_lower_u_degree_is_added_once(tmp_path):
    config = with_choice_heads(choice_config(tmp_path))
    assert [h.degree for h in uncertainty_heads(config.uncertainty, config.model.u_sh_degree)] == [2, 0, 1]
    assert with_choice_heads(config) == config
    off = choice_config(tmp_path, uncertainty=dataclasses.replace(config.uncertainty, off=True, extra_heads=()))
    assert with_choice_heads(off).uncertainty.extra_heads == ()


def test_the_held_out_views_are_withheld_until_the_decision_step(tmp_path):
    views = tiny_scene(n_train=8).train
    config = choice_config(tmp_path)
    at = decision_step(config.degree_choice, config.steps)
    assert at == 9
    assert training_views(views, config, at - 1).names == ["t0", "t1", "t2", "t5", "t6", "t7"]
    assert training_views(views, config, at) is views
    off = dataclasses.replace(config, degree_choice=DegreeChoiceConfig())
    assert training_views(views, off, 0) is views


def _model_with_heads(config, seed: int = 0) -> GaussianModel:
    scene = tiny_scene()
    heads = uncertainty_heads(config.uncertainty, config.model.u_sh_degree)
    model = GaussianModel.from_points(scene.points, scene.point_colors, config.model,
                                      torch.Generator().manual_seed(seed), len(heads))
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        model.sh_rest.copy_(0.3 * torch.randn(model.sh_rest.shape, generator=g))
        model.u_sh.copy_(torch.randn(model.u_sh.shape, generator=g))
    return model


@pytest.mark.parametrize(("sh_degree", "u_degree", "channel"), [(1, 1, 2), (0, 2, 0), (2, 0, 1)])
def test_applying_a_choice_cuts_coefficients_heads_and_adam_moments_alike(tmp_path, sh_degree, u_degree, channel):
    """Channels: the run's own head (degree 2), then degree=0 and degree=1; degree 0 leaves no sh_rest."""
    config = with_choice_heads(choice_config(tmp_path, uncertainty=dataclasses.replace(
        choice_config(tmp_path).uncertainty, kind="mean")))
    model = _model_with_heads(config)
    optimizers = Optimizers(model, OptimConfig(), 1.0, 10)
    (model.sh_dc.pow(3).sum() + model.sh_rest.square().sum() + model.u_sh.pow(3).sum()).backward()
    optimizers.step(0)
    u_before = model.u_sh.detach().clone()
    moments = {name: {k: v.clone() for k, v in optimizers.optimizers[name].state[getattr(model, name)].items()}
               for name in ("sh_dc", "sh_rest", "u_sh")}
    generators = [torch.Generator().manual_seed(k) for k in range(3)]
    k, ku = (sh_degree + 1) ** 2, (u_degree + 1) ** 2

    refitted = torch.randn(len(model), k, 3)
    chosen, kept = apply_choice(model, optimizers, generators, config,
                                DegreeScores({"sh_degree": sh_degree, "u_sh_degree": u_degree}, refitted))

    assert (chosen.model.sh_degree, chosen.model.u_sh_degree) == (sh_degree, u_degree) and model.cfg == chosen.model
    assert chosen.uncertainty.extra_heads == () and chosen.uncertainty.kind == "mean"
    assert not chosen.degree_choice.on  # made: resuming or reusing this config never chooses again
    assert kept == [generators[channel]]
    assert torch.equal(model.sh_dc, refitted[:, :1]) and torch.equal(model.sh_rest, refitted[:, 1:])
    assert torch.equal(model.u_sh, u_before[:, :ku, channel:channel + 1])
    cuts = {"sh_dc": lambda t: t, "sh_rest": lambda t: t[:, :k - 1], "u_sh": lambda t: t[:, :ku, channel:channel + 1]}
    for name, cut in cuts.items():
        state = optimizers.optimizers[name].state[getattr(model, name)]
        for key in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(state[key], cut(moments[name][key])), (name, key)
    (model.sh_dc.sum() + model.sh_rest.sum() + model.u_sh.sum()).backward()
    optimizers.step(1)  # the optimizers now hold the cut parameters


def test_a_subset_of_views_slices_every_per_image_tensor_alike():
    views = tiny_scene(n_train=5).train
    n, h, w = len(views), views.images.shape[1], views.images.shape[2]
    views = dataclasses.replace(views, object_masks=torch.rand(n, h, w), depths=torch.rand(n, h, w),
                                observed=torch.rand(n, h, w) > 0.5, alphas=torch.rand(n, h, w),
                                mask_files=torch.rand(n, h, w))
    part = views.subset([3, 1])
    assert part.names == ["t3", "t1"] and part.cameras == [views.cameras[3], views.cameras[1]]
    for name in ("images", "object_masks", "depths", "observed", "alphas", "mask_files"):
        assert torch.equal(getattr(part, name), getattr(views, name)[[3, 1]]), name


def _views_rendered_by(model: GaussianModel, views: Views, degree: int) -> Views:
    """`views` with images rendered by `model`, and masks that keep only pixels the Gaussians cover (empty
    background has no error for any map to find)."""
    with torch.no_grad():
        renders = [model.render(c, degree, torch.zeros(3)) for c in views.cameras]
    return dataclasses.replace(views, images=torch.stack([r.rgb.clamp(0, 1) for r in renders]),
                               object_masks=torch.stack([(r.alpha > 0.5).float() for r in renders]))


def test_refitting_recovers_a_lower_degree_colour_exactly_and_is_weighted_least_squares():
    g = torch.Generator().manual_seed(3)
    n, views = 5, 9
    dirs = safe_normalize(torch.randn(n, views, 3, generator=g, dtype=torch.float64))
    weights = torch.rand(n, views, generator=g, dtype=torch.float64)
    weights = weights / weights.sum(1, keepdim=True)
    coeffs = torch.randn(n, 16, 3, generator=g, dtype=torch.float64)
    low = coeffs.clone()
    low[:, 4:] = 0.0  # a degree-1 colour stored at degree 3
    fitted_low = refit_colour(*normal_equations(dirs, weights, low), low, 1)
    torch.testing.assert_close(fitted_low, low[:, :4], rtol=0, atol=1e-12)
    fitted = refit_colour(*normal_equations(dirs, weights, coeffs), coeffs, 1)
    for i in range(n):  # brute force: the same weighted, ridged least squares, stacked as one system
        root = weights[i].sqrt().unsqueeze(-1)
        a = torch.cat([root * sh_basis(dirs[i], 3)[:, :4], FIT_RIDGE**0.5 * torch.eye(4, dtype=torch.float64)])
        b = torch.cat([root * (sh_basis(dirs[i], 3) @ coeffs[i]), FIT_RIDGE**0.5 * coeffs[i, :4]])
        torch.testing.assert_close(fitted[i], torch.linalg.lstsq(a, b).solution, rtol=1e-9, atol=1e-9)
    unseen = refit_colour(*normal_equations(dirs, torch.zeros(n, views, dtype=torch.float64), coeffs), coeffs, 1)
    torch.testing.assert_close(unseen, coeffs[:, :4], rtol=0, atol=1e-12)  # nothing seen: the cut colour


def test_normal_equations_summed_view_by_view_weigh_views_by_what_they_see(tmp_path):
    """The trainer's one-view-at-a-time sum equals the batched normal equations over all views, with each
    Gaussian's weights its summed blend weight per view, normalised over views."""
    config = with_choice_heads(choice_config(tmp_path))
    model = _model_with_heads(config)
    views = tiny_scene(n_train=8).train.subset([0, 2, 5])
    with torch.no_grad():
        model.opacity_logits[:10] = -20.0  # below α = 1/255 everywhere: no view sees these
    normal, rhs = seen_normal_equations(model, views, torch.zeros(3))
    with torch.no_grad():
        weights = torch.stack([model.render(c, 0, torch.zeros(3)).raster.contrib_sum for c in views.cameras], 1)
        dirs = torch.stack([safe_normalize(model.view_dirs(c)) for c in views.cameras], 1)
        coeffs = torch.cat([model.sh_dc, model.sh_rest], 1)
        seen = weights.sum(1) > 0
        expected = normal_equations(dirs.double(), (weights / weights.sum(1, keepdim=True).clamp_min(1e-12)).double(),
                                    coeffs.double())
    torch.testing.assert_close(normal, expected[0], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(rhs, expected[1], rtol=1e-5, atol=1e-6)
    assert int(seen.sum()) == len(model) - 10
    assert torch.equal(normal[~seen], torch.zeros_like(normal[~seen]))
    # a view whose mask file keeps no pixel was never trained on: it weighs nothing
    height, width = views.images.shape[1:3]
    valid = torch.ones(len(views), height, width)
    valid[1] = 0.0
    masked, _ = seen_normal_equations(model, dataclasses.replace(views, mask_files=valid), torch.zeros(3))
    without, _ = seen_normal_equations(model, views.subset([0, 2]), torch.zeros(3))
    torch.testing.assert_close(masked, without, rtol=1e-6, atol=1e-9)


def test_scores_pick_the_degree_that_explains_held_out_views(tmp_path):
    """A colour of degree 1 (stored at degree 2) makes degrees 1 and 2 equal on held-out views and degree 0
    worse, so degree 1 is kept. The error sits on the Gaussians whose colour was shifted in the targets, and
    only the degree-1 uncertainty head is told which those are."""
    config = with_choice_heads(choice_config(tmp_path))
    model = _model_with_heads(config)
    train = tiny_scene(n_train=8).train
    shifted = torch.zeros(len(model), dtype=torch.bool)
    shifted[::2] = True
    with torch.no_grad():
        model.sh_rest[:, 3:] = 0.0
        model.sh_dc[shifted] += 0.4
        targets = _views_rendered_by(model, train.subset([0, 3, 6]), 2)
        model.sh_dc[shifted] -= 0.4
        model.u_sh.zero_()
        model.u_sh[:, 0, 2] = torch.where(shifted, 2.0, -2.0) / C0  # channel 2 is the degree-1 head
    scores = score_degrees(model, targets, train.subset([1, 2, 4, 5, 7]), config, torch.zeros(3))
    record = scores.record
    assert record["held_out_views"] == ["t0", "t3", "t6"]
    assert abs(record["colour_psnr"][1] - record["colour_psnr"][2]) < 1e-3
    assert record["colour_psnr"][0] < record["colour_psnr"][1] - 0.5
    assert record["sh_degree"] == 1
    torch.testing.assert_close(scores.colour, torch.cat([model.sh_dc, model.sh_rest[:, :3]], 1), rtol=0, atol=1e-4)
    assert list(record["u_ause_mae"]) == [0, 1, 2]
    assert record["u_ause_mae"][1] < 0.75 * min(record["u_ause_mae"][0], record["u_ause_mae"][2])
    assert record["u_sh_degree"] == 1


def test_a_run_chooses_mid_way_records_why_and_loads_with_the_chosen_degrees(tmp_path, scene, monkeypatch):
    seen: list[tuple[int, str]] = []
    real_get = training_step.TrainImages.get

    def record(self, index, level, background=None):
        camera, target = real_get(self, index, level, background)
        seen.append((len(seen), self.views.names[index]))
        return camera, target

    monkeypatch.setattr(training_step.TrainImages, "get", record)
    run_dir = train_command.train(choice_config(tmp_path))
    record_file = json.loads((run_dir / trainer.DEGREE_CHOICE_FILE).read_text())
    assert record_file["step"] == 9 and record_file["held_out_views"] == ["t3", "t4"]
    assert set(record_file["colour_psnr"]) == {"0", "1", "2"} and set(record_file["u_ause_mae"]) == {"0", "1", "2"}
    held = {"t3", "t4"}
    assert not held & {name for step, name in seen if step < 9}
    assert held <= {name for step, name in seen if step >= 9}
    config, model, _ = load_run(run_dir)
    assert config.model.sh_degree == record_file["sh_degree"]
    assert config.model.u_sh_degree == record_file["u_sh_degree"]
    assert model.u_sh.shape[1:] == ((record_file["u_sh_degree"] + 1) ** 2, 1)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["degree_choice"] == record_file
    assert summary["sh_degree"] == record_file["sh_degree"]


def mean_loss_choice(root, **changes):
    """`choice_config` with the `mean` loss, whose heads draw from their own random streams."""
    config = choice_config(root, **changes)
    return dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, kind="mean"))


def assert_same_run(run_dir, reference_dir) -> None:
    assert losses_of(run_dir) == losses_of(reference_dir)
    reference, model = load_run(reference_dir).model, load_run(run_dir).model
    for name in GaussianModel.PARAM_NAMES:
        assert torch.equal(getattr(reference, name), getattr(model, name)), name
    record = json.loads((run_dir / trainer.DEGREE_CHOICE_FILE).read_text())
    assert record == json.loads((reference_dir / trainer.DEGREE_CHOICE_FILE).read_text()) | {
        "seconds": record["seconds"]}
    assert logged_events(run_dir) == logged_events(reference_dir)  # one choice record, every evaluation once


@pytest.mark.parametrize("stop_at", [5, 9, 12])
def test_resume_before_at_or_after_the_choice_equals_an_uninterrupted_run(tmp_path, scene, stop_at):
    """Stopped at step 9, the checkpoint holds the model before the choice, and the resumed run makes it."""
    full_dir = train_command.train(mean_loss_choice(tmp_path / "a"))

    def ctrl_c(step, state):
        if step == stop_at:
            raise KeyboardInterrupt

    with pytest.raises(interrupts.TrainingInterrupted):
        train_command.train(mean_loss_choice(tmp_path / "b"), hooks=[ctrl_c])
    interrupted = (tmp_path / "b" / "outputs" / "tiny" / "splatu" / "latest").resolve()
    assert (interrupted / trainer.DEGREE_CHOICE_FILE).is_file() == (stop_at > 9)
    resumed_dir = train_command.train(dataclasses.replace(mean_loss_choice(tmp_path / "c"), resume=interrupted))
    assert_same_run(resumed_dir, full_dir)


def test_ctrl_c_during_the_choice_resumes_by_choosing_again(tmp_path, scene, monkeypatch):
    full_dir = train_command.train(mean_loss_choice(tmp_path / "a"))
    score_degrees = ctrl_c_on_the_first_call(trainer.score_degrees)
    monkeypatch.setattr(trainer, "score_degrees", score_degrees)
    with pytest.raises(interrupts.TrainingInterrupted, match="aborted during step 10; the last checkpoint is"):
        train_command.train(mean_loss_choice(tmp_path / "b", checkpoint_every=3))
    interrupted = (tmp_path / "b" / "outputs" / "tiny" / "splatu" / "latest").resolve()
    resumed_dir = train_command.train(dataclasses.replace(mean_loss_choice(tmp_path / "c"), resume=interrupted))
    assert score_degrees.calls == 2
    assert_same_run(resumed_dir, full_dir)


def test_held_out_scoring_skips_a_view_its_mask_excludes_and_refuses_when_all_are():
    from splatu.degree_choice import head_ause
    from splatu.losses import UncertaintyLossConfig, uncertainty_heads

    heads = uncertainty_heads(UncertaintyLossConfig(extra_heads=("degree=1",)), 3)
    g = torch.Generator().manual_seed(0)
    renders = [torch.rand(6, 8, 3, generator=g) for _ in range(2)]
    targets = [torch.rand(6, 8, 3, generator=g) for _ in range(2)]
    maps = [np.random.default_rng(i).random((6, 8, len(heads))) for i in range(2)]
    masks = torch.stack([torch.ones(6, 8), torch.zeros(6, 8)])
    both = head_ause(renders, targets, maps, heads, masks)
    assert both == head_ause(renders[:1], targets[:1], maps[:1], heads, masks[:1])
    with pytest.raises(SplatuError, match="every held-out view's mask"):
        head_ause(renders[1:], targets[1:], maps[1:], heads, masks[1:])


def test_the_colour_scores_leave_out_what_the_mask_files_exclude(tmp_path):
    """Pixels a mask file excludes are never trained; the held-out PSNR that picks the colour degree used to
    count them (the uncertainty scores already left them out)."""
    config = dataclasses.replace(choice_config(tmp_path), uncertainty=UncertaintyLossConfig(off=True))
    model = _model_with_heads(config)
    train = tiny_scene(n_train=8).train
    with torch.no_grad():
        targets = _views_rendered_by(model, train.subset([0, 3, 6]), 2)
    valid = torch.ones(targets.images.shape[:3])
    valid[:, :, : valid.shape[2] // 2] = 0.0
    g = torch.Generator().manual_seed(0)

    def scores_with_junk_where_masked() -> dict[int, float]:
        junk = torch.where(valid[..., None] > 0, targets.images, torch.rand(targets.images.shape, generator=g))
        held_out = dataclasses.replace(targets, images=junk, mask_files=valid)
        return score_degrees(model, held_out, train.subset([1, 2, 4, 5, 7]), config, torch.zeros(3)).record[
            "colour_psnr"]

    assert scores_with_junk_where_masked() == scores_with_junk_where_masked()
    nothing_kept = dataclasses.replace(targets, mask_files=torch.zeros_like(valid))
    with pytest.raises(SplatuError, match="every held-out view's mask excludes all of its pixels"):
        score_degrees(model, nothing_kept, train.subset([1, 2, 4, 5, 7]), config, torch.zeros(3))


def test_a_resume_after_an_abort_that_followed_the_choice_chooses_and_logs_it_once(tmp_path, scene, monkeypatch):
    full_dir = train_command.train(mean_loss_choice(tmp_path / "a"))
    step_once = trainer.train_step

    def abort_step_10_once(state, config, images):
        if state.step == 9 and not aborted:
            aborted.append(1)
            raise KeyboardInterrupt  # a second Ctrl-C: the choice is made and logged, step 10 is not
        return step_once(state, config, images)

    aborted: list[int] = []
    monkeypatch.setattr(trainer, "train_step", abort_step_10_once)
    with pytest.raises(interrupts.TrainingInterrupted, match="aborted during step 10"):
        train_command.train(mean_loss_choice(tmp_path / "b", checkpoint_every=3))
    interrupted = (tmp_path / "b" / "outputs" / "tiny" / "splatu" / "latest").resolve()
    resumed_dir = train_command.train(dataclasses.replace(mean_loss_choice(tmp_path / "c"), resume=interrupted))
    assert_same_run(resumed_dir, full_dir)


@pytest.mark.parametrize(("choice_step", "newest", "set_aside"),
                         [(9, 12, True), (12, 12, True), (6, 12, False), (9, 9, True), (6, 9, False)])
def test_resuming_from_a_checkpoint_before_the_choice_sets_its_record_aside(tmp_path, choice_step, newest, set_aside):
    """The checkpoint of the decision step holds the model before the choice, so a resume from it (or from an
    earlier one) chooses again: the old record must not sit in the run as if it were the new one's, even when no
    later checkpoint exists (a second Ctrl-C right after the choice)."""
    (tmp_path / "checkpoints").mkdir()
    for step in sorted({9, newest}):
        (tmp_path / "checkpoints" / f"step-{step:07d}.pt").write_bytes(b"")
    (tmp_path / trainer.DEGREE_CHOICE_FILE).write_text(json.dumps({"step": choice_step}))
    folder = run_records.set_aside_later_work(tmp_path, 9)
    assert (folder is not None and (folder / trainer.DEGREE_CHOICE_FILE).is_file()) == set_aside
    assert (tmp_path / trainer.DEGREE_CHOICE_FILE).is_file() != set_aside


def test_extend_to_refuses_a_run_still_to_choose_its_degrees_and_trains_on_one_that_chose(tmp_path, scene):
    """Stopped before its decision step (9 of 16), the run would choose at another step of a longer run (13 of 24):
    refused in one line. Once the degrees are chosen the saved options no longer choose, so it trains on."""
    def stop_at_5(step, state):
        if step == 5:
            raise KeyboardInterrupt

    with pytest.raises(interrupts.TrainingInterrupted, match="interrupted at step 5"):
        train_command.train(choice_config(tmp_path), hooks=[stop_at_5])
    (run_dir,) = (p for p in (tmp_path / "outputs" / "tiny" / "splatu").iterdir() if not p.is_symlink())
    with pytest.raises(SplatuError, match="cannot train on a run stopped before its mid-run SH degree choice"):
        train_command.train(dataclasses.replace(choice_config(tmp_path), resume=run_dir, extend_to=24))
    assert not (run_dir / run_records.DEGREE_CHOICE_FILE).exists()
    train_command.train(dataclasses.replace(choice_config(tmp_path), resume=run_dir))
    chosen = json.loads((run_dir / run_records.DEGREE_CHOICE_FILE).read_text())
    train_command.train(dataclasses.replace(choice_config(tmp_path), resume=run_dir, extend_to=24))
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["steps"] == 24 and summary["degree_choice"] == chosen
