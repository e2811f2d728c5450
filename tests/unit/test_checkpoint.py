import random

import numpy as np
import pytest
import torch

from splatu import checkpoint as ckpt
from splatu.config_values import to_dict
from splatu.errors import SplatuError
from splatu.model import GaussianModel
from splatu.train_config import TrainConfig


def _state(config: TrainConfig, seed: int) -> dict:
    generator = torch.Generator().manual_seed(seed)
    model = GaussianModel.from_points(torch.rand(50, 3, generator=generator), None, config.model, generator)
    return {"config": to_dict(config), "model": model.state_dict(), "num_gaussians": len(model)}


def test_save_then_load_run_round_trips_config_and_model(tmp_path):
    config = TrainConfig(steps=7, seed=3)
    state = _state(config, 0)
    ckpt.save_checkpoint(tmp_path, 5, state)
    loaded_config, model, _ = ckpt.load_run(tmp_path)
    assert loaded_config == config
    for name, value in state["model"].items():
        assert torch.equal(model.state_dict()[name], value)


def test_crash_mid_write_leaves_the_old_checkpoint_intact(tmp_path, monkeypatch):
    config = TrainConfig()
    good = _state(config, 0)
    path = ckpt.save_checkpoint(tmp_path, 10, good)

    def crash(obj, f):
        f.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(ckpt.torch, "save", crash)
    with pytest.raises(SplatuError, match=r"could not write step-0000010\.pt"):  # one line, not a traceback
        ckpt.save_checkpoint(tmp_path, 10, _state(config, 1))
    monkeypatch.undo()
    survived = ckpt.read_checkpoint(path)
    assert torch.equal(survived["model"]["means"], good["model"]["means"])
    assert [p.name for p in (tmp_path / ckpt.CHECKPOINT_DIR).iterdir()] == [path.name]  # no temp file left


def test_only_the_newest_checkpoints_are_kept_and_the_newest_is_resolved(tmp_path):
    state = _state(TrainConfig(), 0)
    for step in (10, 20, 30):
        ckpt.save_checkpoint(tmp_path, step, state)
    names = [p.name for p in ckpt.list_checkpoints(tmp_path)]
    assert names == ["step-0000020.pt", "step-0000030.pt"]  # the default keeps two
    assert ckpt.resolve_checkpoint(tmp_path) == ckpt.checkpoint_path(tmp_path, 30)
    assert ckpt.run_dir_of(ckpt.checkpoint_path(tmp_path, 30)) == tmp_path.resolve()
    for step in (40, 50, 60):
        ckpt.save_checkpoint(tmp_path, step, state, keep=4)
    assert [p.name for p in ckpt.list_checkpoints(tmp_path)] == [f"step-00000{s}.pt" for s in (30, 40, 50, 60)]


def test_a_checkpoint_is_inside_a_run_only_beside_or_below_its_config(tmp_path):
    """A run writes config.yml first; a folder without one (~/Downloads, a copied checkpoints/, abandoned/<time>/)
    is no run, and `--resume` of a checkpoint in it trains on in a new run instead of turning it into one."""
    run = tmp_path / "run"
    in_checkpoints = ckpt.checkpoint_path(run, 5)
    in_checkpoints.parent.mkdir(parents=True)
    in_checkpoints.touch()
    (run / "by_hand.pt").touch()
    assert ckpt.run_holding(in_checkpoints) is None and ckpt.run_holding(run / "by_hand.pt") is None
    (run / "config.yml").write_text("steps: 3\n")
    assert ckpt.run_holding(in_checkpoints) == ckpt.run_holding(run / "by_hand.pt") == run.resolve()
    (run / "abandoned" / "t").mkdir(parents=True)
    (run / "abandoned" / "t" / "step-0000009.pt").touch()
    assert ckpt.run_holding(run / "abandoned" / "t" / "step-0000009.pt") is None


