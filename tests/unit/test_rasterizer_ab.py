"""benchmarks/rasterizer_ab.py imports an earlier commit's package beside the working tree's, renamed; the
renaming must reach every import statement and nothing else, or the "base" would silently run current code."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pytest
import torch

import splatu.data.resolve
from splatu import checkpoint
from splatu.camera import Camera, look_at
from splatu.config_values import to_dict
from splatu.data.poster.path import WORLD_UP
from splatu.model import GaussianModel
from splatu.rasterizer import rasterize
from splatu.train_config import ModelConfig, TrainConfig
from tests.benchmark_scripts import benchmark_script

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ab():
    yield from benchmark_script("rasterizer_ab")


def test_rename_package_rewrites_imports_only(ab) -> None:
    source = ("from splatu.rasterizer import rasterize\nimport splatu.sh\n    from splatu import losses\n"
              "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")
    assert ab.rename_package(source) == (
        "from splatu_base.rasterizer import rasterize\nimport splatu_base.sh\n    from splatu_base import losses\n"
        "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(), reason="needs git and a clone")
def test_the_exported_base_runs_only_its_own_modules(ab, tmp_path: Path) -> None:
    """Import the exported HEAD's rasterizer in a fresh interpreter: every splatu* module it loads must come
    from the export, none from the working tree."""
    ab.export_base(ab.resolve_commit("HEAD"), tmp_path)
    probe = (
        "import sys; sys.path.insert(0, sys.argv[1]); import splatu_base.rasterizer\n"
        "for name, module in sorted(sys.modules.items()):\n"
        "    if name.split('.')[0].startswith('splatu'): print(name, module.__file__)\n"
    )
    loaded = subprocess.run([sys.executable, "-c", probe, str(tmp_path)], capture_output=True, text=True,
                            check=True, cwd=tmp_path).stdout.splitlines()
    assert any(line.startswith("splatu_base.rasterizer.composite ") for line in loaded)
    for line in loaded:
        name, file = line.split(" ", 1)
        assert name.startswith("splatu_base") and Path(file).is_relative_to(tmp_path), line


def test_a_revision_that_names_no_commit_is_one_clear_line(ab) -> None:
    with pytest.raises(SystemExit, match="is not a commit of the repository"):
        ab.resolve_commit("--no-such-revision")


def test_a_trained_run_is_timed_at_each_training_view_as_training_renders_it(ab, tmp_path: Path, monkeypatch) -> None:
    """`--run`: one view per training camera, and each renders what the model's own render gives there (its
    view-dependent colours, opacities and screen blur), so the A/B times the renders training makes."""
    config = TrainConfig(model=ModelConfig(sh_degree=2, screen_blur=0.1))
    generator = torch.Generator().manual_seed(0)
    model = GaussianModel.from_points(torch.rand(60, 3, generator=generator) - 0.5, None, config.model, generator)
    model.sh_rest.data.normal_(0.0, 0.3, generator=generator)  # view-dependent colour, so directions matter
    checkpoint.save_checkpoint(tmp_path, 5, {"config": to_dict(config), "model": model.state_dict(),
                                             "num_gaussians": len(model)})
    K = torch.tensor([[40.0, 0.0, 24.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    eyes = [torch.tensor([3 * math.cos(a), 3 * math.sin(a), 0.5], dtype=torch.float64) for a in (0.0, 2.0, 4.0)]
    cameras = [Camera(K, look_at(eye, torch.zeros(3, dtype=torch.float64), WORLD_UP).float(), 48, 32) for eye in eyes]
    monkeypatch.setattr(splatu.data.resolve, "load_scene",
                        lambda data: types.SimpleNamespace(train=types.SimpleNamespace(cameras=cameras)))
    name, views = ab.trained_views(tmp_path)
    assert len(views) == 3 and "60 Gaussians" in name
    bench = ab.load_rasterizer_benchmark()
    for camera, view in zip(cameras, views, strict=True):
        assert view.options["blur"] == 0.1
        image, _, pairs = ab.render_step(rasterize, bench, view)
        with torch.no_grad():
            expected = model.render(camera, config.model.sh_degree, torch.zeros(3))
        assert pairs > 0
        assert torch.allclose(image, expected.rgb, atol=1e-6)
