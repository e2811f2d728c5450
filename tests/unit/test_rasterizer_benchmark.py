"""The dense per-tile baseline of benchmarks/rasterizer.py renders what splatu's rasterizer renders, so the speed
ratio compares the same work, and it counts the candidate pairs it evaluates."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from splatu.rasterizer import rasterize
from splatu.rasterizer.projection import project_gaussians
from tests.benchmark_scripts import BENCHMARKS, benchmark_script
from tests.reference_rasterizer import reference_rasterize as brute_force


@pytest.fixture(scope="module")
def rasterizer_benchmark():
    yield from benchmark_script("rasterizer")


def test_the_baseline_renders_our_image_and_counts_whole_tiles_of_candidates(rasterizer_benchmark) -> None:
    case = rasterizer_benchmark.Case("small", 400, 40, 36, seed=3)  # neither side a multiple of 16
    scene = rasterizer_benchmark.make_scene(case)
    ours = rasterize(*scene, case.width, case.height, log_scales=True)
    image, alpha, candidates = rasterizer_benchmark.reference_rasterize(*scene, case.width, case.height)
    assert image.shape == ours.image.shape and alpha.shape == ours.alpha.shape
    # Identical rules, except that the baseline bins by 3σ boxes, which an opaque Gaussian's α ≥ 1/255 ellipse
    # (up to 3.33σ) can overstep by a pixel of α near 1/255; on this scene they agree to float32 rounding.
    assert float((image - ours.image).abs().mean()) < 1e-5
    assert float((alpha - ours.alpha).abs().max()) < 0.01
    assert candidates % (rasterizer_benchmark.TILE ** 2) == 0
    assert candidates >= ours.num_contributing_pairs > 0


@pytest.mark.parametrize("opacity", [None, 0.99])  # 0.99: α ≥ 1/255 reaches 3.3σ, past the baseline's 3σ boxes
def test_the_pair_count_is_the_brute_force_reference_s_not_our_rasterizer_s(rasterizer_benchmark, opacity) -> None:
    case = rasterizer_benchmark.Case("small", 400, 40, 36, seed=3)
    means, quats, log_scales, opacities, *camera = rasterizer_benchmark.make_scene(case)
    if opacity is not None:
        opacities = torch.full_like(opacities, opacity)
    scene = (means, quats, log_scales, opacities, *camera)
    expected = brute_force(*(t.double() for t in scene), case.width, case.height, log_scales=True)
    assert rasterizer_benchmark.count_contributing_pairs(*scene, case.width, case.height) \
        == expected.num_contributing_pairs > 0


@pytest.mark.parametrize("case_index", [0, 1])
def test_the_scenes_spread_radii_and_opacities_as_the_docstring_says(rasterizer_benchmark, case_index) -> None:
    case = rasterizer_benchmark.CASES[case_index]
    means, quats, log_scales, opacities, _, world_to_camera, K = rasterizer_benchmark.make_scene(case)
    proj = project_gaussians(means, quats, log_scales, world_to_camera, K, case.width, case.height, 0.01, 1e10, True)
    radii = proj.radii[proj.visible].float()
    low, p5, median, p95, high = torch.quantile(radii, torch.tensor([0.0, 0.05, 0.5, 0.95, 1.0])).tolist()
    assert (low, p5, median) == (2, 3, 8) and 31 <= p95 <= 32 and high == 50
    assert 0.05 < float((radii > 30).float().mean()) < 0.07
    assert 0.005 <= float(opacities.min()) < 0.01 and 0.99 < float(opacities.max()) <= 0.995


def test_quick_run_writes_the_issue_s_json_schema_and_a_table(tmp_path) -> None:
    output = tmp_path / "quick.json"
    run = subprocess.run([sys.executable, str(BENCHMARKS / "rasterizer.py"), "--quick", "--json", str(output)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    written = json.loads(output.read_text())
    [case] = written["cases"]
    for key in ("name", "gaussians", "width", "height", "ms_forward", "ms_backward", "contributing_pairs",
                "ns_per_pair", "speedup_vs_reference", "peak_rss_mb"):
        assert key in case, key
    total = case["ms_forward"] + case["ms_backward"]
    assert case["contributing_pairs"] > 0 and case["speedup_vs_reference"] > 0
    assert case["ours_contributing_pairs"] == case["contributing_pairs"]  # counted apart, and they agree
    assert case["ns_per_pair"] == pytest.approx(1e6 * total / case["contributing_pairs"], rel=0.01)
    assert written["measured_on"]["torch"] == torch.__version__
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=BENCHMARKS.parent, capture_output=True,
                          text=True)
    if head.returncode == 0:  # a figure is quoted with its commit: the file holds it
        assert written["measured_on"]["revision"].split()[0] == head.stdout.strip()
    assert case["name"] in run.stdout and "ns_per_pair" in run.stdout  # the same figures as a table


def test_peak_rss_is_the_worker_s_own_not_its_parent_s_peak() -> None:
    ballast = bytearray(1 << 30)  # 1 GB touched in this process, then freed: its peak stays above 1 GB (the suite's
    ballast[::4096] = b"\x01" * len(range(0, 1 << 30, 4096))  # own peak rose to 3.1 GB with 2 GB here)
    del ballast
    code = f"import runpy; print(runpy.run_path({str(BENCHMARKS / 'rasterizer.py')!r})['peak_rss_mb']())"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert 10 < float(run.stdout) < 1000  # importing torch takes a few hundred MB
