"""Step time of a fresh training process with glibc malloc's default thresholds against splatu's fixed ones.

    .venv/bin/python benchmarks/allocator.py [--steps 600] [--measured 150]

Each configuration (malloc defaults or `splatu.allocator.keep_freed_memory`, uncertainty loss on or
off) trains the `fast` preset on the poster stand-in from scratch in its own subprocess, as the first
training of a process does, and reports the median step time, the minor page faults and the kernel
(system) time per step over the last `--measured` steps (full resolution, densifying). The four run
one after another in one invocation, so compare the ratios. Writes benchmarks/results/allocator.json.
"""

from __future__ import annotations

import dataclasses
import json
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import tyro

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


@dataclass
class Args:
    steps: int = 600
    """Training steps per configuration (the `fast` preset reaches full resolution at step 400)."""
    measured: int = 150
    """The last steps, whose medians are reported."""
    worker: str = ""
    """Internal: run one configuration, "<malloc>,<loss>", and print its JSON."""


def worker(malloc: str, loss: str, steps: int, measured: int) -> dict:
    """Train in this process and measure the last `measured` steps."""
    from splatu import trainer, training_step
    from splatu.allocator import keep_freed_memory
    from splatu.data.resolve import load_scene
    from splatu.rasterizer.kernels import set_compile
    from splatu.train_config import preset_config

    tuned = keep_freed_memory() if malloc == "fixed" else False
    base = preset_config("fast")
    config = dataclasses.replace(base, data=dataclasses.replace(base.data, data="poster"), progress=False)
    config = dataclasses.replace(config, uncertainty=dataclasses.replace(config.uncertainty, off=loss == "off"))
    set_compile(config.compile_kernels)
    scene = load_scene(config.data)
    state = trainer.fresh_state(config, scene)
    images = training_step.TrainImages(scene.train)
    seconds, faults, kernel = [], [], []
    for _ in range(steps):
        before, started = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        training_step.train_step(state, config, images)
        state.step += 1
        after = resource.getrusage(resource.RUSAGE_SELF)
        seconds.append(time.perf_counter() - started)
        faults.append(after.ru_minflt - before.ru_minflt)
        kernel.append(after.ru_stime - before.ru_stime)
    tail = slice(steps - measured, steps)
    return {"malloc": malloc, "loss": loss, "thresholds_fixed": tuned, "gaussians": len(state.model),
            "median_step_ms": 1e3 * statistics.median(seconds[tail]),
            "mean_page_faults_per_step": statistics.mean(faults[tail]),
            "mean_kernel_ms_per_step": 1e3 * statistics.mean(kernel[tail])}


def main(args: Args) -> None:
    if args.worker:
        malloc, loss = args.worker.split(",")
        print(json.dumps(worker(malloc, loss, args.steps, args.measured)))
        return
    rows = []
    for malloc in ("defaults", "fixed"):
        for loss in ("on", "off"):
            done = subprocess.run([sys.executable, __file__, "--worker", f"{malloc},{loss}", "--steps", str(args.steps),
                                   "--measured", str(args.measured)], capture_output=True, text=True, check=True)
            rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]), flush=True)
    by = {(r["malloc"], r["loss"]): r for r in rows}
    ratios = {loss: by["defaults", loss]["median_step_ms"] / by["fixed", loss]["median_step_ms"]
              for loss in ("on", "off")}
    print(f"\n{'malloc':<10}{'loss':<6}{'ms/step':>10}{'faults/step':>14}{'kernel ms/step':>16}")
    for r in rows:
        print(f"{r['malloc']:<10}{r['loss']:<6}{r['median_step_ms']:>10.1f}{r['mean_page_faults_per_step']:>14.0f}"
              f"{r['mean_kernel_ms_per_step']:>16.1f}")
    print(f"defaults ÷ fixed, median step time: loss on {ratios['on']:.3f}, loss off {ratios['off']:.3f}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "allocator.json").write_text(json.dumps({"steps": args.steps, "measured": args.measured, "rows": rows,
                                                        "defaults_over_fixed": ratios}, indent=2) + "\n")


if __name__ == "__main__":
    main(tyro.cli(Args))
