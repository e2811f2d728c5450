"""benchmarks/overhead.py times the steps `splatu train` takes, under the same process settings."""

from __future__ import annotations

import statistics

import pytest
import torch

from splatu import trainer, training_step
from tests.benchmark_scripts import benchmark_script
from tests.unit.test_trainer import tiny_config, tiny_scene


@pytest.fixture(scope="module")
def overhead_benchmark():
    yield from benchmark_script("overhead")


class _Stop(Exception):
    """Ends `measure` once it has set the process up, before it loads or trains anything."""


def test_measure_fixes_malloc_s_thresholds_before_any_step(overhead_benchmark, monkeypatch) -> None:
    # without them the full-resolution measured steps page-fault (~22,000 faults each) where training does not
    calls: list[str] = []
    monkeypatch.setattr(overhead_benchmark, "keep_freed_memory", lambda: calls.append("malloc") or True)

    def load_scene(_data: object) -> None:
        calls.append("load")
        raise _Stop

    monkeypatch.setattr(overhead_benchmark, "load_scene", load_scene)
    monkeypatch.setattr(overhead_benchmark, "set_compile", lambda _on: None)
    with pytest.raises(_Stop):
        overhead_benchmark.measure(overhead_benchmark.Args())
    assert calls == ["malloc", "load"]


def test_the_isolated_extra_work_is_the_loss_and_the_u_sh_update_only(overhead_benchmark, tmp_path) -> None:
    # the loss off skips both: timing the loss alone left the Adam step of u_sh out of (off + extra) / off
    scene = tiny_scene(n_train=1)
    config = tiny_config(tmp_path, resolution_levels=0)
    state = trainer.fresh_state(config, scene)
    before = {name: getattr(state.model, name).detach().clone() for name in state.model.PARAM_NAMES}
    loss_times, update_times = overhead_benchmark.isolated_extra_seconds(
        state, config, training_step.TrainImages(scene.train), repeats=3)
    assert len(loss_times) == len(update_times) == 3 and min(update_times) > 0
    changed = {name for name, value in before.items() if not torch.equal(value, getattr(state.model, name))}
    assert changed == {"u_sh"}
    assert all(getattr(state.model, name).grad is None for name in state.model.PARAM_NAMES)


def test_the_pairs_own_ratios_are_reported_beside_the_ratio_of_medians(overhead_benchmark) -> None:
    # the ratio of medians read 1.012 where the pairs' own ratios had a median of 1.04 (quartiles 0.88-1.15)
    on, off = [1.0, 1.0, 1.0, 3.0, 3.0], [1.0, 2.0, 2.0, 2.0, 0.5]
    assert statistics.median(on) / statistics.median(off) == 0.5
    spread = overhead_benchmark.pair_ratio_quartiles(on, off)
    assert spread["pair_ratio_median"] == 1.0  # ratios 1, 0.5, 0.5, 1.5, 6
    assert spread["pair_ratio_q1"] == 0.5 and spread["pair_ratio_q3"] == 3.75
