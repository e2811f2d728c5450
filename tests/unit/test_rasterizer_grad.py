"""Gradients of `splatu.rasterizer.rasterize`: gradcheck in float64, and the 2D-mean gradients used for densification.

Scenes are tiny and kept away from the discontinuities (α clamp at 0.99, α ≥ 1/255 edge, T < 1e-4
stop, Jacobian clamp): opacities ≤ 0.8, at most four layers, centres inside the field of view.
The fixed seeds were checked to have no pixel within finite-difference reach of an α edge.
"""

from __future__ import annotations

import shutil
import sys
import warnings

import pytest
import torch
from torch._dynamo.utils import counters

from splatu.rasterizer import RasterInputError, kernels, rasterize
from splatu.rasterizer.composite import segments
from splatu.rasterizer.footprint import block_entries
from splatu.rasterizer.function import CompositeFunction
from splatu.rasterizer.kernels import ALPHA_MIN, kernels_compiled, set_compile
from splatu.rasterizer.projection import project_gaussians

WIDTH, HEIGHT = 12, 10
F64 = torch.float64


def tiny_scene(seed: int, n: int = 4) -> dict[str, torch.Tensor]:
    """n Gaussians 2–4 px wide in front of an axis-aligned camera; leaves require grad."""
    g = torch.Generator().manual_seed(seed)
    fx = 14.0
    z = 3.0 + 2.0 * torch.rand(n, generator=g, dtype=F64)
    x = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 0.6 * WIDTH / fx * z
    y = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 0.6 * HEIGHT / fx * z
    std_px = 1.0 + 1.5 * torch.rand(n, 3, generator=g, dtype=F64)
    scene = {
        "means": torch.stack([x, y, z], dim=-1),
        "quats": torch.randn(n, 4, generator=g, dtype=F64),
        "scales": std_px * z[:, None] / fx,
        "opacities": 0.3 + 0.5 * torch.rand(n, generator=g, dtype=F64),
        "features": torch.rand(n, 3, generator=g, dtype=F64),
        "background": torch.rand(3, generator=g, dtype=F64),
    }
    return {k: v.requires_grad_(True) for k, v in scene.items()}


def camera() -> tuple[torch.Tensor, torch.Tensor]:
    K = torch.tensor([[14.0, 0.0, WIDTH / 2 + 0.1], [0.0, 14.5, HEIGHT / 2 - 0.2], [0.0, 0.0, 1.0]], dtype=F64)
    w2c = torch.eye(4, dtype=F64)
    w2c[:3, :3] = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.05, 0.02], [0.05, 0.0, -0.03], [-0.02, 0.03, 0.0]]))
    return w2c.to(F64), K


def render_all(means, quats, scales, opacities, features, background, log_scales=False, **options):
    w2c, K = camera()
    out = rasterize(means, quats, scales, opacities, features, w2c, K, WIDTH, HEIGHT,
                    background=background, log_scales=log_scales, **options)
    return out.image, out.alpha, out.depth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradcheck_all_inputs_linear_scales(seed):
    s = tiny_scene(seed)
    assert torch.autograd.gradcheck(
        render_all, (s["means"], s["quats"], s["scales"], s["opacities"], s["features"], s["background"]),
        fast_mode=True, atol=1e-6, rtol=1e-4,
    )


@pytest.mark.parametrize("seed", [7, 8])
def test_gradcheck_antialiased(seed):
    """Mip-Splatting's 2D filter: the opacity factor sqrt(det Σ₂ / det(Σ₂ + 0.1 I)) adds a gradient path from the
    opacities' scale back to the means, rotations and scales."""
    s = tiny_scene(seed)
    assert torch.autograd.gradcheck(
        lambda *inputs: render_all(*inputs, blur=0.1, antialiased=True),
        (s["means"], s["quats"], s["scales"], s["opacities"], s["features"], s["background"]),
        fast_mode=True, atol=1e-6, rtol=1e-4,
    )


@pytest.mark.parametrize("blur", [0.0, 1e-4, -0.1, float("nan"), float("inf")])
def test_a_blur_that_is_too_small_or_not_finite_raises_a_clear_error(blur):
    s = tiny_scene(0)
    with pytest.raises(RasterInputError, match="blur"):
        render_all(*s.values(), blur=blur)