def test_keeping_no_checkpoint_is_refused(tmp_path):
    from splatu.cli import main

    with pytest.raises(SplatuError, match="--keep-checkpoints"):
        TrainConfig(keep_checkpoints=0)
    with pytest.raises(SplatuError, match="--keep-checkpoints"):
        main(["train", "--keep-checkpoints", "0", "--output-dir", str(tmp_path)], False)


def test_a_users_copy_in_the_checkpoint_folder_is_not_a_checkpoint(tmp_path):
    """'step-0000200 (copy).pt' matched step-*.pt: it sorted as the newest (so it was resumed from), broke
    checkpoint_step with a traceback, and was deleted by the pruning of old checkpoints."""
    state = _state(TrainConfig(), 0)
    ckpt.save_checkpoint(tmp_path, 100, state)
    copy = tmp_path / ckpt.CHECKPOINT_DIR / "step-0000100 (copy).pt"
    copy.write_bytes(ckpt.checkpoint_path(tmp_path, 100).read_bytes())
    assert ckpt.list_checkpoints(tmp_path) == [ckpt.checkpoint_path(tmp_path, 100)]
    for step in (200, 300, 400):
        ckpt.save_checkpoint(tmp_path, step, state)
    assert ckpt.resolve_checkpoint(tmp_path) == ckpt.checkpoint_path(tmp_path, 400)
    assert copy.is_file()


def test_corrupt_foreign_and_missing_checkpoints_are_one_line_errors(tmp_path):
    corrupt = tmp_path / "bad.pt"
    corrupt.write_bytes(b"\x00not a checkpoint")
    with pytest.raises(SplatuError, match="corrupt"):
        ckpt.read_checkpoint(corrupt)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(2)}, foreign)
    with pytest.raises(SplatuError, match="not a splatu checkpoint"):
        ckpt.read_checkpoint(foreign)
    with pytest.raises(SplatuError, match="not found"):
        ckpt.resolve_checkpoint(tmp_path / "missing")
    (tmp_path / "data_folder").mkdir()
    with pytest.raises(SplatuError, match=r"not a splatu run \(it has no checkpoints/ folder or config.yml\)"):
        ckpt.load_run(tmp_path / "data_folder")
    (tmp_path / "aborted_run").mkdir()  # stopped in its first step: its config, no checkpoint yet
    (tmp_path / "aborted_run" / "config.yml").write_text("steps: 10\n")
    with pytest.raises(SplatuError, match="no checkpoint in this run directory"):
        ckpt.load_run(tmp_path / "aborted_run")
    (tmp_path / "empty_run" / ckpt.CHECKPOINT_DIR).mkdir(parents=True)
    with pytest.raises(SplatuError, match="no checkpoint in this run directory"):
        ckpt.load_run(tmp_path / "empty_run")
    transforms = tmp_path / "transforms.json"  # a scene file passed to --load is not a damaged checkpoint
    transforms.write_text('{"frames": []}')
    with pytest.raises(SplatuError) as caught:
        ckpt.load_run(transforms)
    assert caught.value.what == "not a splatu checkpoint" and caught.value.where == f"in {transforms}"


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_checkpoint_with_nan_or_inf_names_the_file_and_tensor(tmp_path, bad):
    """It used to load, and the render then blamed the rasterizer's input; a resume set later work aside first."""
    state = _state(TrainConfig(), 0)
    state["model"]["u_sh"][3, 0, 0] = bad
    path = ckpt.save_checkpoint(tmp_path, 5, state)
    with pytest.raises(SplatuError) as caught:
        ckpt.load_run(tmp_path)
    assert caught.value.what == "checkpoint has NaN or Inf in u_sh (1 of 800 values)"
    assert caught.value.where == f"in {path}"


def test_the_folder_holding_runs_names_its_latest_run(tmp_path):
    """`--load outputs/poster/splatu` (the runs' folder, as nerfstudio users type it) said only "pass a run
    directory": the fix names the `latest` link inside it."""
    method_dir = tmp_path / "outputs" / "poster" / "splatu"
    (method_dir / "2026-01-01_000000").mkdir(parents=True)
    (method_dir / "latest").symlink_to("2026-01-01_000000")
    with pytest.raises(SplatuError) as caught:
        ckpt.resolve_checkpoint(method_dir)
    assert caught.value.fix == f"pass {method_dir}/latest, the newest run in it, or one of its timestamped runs"


