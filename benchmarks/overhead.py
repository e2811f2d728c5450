"""Cost of the uncertainty loss: time per training step with it on ÷ off, same run, same scene.

    .venv/bin/python benchmarks/overhead.py            # built-in poster stand-in, fast preset

One model is first trained for `warmup` steps (so it has a realistic, densified set of
Gaussians), then measured steps alternate on/off on that same state, each pair on the same
camera at full resolution; refinement is switched off during measurement so the number of
Gaussians stays fixed. The ratio of the median step times is the overhead (target ≤ 1.05);
because step times on a shared machine are noisy, the script also times alone the work a step does
only with the loss on (its forward + backward, then the Adam step of `u_sh` and the finiteness check
of its gradient) and reports (median off + that) / median off.
Kernels are compiled when the preset compiles them (as in training; --eager for eager ones), and glibc malloc's
thresholds are fixed as `splatu train` fixes them (splatu.allocator): with glibc's defaults the full-resolution
measured steps page-faulted ~22,000 times each (the warm-up, at lower resolution, almost never), a cost training
does not pay that lengthened on and off alike and so pulled the ratio towards 1.
The median and quartiles of the per-pair ratios are reported too: the ratio of medians alone read 1.012 where the
pairs' own ratios had a median of 1.04 (quartiles 0.88–1.15) on a noisy host.
Writes --json, by default benchmarks/results/overhead.json (compiled) or overhead_eager.json.
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch
import tyro

from splatu import trainer, training_step
from splatu.allocator import keep_freed_memory
from splatu.data.resolve import load_scene
from splatu.densify import DensityController
from splatu.losses import uncertainty_loss
from splatu.provenance import measured_on
from splatu.rasterizer.kernels import kernels_compiled, set_compile
from splatu.train_config import TrainConfig, preset_config

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


@dataclass
class Args:
    data: str = "poster"
    """Scene to measure on."""
    preset: str = "fast"
    """Preset whose settings (Gaussian budget, SH degrees, loss) are measured."""
    warmup: int = 300
    """Training steps before measuring, so the model is densified as in a real run."""
    pairs: int = 40
    """Measured (on, off) step pairs."""
    eager: bool = False
    """Eager rasterizer kernels even when the preset compiles them (training uses the preset's choice)."""
    json: Path | None = None
    """Where to write the results; default benchmarks/results/overhead.json (overhead_eager.json with --eager)."""


def measure(args: Args) -> dict:
    base = preset_config(args.preset)  # its data options (--max-image-size) with the scene swapped in
    config = dataclasses.replace(base, data=dataclasses.replace(base.data, data=args.data), progress=False)
    set_compile(config.compile_kernels and not args.eager)
    malloc_fixed = keep_freed_memory()  # as `splatu train` does before its first step
    scene = load_scene(config.data)
    state = trainer.fresh_state(config, scene)
    images = training_step.TrainImages(scene.train)
    for _ in range(args.warmup):
        training_step.train_step(state, config, images)
        state.step += 1

    frozen = dataclasses.replace(config.densify, warmup_length=10**9)  # no refinement while measuring
    state.density = DensityController(frozen, state.scene_extent, state.generator)
    full_res = dataclasses.replace(config, resolution_levels=0, densify=frozen)
    variants = {"on": dataclasses.replace(full_res, uncertainty=dataclasses.replace(config.uncertainty, off=False)),
                "off": dataclasses.replace(full_res, uncertainty=dataclasses.replace(config.uncertainty, off=True))}
    times: dict[str, list[float]] = {"on": [], "off": []}
    for i in range(args.pairs):
        order = ("on", "off") if i % 2 == 0 else ("off", "on")  # alternate who goes first
        step = state.step
        for name in order:
            state.step = step  # same camera, same schedule for both members of the pair
            started = time.perf_counter()
            training_step.train_step(state, variants[name], images)
            times[name].append(time.perf_counter() - started)
        state.step = step + 1
    median = {name: statistics.median(values) for name, values in times.items()}
    loss_times, update_times = isolated_extra_seconds(state, variants["on"], images, repeats=5 * args.pairs)
    loss_seconds, update_seconds = statistics.median(loss_times), statistics.median(update_times)
    return {
        "scene": scene.name, "preset": args.preset, "gaussians": len(state.model), "warmup_steps": args.warmup,
        "pairs": args.pairs, "threads": torch.get_num_threads(), "compiled_kernels": kernels_compiled(),
        "malloc": "splatu.allocator" if malloc_fixed else "glibc defaults",
        "median_step_seconds_on": median["on"], "median_step_seconds_off": median["off"],
        "ratio_on_over_off": median["on"] / median["off"],
        **pair_ratio_quartiles(times["on"], times["off"]),
        "median_uncertainty_loss_seconds": loss_seconds,
        "median_u_sh_update_seconds": update_seconds,
        "isolated_ratio": (median["off"] + loss_seconds + update_seconds) / median["off"],
        "step_seconds_on": times["on"], "step_seconds_off": times["off"],
    }


def pair_ratio_quartiles(on: list[float], off: list[float]) -> dict[str, float]:
    """The median and quartiles of on ÷ off within each pair (same camera, same state, back to back): a spread the
    ratio of the two medians hides."""
    ratios = [a / b for a, b in zip(on, off, strict=True)]
    if len(ratios) < 2:
        return {"pair_ratio_median": ratios[0], "pair_ratio_q1": ratios[0], "pair_ratio_q3": ratios[0]}
    q1, q2, q3 = statistics.quantiles(ratios, n=4)
    return {"pair_ratio_median": q2, "pair_ratio_q1": q1, "pair_ratio_q3": q3}


def isolated_extra_seconds(state: training_step.TrainState, config: TrainConfig, images: training_step.TrainImages,
                           repeats: int) -> tuple[list[float], list[float]]:
    """Times of the work only a step with the loss on does, on one render: the loss's forward + backward, and the
    update of `u_sh` (its Adam step and the finiteness check of its gradient, which the loss off skips).

    Step times on a shared machine are noisy; this cost is small and stable, so (off + it) / off
    estimates the overhead independently of the interleaved ratio.
    """
    camera, _ = images.get(0, 0)
    with torch.no_grad():
        raster = state.model.render(camera, config.model.sh_degree, torch.zeros(3)).raster
    u_sh_adam = state.optimizers.optimizers["u_sh"]
    loss_seconds, update_seconds = [], []
    for _ in range(repeats):
        state.optimizers.zero_grad()  # each backward allocates its gradient, as after a step's zero_grad
        started = time.perf_counter()
        uncertainty_loss(state.model, camera.center(), raster, config.uncertainty,
                         state.uncertainty_generators).backward()
        between = time.perf_counter()
        bool(torch.isfinite(state.model.u_sh.grad.sum()))
        u_sh_adam.step()
        update_seconds.append(time.perf_counter() - between)
        loss_seconds.append(between - started)
    state.optimizers.zero_grad()
    return loss_seconds, update_seconds


def main(args: Args) -> None:
    result = {**measure(args), "measured_on": measured_on()}
    path = args.json or RESULTS / ("overhead.json" if result["compiled_kernels"] else "overhead_eager.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    print(f"{'scene':<10}{'gaussians':>10}{'pairs':>7}{'median on (s)':>15}{'median off (s)':>16}{'on/off':>8}"
          f"{'pairs: median (q1-q3)':>24}{'L_u fwd+bwd (ms)':>18}{'u_sh update (ms)':>18}{'(off+both)/off':>16}")
    spread = f"{result['pair_ratio_median']:.3f} ({result['pair_ratio_q1']:.3f}-{result['pair_ratio_q3']:.3f})"
    print(f"{result['scene']:<10}{result['gaussians']:>10}{result['pairs']:>7}{result['median_step_seconds_on']:>15.4f}"
          f"{result['median_step_seconds_off']:>16.4f}{result['ratio_on_over_off']:>8.3f}{spread:>24}"
          f"{1000 * result['median_uncertainty_loss_seconds']:>18.2f}"
          f"{1000 * result['median_u_sh_update_seconds']:>18.2f}{result['isolated_ratio']:>16.4f}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main(tyro.cli(Args))