@pytest.mark.parametrize("seed", [3, 4])
def test_gradcheck_log_scales(seed):
    s = tiny_scene(seed)
    log_scales = s["scales"].detach().log().requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda m, q, ls, o, f, bg: render_all(m, q, ls, o, f, bg, log_scales=True),
        (s["means"], s["quats"], log_scales, s["opacities"], s["features"], s["background"]),
        fast_mode=True, atol=1e-6, rtol=1e-4,
    )


@pytest.mark.slow
def test_gradcheck_full_jacobian_one_scene():
    """The exact (not randomly projected) Jacobian on one scene, for every input (~10 s: marked slow)."""
    s = tiny_scene(5, n=3)
    assert torch.autograd.gradcheck(
        render_all, (s["means"], s["quats"], s["scales"], s["opacities"], s["features"], s["background"]),
        atol=1e-6, rtol=1e-4,
    )


def test_gradcheck_composite_function_directly():
    """The analytic backward against finite differences in its own inputs, including the 2D means."""
    s = tiny_scene(6, n=4)
    w2c, K = camera()
    with torch.no_grad():
        proj = project_gaussians(s["means"], s["quats"], s["scales"], w2c, K, WIDTH, HEIGHT, 0.01, 1e10, False)
        entries = block_entries(proj.means2d, proj.cov2d, proj.det, s["opacities"], proj.depths, proj.visible,
                                WIDTH, HEIGHT, block_width=8)
    n = s["means"].shape[0]
    assert proj.swapped[proj.visible].any() and not proj.swapped[proj.visible].all()  # both sheared forms
    inputs = [proj.means2d, proj.log_conics, s["opacities"], s["features"], proj.depths, s["background"]]
    inputs = [x.detach().clone().requires_grad_(True) for x in inputs]
    absgrad = torch.zeros(n, 2, dtype=F64)

    def composite(means2d, log_conics, opacities, features, depths, background):
        features_ext = torch.cat([features, depths[:, None], torch.ones(n, 1, dtype=F64)], dim=1)
        image, alpha, depth_num, *_ = CompositeFunction.apply(
            means2d, log_conics, opacities, features_ext, background, proj.swapped, entries, WIDTH, HEIGHT,
            absgrad, 1 << 20, None,
        )
        return image, alpha, depth_num

    assert torch.autograd.gradcheck(composite, tuple(inputs), atol=1e-6, rtol=1e-4)


def test_means2d_grad_and_absgrad_match_per_pixel_autograd():
    """Summing per-pixel backward passes reproduces means2d.grad (signed) and means2d_absgrad (|·| per pixel)."""
    s = tiny_scene(7, n=4)
    weights = torch.randn(HEIGHT, WIDTH, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    params = [s[k].detach() for k in ("means", "quats", "scales", "opacities", "features", "background")]

    def run(pixel: tuple[int, int] | None):
        leaves = [p.clone().requires_grad_(True) for p in params]
        w2c, K = camera()
        out = rasterize(*leaves[:5], w2c, K, WIDTH, HEIGHT, background=leaves[5])
        out.means2d.retain_grad()
        per_pixel = (out.image * weights).sum(-1)
        (per_pixel.sum() if pixel is None else per_pixel[pixel]).backward()
        return out.means2d.grad.clone(), out.means2d_absgrad.clone()

    full_grad, full_abs = run(None)
    signed_sum = torch.zeros_like(full_grad)
    abs_sum = torch.zeros_like(full_abs)
    for py in range(HEIGHT):
        for px in range(WIDTH):
            grad, absgrad = run((py, px))
            torch.testing.assert_close(absgrad, grad.abs(), atol=1e-12, rtol=1e-10)  # one pixel: equal
            signed_sum += grad
            abs_sum += grad.abs()
    torch.testing.assert_close(full_grad, signed_sum, atol=1e-10, rtol=1e-8)
    torch.testing.assert_close(full_abs, abs_sum, atol=1e-10, rtol=1e-8)
    assert (full_abs >= full_grad.abs() - 1e-12).all()
    assert (full_abs > full_grad.abs() + 1e-6).any(), "some gradients should cancel across pixels"


def test_chunked_compositing_matches_single_chunk(monkeypatch):
    """Splitting the entry list into many chunks changes nothing, forward or backward."""
    s = tiny_scene(8, n=30)
    raster_module = sys.modules["splatu.rasterizer.rasterize"]

    def grads_with(max_elements: int):
        monkeypatch.setattr(raster_module, "MAX_CHUNK_ELEMENTS", max_elements)
        leaves = {k: v.detach().clone().requires_grad_(True) for k, v in s.items()}
        out = render_all(*leaves.values())
        sum(o.sum() for o in out).backward()
        return [o.detach() for o in out] + [v.grad for v in leaves.values()]

    for a, b in zip(grads_with(1 << 22), grads_with(16), strict=True):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=1e-10)