def test_a_runs_checkpoints_folder_names_its_run(tmp_path):
    """`--load RUN/checkpoints` said "pass a run directory" without naming the one it is in."""
    path = ckpt.save_checkpoint(tmp_path / "run", 5, _state(TrainConfig(), 0))
    (tmp_path / "run" / "config.yml").write_text("steps: 10\n")
    with pytest.raises(SplatuError) as caught:
        ckpt.resolve_checkpoint(path.parent)
    assert caught.value.fix == f"pass its run, {tmp_path / 'run'}, or one of the .pt files in this folder"


def test_a_folder_above_the_runs_names_a_few_of_them(tmp_path):
    """`--load outputs` (the root of every scene's runs) said only "pass a run directory": the fix names the
    `latest` link of each scene and method beneath it, or, without such links, the runs themselves."""
    outputs = tmp_path / "outputs"
    for scene, method in (("poster", "splatu"), ("fox", "splatu"), ("poster", "splatfacto"), ("fox", "ensemble")):
        (outputs / scene / method / "2026-01-01_000000").mkdir(parents=True)
        (outputs / scene / method / "latest").symlink_to("2026-01-01_000000")
    with pytest.raises(SplatuError) as caught:
        ckpt.resolve_checkpoint(outputs)
    assert caught.value.fix == (f"pass a run beneath it, such as {outputs}/fox/ensemble/latest, "
                                f"{outputs}/fox/splatu/latest or {outputs}/poster/splatfacto/latest (3 of 4)")
    loose = tmp_path / "loose"
    (loose / "a" / "b" / "run").mkdir(parents=True)
    (loose / "a" / "b" / "run" / "config.yml").write_text("steps: 10\n")
    with pytest.raises(SplatuError) as caught:
        ckpt.resolve_checkpoint(loose)
    assert caught.value.fix == f"pass a run beneath it, such as {loose}/a/b/run"


def test_a_checkpoint_that_does_not_fit_its_config_names_the_file(tmp_path):
    state = _state(TrainConfig(), 0)
    state["model"]["sh_rest"] = state["model"]["sh_rest"][:, :3]
    path = ckpt.save_checkpoint(tmp_path, 5, state)
    with pytest.raises(SplatuError) as caught:
        ckpt.load_run(tmp_path)
    assert caught.value.what.startswith("checkpoint model does not match its config")
    assert caught.value.where == f"in {path}"


