"""benchmarks/overhead.py times the steps `splatu train` takes, under the same process settings."""

from __future__ import annotations

import pytest

from tests.benchmark_scripts import benchmark_script


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