def test_no_grad_path_matches_grad_path():
    s = tiny_scene(9, n=20)
    w2c, K = camera()
    args = [s[k] for k in ("means", "quats", "scales", "opacities", "features")]
    with_grad = rasterize(*args, w2c, K, WIDTH, HEIGHT, background=s["background"])
    with torch.no_grad():
        without = rasterize(*args, w2c, K, WIDTH, HEIGHT, background=s["background"])
    assert not without.image.requires_grad
    for name in ("image", "alpha", "depth", "contrib_sum", "contrib_max"):
        torch.testing.assert_close(getattr(with_grad, name).detach(), getattr(without, name), atol=0, rtol=0)
    assert with_grad.num_contributing_pairs == without.num_contributing_pairs > 0


def test_float32_gradients_match_float64():
    s = tiny_scene(10, n=20)
    grads = {}
    for dtype in (torch.float32, F64):
        leaves = {k: v.detach().to(dtype).requires_grad_(True) for k, v in s.items()}
        w2c, K = camera()
        out = rasterize(*list(leaves.values())[:5], w2c.to(dtype), K.to(dtype), WIDTH, HEIGHT,
                        background=leaves["background"])
        assert out.image.dtype == dtype
        (out.image.sum() + out.depth.sum()).backward()
        grads[dtype] = {k: v.grad for k, v in leaves.items()}
    for name, g64 in grads[F64].items():
        torch.testing.assert_close(grads[torch.float32][name].double(), g64, atol=2e-3, rtol=2e-3)


def test_contribution_outputs_carry_no_grad_and_alpha_threshold_holds():
    s = tiny_scene(11, n=10)
    w2c, K = camera()
    out = rasterize(*[s[k] for k in ("means", "quats", "scales", "opacities", "features")], w2c, K, WIDTH, HEIGHT)
    assert not out.contrib_sum.requires_grad and not out.contrib_max.requires_grad
    assert out.means2d.requires_grad and not out.depths.requires_grad
    assert torch.all(out.means2d_absgrad == 0)
    hit = out.contrib_max > 0
    assert hit.any()
    assert torch.all(out.contrib_max[hit] >= ALPHA_MIN * 1e-4)
    assert torch.all(out.contrib_sum >= out.contrib_max)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.int64])
def test_a_dtype_other_than_float32_or_float64_raises_a_clear_error(dtype):
    s = {k: v.detach() for k, v in tiny_scene(12, n=3).items()}
    w2c, K = camera()
    with pytest.raises(RasterInputError, match=f"`means` of dtype {dtype}"):
        rasterize(s["means"].to(dtype), s["quats"], s["scales"], s["opacities"], s["features"], w2c, K, WIDTH,
                  HEIGHT)


def test_mismatched_sizes_raise_a_clear_error():
    s = tiny_scene(12, n=3)
    w2c, K = camera()
    with pytest.raises(RasterInputError, match="`opacities` has shape \\(2,\\)"):
        rasterize(s["means"], s["quats"], s["scales"], s["opacities"][:2], s["features"], w2c, K, WIDTH, HEIGHT)
    with pytest.raises(RasterInputError, match="`background` has shape \\(2,\\)"):
        rasterize(s["means"], s["quats"], s["scales"], s["opacities"], s["features"], w2c, K, WIDTH, HEIGHT,
                  background=s["background"][:2])


@pytest.mark.skipif(not any(shutil.which(c) for c in ("c++", "g++", "clang++")),
                    reason="torch.compile's CPU backend needs a C++ compiler (without one splatu runs eager)")