def test_rng_states_round_trip_through_a_saved_checkpoint(tmp_path):
    generator = torch.Generator().manual_seed(1)
    torch.manual_seed(2)
    np.random.seed(3)
    random.seed(4)
    ckpt.save_checkpoint(tmp_path, 1, {"rng": ckpt.capture_rng(generator)})
    expected = (torch.rand(3, generator=generator), torch.rand(3), np.random.rand(3), random.random())
    restored = torch.Generator()
    ckpt.restore_rng(ckpt.read_checkpoint(ckpt.checkpoint_path(tmp_path, 1))["rng"], restored)
    again = (torch.rand(3, generator=restored), torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(expected[0], again[0]) and torch.equal(expected[1], again[1])
    assert np.array_equal(expected[2], again[2]) and expected[3] == again[3]


def test_checkpoint_missing_keys_is_a_one_line_error(tmp_path):
    path = ckpt.checkpoint_path(tmp_path, 1)
    path.parent.mkdir(parents=True)
    torch.save({"format": ckpt.FORMAT, "step": 1}, path)
    with pytest.raises(SplatuError, match="incomplete checkpoint"):
        ckpt.load_run(tmp_path)
    with pytest.raises(SplatuError, match="incomplete checkpoint"):
        ckpt.read_checkpoint(path, ckpt.RESUME_KEYS)


@pytest.mark.parametrize("damage", [
    lambda state: state.update(config=None),
    lambda state: state.update(model=[1, 2]),
    lambda state: state.update(world_transform=3.0),
    lambda state: state["world_transform"].update(scale=float("nan")),
    lambda state: state["world_transform"].update(scale=0.0),
    lambda state: state["world_transform"].update(translation=torch.tensor([0.0, float("inf"), 0.0])),
    lambda state: state["world_transform"].pop("rotation"),
])
def test_a_checkpoint_with_a_damaged_config_model_or_frame_names_the_file(tmp_path, damage):
    """Each of these was a traceback (AttributeError, ValueError, KeyError), or a NaN frame that then read as
    "the scene's normalisation differs"."""
    from splatu.world_frame import WorldTransform

    state = _state(TrainConfig(), 0)
    state["world_transform"] = WorldTransform.from_normalization(torch.zeros(3), 2.0).state_dict()
    path = ckpt.save_checkpoint(tmp_path, 5, state)
    ckpt.load_run(tmp_path)  # whole, it loads
    damage(state)
    path = ckpt.save_checkpoint(tmp_path, 6, state)
    with pytest.raises(SplatuError) as caught:
        ckpt.load_run(tmp_path)
    assert "damaged" in caught.value.what and caught.value.where == f"in {path}"


def test_a_checkpoint_older_than_the_frame_record_and_the_blur_option_loads_as_it_was_trained(tmp_path):
    """Runs saved before the scene's normalisation was recorded, and before `screen_blur` and `antialiased` were
    options, load with no frame to check (so any scene is let through) and with 3DGS's 0.3 px² blur, unscaled
    opacities: what they were trained with, not the presets' 0.1 of today."""
    config = TrainConfig(steps=7)
    state = _state(config, 0)
    del state["config"]["model"]["screen_blur"], state["config"]["model"]["antialiased"]
    assert "world_transform" not in state
    ckpt.save_checkpoint(tmp_path, 7, state)
    loaded_config, model, frame = ckpt.load_run(tmp_path)
    assert frame is None
    assert loaded_config.model.screen_blur == 0.3 and loaded_config.model.antialiased is False
    assert loaded_config.steps == 7 and len(model) == state["num_gaussians"]


def test_an_ensemble_run_is_named_as_one_wherever_a_single_run_is_expected(tmp_path, capsys):
    """Its folder holds one run per member and no checkpoint of its own: "no checkpoint in this run directory,
    train it first" would send the user the wrong way."""
    from splatu.cli import entrypoint

    (tmp_path / "ensemble.json").write_text("{}")
    (tmp_path / "config.yml").write_text("steps: 3\n")
    for load in (ckpt.resolve_checkpoint, ckpt.load_run):
        with pytest.raises(SplatuError, match="this is an ensemble run"):
            load(tmp_path)
    with pytest.raises(SystemExit):
        entrypoint(["export", "--load", str(tmp_path)])
    assert "this is an ensemble run" in capsys.readouterr().err


@pytest.mark.parametrize("load", ["run", "checkpoint"])
def test_a_checkpoint_copied_in_from_another_run_is_refused_by_render_eval_and_export(tmp_path, load):
    """render-uncertainty, eval-ause and export load through load_run: another run's checkpoint put in this run's
    checkpoints/ rendered or exported the other model and filed it under this run's name."""
    from splatu.train_config import save_config
    save_config(TrainConfig(seed=1), tmp_path / "config.yml")
    path = ckpt.save_checkpoint(tmp_path, 5, _state(TrainConfig(seed=0), 0))
    with pytest.raises(SplatuError) as caught:
        ckpt.load_run(tmp_path if load == "run" else path)
    assert caught.value.what == ("this checkpoint was not written by this run (its seed is 0, the run's config.yml "
                                 "has 1)")
    assert caught.value.where == f"in {path}" and caught.value.fix.endswith("to --load")
    save_config(TrainConfig(seed=0, steps=9), tmp_path / "config.yml")  # only what a run's own life changes differs
    assert ckpt.load_run(path).config.seed == 0
