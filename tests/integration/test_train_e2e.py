"""A short end-to-end run on a tiny built-in stand-in: data generation, training, eval, export."""

import dataclasses
import json
import time

from splatu import train_command
from splatu.checkpoint import load_run
from splatu.data.config import DataConfig
from splatu.data.poster import PosterConfig
from splatu.densify import DensifyConfig
from splatu.train_config import preset_config

TINY_POSTER = PosterConfig(width=32, height=48, frames=16, eval_block=3, interp_every=5, points=1000)


def test_tiny_standin_trains_end_to_end_and_learns(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SPLATU_CACHE", str(tmp_path / "cache"))
    base = preset_config("fast")
    config = dataclasses.replace(
        base, steps=40, eval_every_steps=10, checkpoint_every=20, progress=False, output_dir=tmp_path / "outputs",
        compile_kernels=False,
        resolution_levels=0, model=dataclasses.replace(base.model, sh_degree_interval=20),
        data=DataConfig(data="poster", poster=TINY_POSTER),
        densify=DensifyConfig(warmup_length=10, refine_every=10, stop_split_at=40, stop_screen_size_at=20,
                              max_gaussians=2000),
    )
    started = time.perf_counter()
    run_dir = train_command.train(config)
    seconds = time.perf_counter() - started

    evals = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    interp = [r for r in evals if r["event"] == "eval" and r["set"] == "interp"]
    assert [r["step"] for r in interp] == [10, 20, 30, 40]
    assert interp[-1]["psnr"] > interp[0]["psnr"] + 1.0, interp  # it learns
    assert seconds < 60, f"the tiny end-to-end run took {seconds:.0f} s (issue 5: under 60 s)"
    held_out = [r for r in evals if r["event"] == "eval" and r["set"] == "eval"]
    assert "psnr_observed" in held_out[-1]
    assert (tmp_path / "outputs" / "poster" / "splatu" / "latest" / "splat.ply").is_file()
    loaded_config, model, _ = load_run(run_dir)
    chosen = dataclasses.replace(config.data, downscale=1)  # the run records the downscale train chose for it
    assert loaded_config == dataclasses.replace(config, data=chosen) and len(model) > 0
    said = [line for line in capsys.readouterr().err.splitlines() if "stand-in" in line]
    assert len(said) == 1 and said[0].startswith("scene poster (the built-in stand-in, not nerfstudio's capture")
    assert json.loads((run_dir / "summary.json").read_text())["stand_in"] is True
