"""render-uncertainty and eval-ause --load on a tiny trained stand-in, every method, and the orbit."""

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch

from splatu.camera import Camera
from splatu.cli import entrypoint
from splatu.orbit import capture_frame, look_at, orbit_cameras


def _ring(n: int = 12, radius: float = 2.0, height: float = 1.0) -> list[Camera]:
    """Cameras on a ring above the origin, +z up, all looking at (0, 0, 0.2)."""
    K = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
    target = torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    cameras = []
    for k in range(n):
        a = 2 * math.pi * k / n
        position = torch.tensor([radius * math.cos(a), radius * math.sin(a), height], dtype=torch.float64)
        cameras.append(Camera(K, look_at(position, target, up).float(), 64, 48, name=f"ring_{k}"))
    return cameras


def test_orbit_recovers_the_capture_and_looks_from_below():
    ring = _ring()
    frame = capture_frame(ring)
    assert torch.allclose(frame.center, torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64), atol=1e-4)
    assert float(frame.up[2]) > 0.9  # cameras tilt down at the target, their mean up is still near +z
    orbit = orbit_cameras(ring, frames=16, max_elevation_degrees=60.0)
    elevations = [f.elevation_degrees for f in orbit]
    assert max(elevations) == pytest.approx(60.0) and min(elevations) == pytest.approx(-60.0)
    for f in orbit:
        uv, z = f.camera.project(frame.center[None].float())
        assert float(z[0]) > 0 and torch.allclose(uv[0], torch.tensor([32.0, 24.0]), atol=1e-3)
        below = float(f.camera.center()[2]) < 0.2
        assert below == (f.elevation_degrees < -1e-6) or abs(f.elevation_degrees) < 1e-6


# --- on a tiny trained stand-in ----------------------------------------------------------------

