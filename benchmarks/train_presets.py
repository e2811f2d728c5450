"""PSNR and wall time of the training presets on the built-in poster stand-in and on fox.

    .venv/bin/python benchmarks/train_presets.py                      # poster + fox, fast + quality
    .venv/bin/python benchmarks/train_presets.py --scenes poster --presets fast
    .venv/bin/python benchmarks/train_presets.py --scenes poster --presets fast --sh-degrees 0 1 3
    .venv/bin/python benchmarks/train_presets.py --scenes fox --presets fast --sh-degrees 0 1 3 --seeds 0 1 2
    .venv/bin/python benchmarks/train_presets.py --presets fast --degree-choice --seeds 0 1 2

Each row is one full `splatu train` run through the Python API (data loading included in the
wall time; the image/stand-in cache may already be warm, which the table says). `--sh-degrees`
trains each preset once per colour-SH degree, to measure which degree a scene needs (the
preset's own degree when not given); `--degree-choice` lets each run choose its degrees instead.
`--seeds` repeats every configuration per seed, because on fox one seed's held-out PSNR spreads by
about 3 dB, more than the degrees differ. fox is read from
../shared/data/fox with a contiguous eval block and is skipped with a message when absent.
Writes benchmarks/results/train_presets.json and .md, keeping rows this invocation did not rerun; each new row
records its date and CPU.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import tyro

from splatu import train_command
from splatu.data.config import DataConfig
from splatu.provenance import measured_on
from splatu.train_config import preset_config

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SPLATU_SHARED_DATA", REPO.parent / "shared" / "data"))
RESULTS = REPO / "benchmarks" / "results"


@dataclass
class Args:
    scenes: list[str] = field(default_factory=lambda: ["poster", "fox"])
    """Scenes to train: poster (built-in stand-in) and/or fox (../shared/data/fox)."""
    presets: list[str] = field(default_factory=lambda: ["fast", "quality"])
    """Presets to compare."""
    sh_degrees: list[int] = field(default_factory=list)
    """Colour-SH degrees to train each preset at (empty: the preset's own)."""
    seeds: list[int] = field(default_factory=lambda: [0])
    """Seeds to train each configuration with."""
    degree_choice: bool = False
    """Let each run choose its colour and u-SH degrees on held-out views (--degree-choice.on); a row then records
    the degrees chosen, and --sh-degrees sets the highest one considered."""
    fox_downscale: int = 8
    """fox is 1080x1920; 8 gives 135x240, about the stand-in's 144x256."""
    output_dir: Path = Path("outputs/benchmarks")
    """Where the benchmark runs are written."""


def data_config(scene: str, fox_downscale: int) -> DataConfig | None:
    if scene == "poster":
        return DataConfig(data="poster")
    path = SHARED_DATA / scene
    if not path.is_dir():
        print(f"skipping {scene}: {path} not found (../shared/data is absent on this machine)")
        return None
    return DataConfig(data=str(path), eval_split="contiguous", downscale=fox_downscale)


def run_one(scene: str, preset: str, sh_degree: int | None, seed: int, data: DataConfig, output_dir: Path,
            degree_choice: bool) -> dict:
    base = preset_config(preset)  # the scene's options, with the preset's image size where no --downscale is given
    data = dataclasses.replace(data, max_image_size=base.data.max_image_size)
    config = dataclasses.replace(base, data=data, output_dir=output_dir, progress=False, seed=seed)
    if sh_degree is not None:
        config = dataclasses.replace(config, model=dataclasses.replace(config.model, sh_degree=sh_degree))
    if degree_choice:
        config = dataclasses.replace(config, degree_choice=dataclasses.replace(config.degree_choice, on=True))
    started = time.perf_counter()
    run_dir = train_command.train(config)
    wall = time.perf_counter() - started
    summary = json.loads((run_dir / "summary.json").read_text())
    uncertainty = "off" if config.uncertainty.off else f"{config.uncertainty.kind}, u-SH {summary['u_sh_degree']}"
    row = {"scene": scene, "preset": preset, "sh_degree": summary["sh_degree"], "seed": seed,
           "degree_choice": degree_choice, "uncertainty": uncertainty,
           "steps": summary["steps"], "gaussians": summary["num_gaussians"],
           "wall_seconds": wall, "train_seconds": summary["train_seconds"],
           "train_compile_seconds": summary["train_compile_seconds"], "run_dir": str(run_dir),
           **{k: v for k, v in measured_on().items() if k in ("date", "revision", "cpu")}}
    for set_name, metrics in summary["eval"].items():
        for key, value in metrics.items():
            if key != "num_images":
                row[f"{set_name}_{key}"] = value
    return row


def markdown(rows: list[dict]) -> str:
    cols = ["scene", "preset", "sh_degree", "degree_choice", "seed", "uncertainty", "steps", "gaussians",
            "wall_seconds", "eval_psnr", "eval_psnr_observed", "eval_ssim", "interp_psnr", "interp_ssim", "date", "cpu"]
    lines = ["PSNR (dB, mean over images) on the contiguous held-out block (`eval`), on its observed pixels",
             "(built-in scene only) and on every-8th held-out path frames (`interp`, built-in only); wall time",
             "includes data loading (cached stand-in/images when warm). 2 shared CPU cores; wall times compare only",
             "between rows of one CPU. `degree_choice` True: the run chose its colour-SH and u-SH degrees itself",
             "(--degree-choice.on), and those columns show what it chose.", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in rows:
        cells = [f"{row[c]:.2f}" if isinstance(row.get(c), float) else str(row.get(c, "-")) for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def merged_with_previous(rows: list[dict], path: Path) -> list[dict]:
    """Keep earlier rows for (scene, preset, colour-SH degree or chosen, seed) this invocation did not rerun."""
    previous = json.loads(path.read_text()) if path.is_file() else []
    done = {_key(r) for r in rows}
    return [r for r in previous if _key(r) not in done] + rows


def _key(row: dict) -> tuple[str, str, int | str, int]:
    # rows from before the sweep used degree 3 and seed 0; a run that chose its degree is keyed by that, not by
    # the degree it happened to choose
    degree = "chosen" if row.get("degree_choice") else row.get("sh_degree", 3)
    return row["scene"], row["preset"], degree, row.get("seed", 0)


def main(args: Args) -> None:
    rows = []
    for scene in args.scenes:
        data = data_config(scene, args.fox_downscale)
        if data is None:
            continue
        for preset in args.presets:
            for seed in args.seeds:
                for sh_degree in args.sh_degrees or [None]:
                    degree = "of the preset" if sh_degree is None else sh_degree
                    chosen = ", degrees chosen on held-out views" if args.degree_choice else ""
                    print(f"training {scene} with preset {preset}, colour-SH degree {degree}{chosen}, seed {seed} ...",
                          flush=True)
                    rows.append(run_one(scene, preset, sh_degree, seed, data, args.output_dir, args.degree_choice))
                    print(json.dumps(rows[-1]), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    rows = merged_with_previous(rows, RESULTS / "train_presets.json")
    (RESULTS / "train_presets.json").write_text(json.dumps(rows, indent=2))
    (RESULTS / "train_presets.md").write_text(markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main(tyro.cli(Args))