def test_compiled_projection_takes_parameters_of_any_length_without_recompiling():
    """A densifying model hands the projection nn.Parameters whose length changes every refinement, and the
    resolution schedule changes the image size. torch.compile makes a parameter's shape static by default, so each
    new length recompiled (~10 s each) until dynamo's limit of 8 turned compiling off for good; one graph must serve
    every length and size, and agree with eager torch."""
    torch._dynamo.reset()
    counters.clear()
    w2c, K = camera()
    for n, scale in ((5, 1.0), (6, 0.5), (9, 2.0)):
        scene = tiny_scene(20 + n, n=n)
        width, height = round(WIDTH * scale), round(HEIGHT * scale)
        results = []
        for compiled in (False, True):
            previous = set_compile(compiled)
            try:
                means, quats = (torch.nn.Parameter(scene[k].detach().clone()) for k in ("means", "quats"))
                log_scales = torch.nn.Parameter(scene["scales"].detach().log())
                with torch._dynamo.config.patch(error_on_recompile=True), warnings.catch_warnings():
                    warnings.filterwarnings("error", message="torch.compile of rasterizer kernel")
                    proj = project_gaussians(means, quats, log_scales, w2c, K * scale, width, height, 0.01, 100.0,
                                             log_scales=True, blur=0.3, antialiased=True)
                outputs = (proj.means2d, proj.log_conics, proj.depths, proj.opacity_scale)
                sum(o.sum() for o in outputs).backward()
                results.append([o.detach() for o in outputs]
                               + [proj.radii, means.grad, quats.grad, log_scales.grad])
            finally:
                set_compile(previous)
        for eager, compiled in zip(*results, strict=True):
            torch.testing.assert_close(compiled, eager, atol=1e-12, rtol=1e-10)
    assert counters["stats"]["unique_graphs"] == 1


def test_compiled_kernels_stay_compiled_across_dtypes_and_channel_widths(monkeypatch):
    """One process renders float32 (training) and float64, with several channel widths (colour, uncertainty heads,
    the baselines' extra features). The backward kernels compile one graph per width and dtype: ten here, past
    dynamo's limit of 8 per function, beyond which it ran the kernel eager and said so only in a log line. dynamo's
    eager backend stands in for inductor: the limit is dynamo's, and inductor's cold compile of every kernel's ten
    graphs took 159-355 s (test_compiled_kernels_match_eager compiles one with inductor)."""
    real_compile = torch.compile
    monkeypatch.setattr(torch, "compile", lambda fn, **options: real_compile(fn, backend="eager", **options))
    monkeypatch.setattr(kernels, "_compiled", {})
    torch._dynamo.reset()
    counters.clear()
    previous = set_compile(True)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("error", message="torch.compile of rasterizer kernel")  # a fallback must be said
            warnings.filterwarnings("error", message="rasterizer kernel .* needed more than")
            for channels in (1, 2, 3, 4, 5):
                for dtype in (torch.float32, F64):
                    scene = tiny_scene(30 + channels, n=6)
                    scene["features"] = scene["features"].detach()[:, :1].repeat(1, channels)
                    scene["background"] = scene["background"].detach()[:1].repeat(channels)
                    leaves = [v.detach().to(dtype).requires_grad_(True) for v in scene.values()]
                    sum(o.sum() for o in render_all(*leaves)).backward()
        assert kernels_compiled()
        graphs = counters["stats"]["unique_graphs"]
    finally:
        set_compile(previous)
        torch._dynamo.reset()
    assert graphs >= 2 * 10  # the two backward kernels compiled a graph per width and dtype, past dynamo's 8
    assert not [reason for reason in counters["unimplemented"] if "recompile limit" in reason]


@pytest.mark.slow
def test_compiled_kernels_match_eager():
    """torch.compile'd kernels (≈1 min to compile cold) give the eager results and gradients."""
    s = tiny_scene(13, n=40)
    results = []
    for compiled in (False, True):
        previous = set_compile(compiled)
        try:
            leaves = {k: v.detach().clone().requires_grad_(True) for k, v in s.items()}
            out = render_all(*leaves.values())
            sum(o.sum() for o in out).backward()
            results.append([o.detach() for o in out] + [v.grad for v in leaves.values()])
            assert kernels_compiled() == compiled  # else eager is compared with itself (a failed compile, dynamo off)
        finally:
            set_compile(previous)
    for eager, compiled in zip(*results, strict=True):
        torch.testing.assert_close(compiled, eager, atol=1e-12, rtol=1e-10)