TINY_STEPS = 80


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One short training of the paper's method on a tiny stand-in, shared by this module's tests."""
    from splatu import trainer
    from splatu.data.config import DataConfig
    from splatu.data.poster import PosterConfig
    from splatu.densify import DensifyConfig
    from splatu.train_config import preset_config

    root = tmp_path_factory.mktemp("render_uncertainty")
    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setenv("SPLATU_CACHE", str(root / "cache"))
    base = preset_config("fast")
    config = dataclasses.replace(
        base, steps=TINY_STEPS, checkpoint_every=0, progress=False, compile_kernels=False, output_dir=root / "outputs",
        resolution_interval=30, model=dataclasses.replace(base.model, sh_degree_interval=20),
        data=DataConfig(data="poster", poster=PosterConfig(width=48, height=80, frames=24, eval_block=5,
                                                            interp_every=6, points=2000)),
        densify=DensifyConfig(warmup_length=10, refine_every=10, stop_split_at=50, stop_screen_size_at=25,
                              max_gaussians=2500),
    )
    run_dir = trainer.train(config)
    yield run_dir
    monkeypatch.undo()


def _render(run_dir, *args: str):
    entrypoint(["render-uncertainty", "--load", str(run_dir), *args])


def test_render_eval_writes_every_file_with_finite_maps_in_unit_range(tiny_run, tmp_path):
    out = tmp_path / "eval"
    _render(tiny_run, "--output", str(out))
    record = json.loads((out / "render.json").read_text())
    names = [v["name"] for v in record["per_view"]]
    assert len(names) == 5  # the eval block
    for name in names:
        for key in ("rgb", "depth", "alpha", "uncertainty"):
            value = np.load(out / "npy" / f"{name}_{key}.npy")
            assert np.isfinite(value).all(), (name, key)
            assert (out / "png" / f"{name}_{key}.png").is_file()
        u = np.load(out / "npy" / f"{name}_uncertainty.npy")
        alpha = np.load(out / "npy" / f"{name}_alpha.npy")
        assert u.min() >= 0.0 and u.max() <= 1.0 + 1e-6
        assert alpha.min() >= -1e-6 and alpha.max() <= 1.0 + 1e-6
        assert (out / "panels" / f"{name}.png").is_file()
        for folder, suffix in (("rgb", "png"), ("gt", "png"), ("uncertainty", "npy"), ("unobserved", "png")):
            assert (out / "maps" / folder / f"{name}.{suffix}").is_file()
    for key in ("uncertainty", "depth", "error"):
        assert (out / f"colorbar_{key}.png").is_file()
    assert record["uncertainty_scale"] == [0.0, 1.0]


def test_orbit_from_below_is_more_uncertain_than_the_training_path(tiny_run, tmp_path):
    _render(tiny_run, "--views", "orbit", "--orbit-frames", "8", "--output", str(tmp_path / "orbit"))
    _render(tiny_run, "--views", "train", "--max-views", "4", "--output", str(tmp_path / "train"))
    orbit = json.loads((tmp_path / "orbit" / "render.json").read_text())["per_view"]
    train = json.loads((tmp_path / "train" / "render.json").read_text())["per_view"]
    below = [v["mean_uncertainty"] for v in orbit if v["elevation_degrees"] < -20.0]
    seen = [v["mean_uncertainty"] for v in train]
    assert len(below) >= 3
    # every view from below is more uncertain than every view of the training path
    assert min(below) > max(seen), (below, seen)
    assert (tmp_path / "orbit" / "orbit.gif").stat().st_size > 0
    assert not (tmp_path / "orbit" / "maps").exists()  # no ground truth on the orbit


def test_eval_ause_load_scores_the_run_with_auroc(tiny_run):
    entrypoint(["eval-ause", "--load", str(tiny_run)])
    report = json.loads((tiny_run / "ause_ours.json").read_text())
    mean = report["mean"]
    for key in ("ause_mae", "ause_rmse", "random_ause_mae", "ause_mae_start_norm", "auroc_unobserved"):
        assert mean[key] is not None and math.isfinite(mean[key]), key
    assert mean["oracle_ause_mae"] == 0.0
    assert 0.0 <= mean["auroc_unobserved"] <= 1.0
    assert len(report["per_image"]) == 5


@pytest.mark.parametrize("method", ["visibility", "fisher", "random"])
def test_every_baseline_renders_and_scores(tiny_run, method):
    entrypoint(["eval-ause", "--load", str(tiny_run), "--method", method])
    mean = json.loads((tiny_run / f"ause_{method}.json").read_text())["mean"]
    assert math.isfinite(mean["ause_mae"]) and math.isfinite(mean["random_ause_mae"])
    maps = tiny_run / "uncertainty" / f"{method}-eval" / "maps" / "uncertainty"
    for path in maps.glob("*.npy"):
        u = np.load(path)
        assert np.isfinite(u).all() and u.min() >= 0.0 and u.max() <= 1.0 + 1e-6


def test_ensemble_of_identical_members_has_zero_std_and_density_aware_adds_empty_space(tiny_run, tmp_path):
    ensemble = tmp_path / "ensemble"
    for k in range(2):
        shutil.copytree(tiny_run, ensemble / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty"))
    (ensemble / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"],
                                                        "wall_seconds": 12.5}))
    _render(ensemble, "--method", "ensemble", "--max-views", "2", "--output", str(tmp_path / "plain"))
    _render(ensemble, "--method", "ensemble", "--density-aware", "--max-views", "2",
            "--output", str(tmp_path / "aware"))
    record = json.loads((tmp_path / "plain" / "render.json").read_text())
    assert record["train_seconds"] == 12.5
    for view in record["per_view"]:
        plain = np.load(tmp_path / "plain" / "npy" / f"{view['name']}_uncertainty.npy")
        aware = np.load(tmp_path / "aware" / "npy" / f"{view['name']}_uncertainty.npy")
        alpha = np.load(tmp_path / "aware" / "npy" / f"{view['name']}_alpha.npy")
        assert np.abs(plain).max() < 1e-6
        assert np.allclose(aware, (1.0 - alpha) ** 2, atol=1e-5)


def test_wrong_method_for_the_run_is_one_line(tiny_run, capsys):
    with pytest.raises(SystemExit) as exc:
        _render(tiny_run, "--method", "ensemble")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ensemble" in err[0]