def test_a_kernel_past_its_recompile_limit_runs_eager_for_those_dtypes_saying_so_once(monkeypatch):
    """A kernel past its limit warned, then turned every kernel eager until the next session's set_compile(True)
    (an ensemble's next member), which tried it again, hit the limit again and warned again. Now the version past
    its limit runs eager, exactly as with compiling off, and the other kernels stay compiled. dynamo's eager backend
    stands in for inductor: the limit is dynamo's, and nothing waits for a C++ compile."""
    real_compile = torch.compile
    monkeypatch.setattr(torch, "compile", lambda fn, **options: real_compile(fn, backend="eager", **options))
    monkeypatch.setattr(kernels, "RECOMPILE_LIMIT", 1)
    monkeypatch.setattr(kernels, "_compiled", {})
    torch._dynamo.reset()

    def gradients(channels: int, compile_kernels: bool) -> list[torch.Tensor]:
        set_compile(compile_kernels)  # as each session (run, ensemble member) of a process does
        scene = tiny_scene(40 + channels, n=6)
        scene["features"] = scene["features"].detach()[:, :1].repeat(1, channels)
        scene["background"] = scene["background"].detach()[:1].repeat(channels)
        leaves = [v.detach().requires_grad_(True) for v in scene.values()]
        outputs = render_all(*leaves)
        sum(o.sum() for o in outputs).backward()
        return [o.detach() for o in outputs] + [leaf.grad for leaf in leaves]

    previous = set_compile(True)
    try:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            for channels in (1, 2, 3):  # the backward kernels need a graph per channel count
                compiled = gradients(channels, True)
                assert kernels_compiled()
                for mine, eager in zip(compiled, gradients(channels, False), strict=True):
                    assert torch.equal(mine, eager)
    finally:
        set_compile(previous)
        torch._dynamo.reset()
    told = sorted(str(w.message).split(" needed")[0] for w in said if "rasterizer kernel" in str(w.message))
    assert told == ["rasterizer kernel entry_gradients", "rasterizer kernel upstream_per_weight"]


def test_per_pixel_kernels_compile_with_inductors_tiling_heuristic_off(monkeypatch):
    """upstream_per_weight and entry_gradients, written pixel by pixel of the block, gather more values per loop
    than inductor's CPU tiling heuristic vectorises: with it on, upstream_per_weight compiled to scalar code and took
    1.7x the time of its (B, Q) form. The other kernels keep inductor's defaults. dynamo's eager backend stands in
    for inductor (the options are only recorded)."""
    real_compile = torch.compile
    options_of: dict[str, dict | None] = {}

    def recording(fn, **options):
        options_of[fn.__name__] = options.pop("options", None)
        return real_compile(fn, backend="eager", **options)

    monkeypatch.setattr(torch, "compile", recording)
    monkeypatch.setattr(kernels, "_compiled", {})
    torch._dynamo.reset()
    previous = set_compile(True)
    try:
        leaves = [v.detach().requires_grad_(True) for v in tiny_scene(50, n=6).values()]
        sum(o.sum() for o in render_all(*leaves)).backward()
    finally:
        set_compile(previous)
        torch._dynamo.reset()
    heuristic_off = {"cpp.enable_tiling_heuristics": False}
    assert {name for name, options in options_of.items() if options == heuristic_off} == {
        "upstream_per_weight", "entry_gradients"}
    assert {"entry_geometry", "alpha_and_log_one_minus", "blend"} <= {
        name for name, options in options_of.items() if options is None}


def test_segments_give_each_entry_its_block_run():
    """The blend and entry_gradients gather one per-run offset per pair through `segment` (three and two gathers
    per pair before: the running sums at the run's first or last entry, and the carried log T or later chunks' sums)."""
    block = torch.tensor([3, 3, 5, 8, 8, 8, 9])
    seg = segments(block)
    assert seg.segment.tolist() == [0, 0, 1, 2, 2, 2, 3]
    assert seg.blocks.tolist() == [3, 5, 8, 9]
    assert seg.block_first.tolist() == [0, 2, 3, 6]
    assert seg.block_last.tolist() == [1, 2, 5, 6]
