"""The dense elementwise math of the rasterizer, as pure functions: the compositor's per-entry work
on (B, Q) tensors, and the footprint's per-row spans.

Each function is one fusable stretch of elementwise work between the steps eager torch must do
itself (cumulative sums, sorts, scatter-adds into pixels or Gaussians). They run as plain torch, or,
after `set_compile(True)`, through `torch.compile`, which fuses each into one loop.

Compositor layout (row_block_spans instead takes 1-D per-row-record inputs): an entry q is one
Gaussian on one block of B pixels of a row; element [x, q] is that Gaussian at column x of the
block. Columns come first so that the running sums down each
pixel's list (along q) are contiguous: torch's CPU cumsum is much slower across a strided dim.
Per-entry inputs are (Q,), or for the conic (3, Q), rows A, S, Q, so that every load along q is contiguous;
`entry_geometry` forms them from the Gaussians' (N, ·) values.
With the conic in sheared form (A, S, Q) (see projection.py), σ = ½A·t² + ½Q·w², t = v − S·w, where (v, w) is
the pixel centre's offset from the mean, (dx, dy) or, for a `swapped` Gaussian, (dy, dx). Along a block only dx
changes, by x: per entry t = t0 + p·x and w = w0 + r·x, with t0 and w0 at its first pixel and (p, r) = (1, 0), or
(−S, 1) when swapped (`entry_geometry`). A pair is valid when σ ≥ 0 (3DGS's rule; in this form only a NaN
fails it), α ≥ 1/255 and the pixel is inside the image; valid pairs are exactly those with log(1 − α) < 0.

"Extended features" are the per-Gaussian features with two more channels, depth z and 1, so one
weighted sum yields the colour, Σ w·z and Σ w = alpha together.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import time
import warnings
from collections.abc import Callable

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
"""3DGS skips a Gaussian at a pixel where its α is below this."""

ALPHA_MAX = 0.99
"""3DGS clamps α here so a single Gaussian never makes a pixel fully opaque."""

LOG_T_MIN = math.log(1e-4)
"""3DGS stops a pixel before the Gaussian that would bring its transmittance below 1e-4."""


def entry_geometry(
    block: Tensor, gaussian: Tensor, means2d: Tensor, conic_planes: Tensor, swapped: Tensor, opacities: Tensor,
    blocks_per_row: int, block_width: int, width: int,
) -> tuple[Tensor, ...]:
    """Per entry (Q,) of Gaussian `gaussian` on block `block`: t0 and w0, t and w at the block's first pixel, their
    slopes p and r along it, the sheared conic (3, Q), the opacity, and the in-image pixels of the block (width − x0).
    One pass with the Gaussians' values gathered inside it: with separate eager gathers and integer divisions around
    an offsets kernel, forming the entries' views took 29–32 against 22–25 ms per render of the 20k benchmark case,
    and 96–100 against 70–83 ms on the 100k case (compiled, two processes each, a scratch timing).

    Offsets are clamped to ±sqrt(max)/4 (4.6e18 px in float32), so that A·t² and Q·w² stay finite where A or Q
    underflow to 0. A clamp changes no α unless the footprint's std along an axis is about 1e18 px or more; the
    gradients of such a footprint's entries (their S, Q and mean) do change, as the backward takes the clamped
    offsets and ignores the clamp.
    """
    dtype = means2d.dtype
    x0 = (block % blocks_per_row) * block_width
    row = torch.div(block, blocks_per_row, rounding_mode="floor")
    mean = means2d.index_select(0, gaussian)  # index_select and gather: eager, x[idx] is much slower on CPU
    conic = torch.gather(conic_planes, 1, gaussian.expand(3, -1))
    dx0, dy = x0.to(dtype) + 0.5 - mean[:, 0], row.to(dtype) + 0.5 - mean[:, 1]
    flipped, shear = swapped.index_select(0, gaussian), conic[1]
    limit = torch.finfo(dtype).max ** 0.5 / 4
    w0 = torch.where(flipped, dx0, dy)
    t0 = (torch.where(flipped, dy, dx0) - shear * w0).clamp(-limit, limit)
    return (t0, w0.clamp(-limit, limit), torch.where(flipped, -shear, 1.0), flipped.to(dtype), conic,
            opacities.index_select(0, gaussian), width - x0)


def _sheared_offsets(t0: Tensor, w0: Tensor, p: Tensor, r: Tensor, block_width: int) -> tuple[Tensor, Tensor]:
    """t and w at each pixel of each entry's block, (B, Q)."""
    x = torch.arange(block_width, dtype=t0.dtype, device=t0.device)[:, None]
    return t0 + p * x, w0 + r * x


def alpha_and_log_one_minus(
    t0: Tensor, w0: Tensor, p: Tensor, r: Tensor, sheared_conic: Tensor, opacity: Tensor, in_image_cols: Tensor,
    block_width: int,
) -> tuple[Tensor, Tensor]:
    """α before clamping, and log(1 − α) (float64 for the running sums) where the pair is valid, else 0.

    `log(1 − α)` rather than `log1p(−α)`: the kernel took half the time (26–28 against 52–53 ms per render of the 20k
    benchmark case, compiled, two processes each, a scratch timing), and for α ≥ 1/255 forming 1 − α rounds by at most
    half a unit of 1, about 6e-8 in float32, the rounding of 3DGS's own T·(1 − α); in float64, about 1e-16."""
    A, _, Q = sheared_conic.unbind(0)
    t, w = _sheared_offsets(t0, w0, p, r, block_width)
    sigma = 0.5 * (A * t * t + Q * w * w)
    alpha_raw = opacity * torch.exp(-sigma)
    alpha = alpha_raw.clamp(max=ALPHA_MAX)
    cols = torch.arange(block_width, device=t0.device)[:, None]
    valid = (sigma >= 0) & (alpha >= ALPHA_MIN) & (cols < in_image_cols)
    return alpha_raw, torch.where(valid, torch.log(1.0 - alpha), 0.0).to(torch.float64)


def blend(
    log_one_minus: Tensor, cumulative: Tensor, segment: Tensor, offset: Tensor, alpha_raw: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Transmittance of kept pairs (0 elsewhere), weight w = T·α (B, Q), and Σ_x w (float64, for the summed
    contributions), max_x w and the number of kept pairs per entry (counted here, fused, rather than by a pass over
    the chunk afterwards).

    `cumulative` is the inclusive running sum of `log_one_minus` along q, and `offset` (B, K) holds per pixel of each
    of the chunk's block runs (`segment` per entry) the log T that pixel carries from earlier chunks minus the
    exclusive running sum at the run's first entry: their sum, with the exclusive running sum, is log T before each
    pair. One gather per pair: gathering the running sums at the run's first entry and the carried log T apart, three
    per pair, took twice the time of the blend without them (a scratch timing). Kept = valid and T·(1 − α) ≥ 1e-4.
    The kept pairs are counted as T > 0, which is the same (a kept pair has T > 1e-4), from the stored T: counting
    `kept` itself made the compiled kernel recompute it from the two float64 sums and the gathers in its reduction
    loop, 9.6 against 5.7 ms per trained-model render (a scratch timing).
    """
    log_t = cumulative - log_one_minus + offset.index_select(1, segment)
    kept = (log_one_minus < 0) & (log_t + log_one_minus >= LOG_T_MIN)
    transmittance = torch.where(kept, torch.exp(log_t.to(alpha_raw.dtype)), 0.0)
    weight = transmittance * alpha_raw.clamp(max=ALPHA_MAX)
    return transmittance, weight, weight.sum(0, dtype=torch.float64), weight.amax(0), (transmittance > 0).sum(0)


def _pixel_by_pixel(
    body: Callable[..., tuple[list[Tensor], list[Tensor]]], dtype: torch.dtype, *per_pixel: Tensor,
) -> tuple[list[Tensor], list[Tensor]]:
    """Run `body(x, *rows)` over the block's pixels x: it returns the pixel's outputs and its terms of sums over the
    block's pixels, and this returns the outputs as (..., B, Q) and the sums as (..., Q). `per_pixel` tensors have
    the pixel at dim -2; `body` indexes them along their last dim only.

    Compiled, the B pixels are unrolled, each a row along q, and the sums added in order (as inductor sums over B):
    inductor then makes one loop along q for every output of the kernel (see PER_PIXEL_KERNELS). Eager, `body` runs
    once on the whole tensors, with x a (B, 1) column of `dtype` (unrolled, an eager render took 1.4x the time), and
    the sums are still added pixel after pixel: torch's `sum` orders its additions by size, so the two differed in the
    last bit, and a kernel that dynamo leaves eager (past its recompile limit) must give what compiling off gives."""
    if not torch.compiler.is_compiling():
        x = torch.arange(per_pixel[0].shape[-2], dtype=dtype, device=per_pixel[0].device)[:, None]
        outputs, terms = body(x, *per_pixel)
        return outputs, [functools.reduce(torch.add, term.unbind(-2)) for term in terms]
    rows, sums = [], []
    for x in range(per_pixel[0].shape[-2]):
        outputs, terms = body(x, *(tensor.select(-2, x) for tensor in per_pixel))
        rows.append(outputs)
        sums = terms if x == 0 else [total + term for total, term in zip(sums, terms, strict=True)]
    return [torch.stack(pixels, -2) for pixels in zip(*rows, strict=True)], sums


def upstream_per_weight(
    up_planes: Tensor, block: Tensor, transmittance: Tensor, alpha_raw: Tensor, features_ext: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """g = dL/dw per pair, w·g in float64 (for the suffix sums), and dL/df_ext per entry (C+2, Q).

    `up_planes` holds per pixel (C+2, B, num_blocks) the upstream gradients of colour, Σ w·z and alpha, one
    plane per channel, so that the products below run along q. With the channels last, torch.compile vectorised
    along the C+2 = 5 channels with masked loads, and this kernel cost more than the blend.
    """
    features = features_ext.t().contiguous()  # (C+2, Q): loads along q

    def pixel(_: object, up_planes: Tensor, transmittance: Tensor, alpha_raw: Tensor) -> tuple[list, list]:
        weight = transmittance * alpha_raw.clamp(max=ALPHA_MAX)
        per_weight, grad_features_ext = torch.zeros_like(weight), []
        for up_plane, feature in zip(up_planes, features, strict=True):
            up = up_plane.index_select(-1, block)
            per_weight = per_weight + up * feature
            grad_features_ext.append(weight * up)
        return [per_weight, (weight * per_weight).to(torch.float64)], grad_features_ext

    (per_weight, weighted), grad_features_ext = _pixel_by_pixel(pixel, alpha_raw.dtype, up_planes, transmittance,
                                                                alpha_raw)
    return per_weight, weighted, torch.stack(grad_features_ext)


def entry_gradients(
    weighted_cumulative: Tensor, segment: Tensor, behind_offset: Tensor,
    transmittance: Tensor, alpha_raw: Tensor, per_weight: Tensor,
    t0: Tensor, w0: Tensor, p: Tensor, r: Tensor, sheared_conic: Tensor, opacity: Tensor, grad_features_ext: Tensor,
) -> Tensor:
    """Per entry, one packed column (C+2 + 8, Q): dL/df_ext | dL/do | dL/d(ln A, S, ln Q) | dL/dmean2d (2) |
    Σ|dL/dmean2d| per axis (2), so that the caller scatters into the Gaussians once (channel-first: see GaussianGrads).

    dL/dα = T g − (Σ_b + T_final h)/(1 − α), Σ_b = Σ of w g over the pairs behind this one in the pixel: those of this
    chunk (a suffix sum up to the block's last entry) plus the later chunks' Σ w g plus T_final h. `behind_offset` (B,
    K) holds per pixel of each of the chunk's block runs (`segment` per entry) the inclusive running sum at the run's
    last entry plus those later terms, so that one gather per pair gives them. With σ = ½A t² + ½Q w², t = v − S w,
    ∂σ/∂S = −A t w, ∂σ/∂mean_v = −A t and ∂σ/∂mean_w = A S t − Q w, so every gradient is a moment of gσ over the block's
    pixels; r = 1 (swapped) maps (mean_v, mean_w) back to (mean_y, mean_x). A and Q enter as their logs: dL/d ln A = Σ
    gσ·½A·t², dL/d ln Q = Σ gσ·½Q·w². Every product takes A or Q with the offsets first (A·t0, Q·w0, and per pair A·t,
    Q·w): for a footprint seen from 1e18 px away A is ~1e-38, and t0·Σ gσ·t alone could exceed float32, then meet an A
    that underflowed to 0 (inf·0 = NaN).
    """
    A, S, Q = sheared_conic.unbind(0)
    at0, ap, qw0, qr = A * t0, A * p, Q * w0, Q * r

    def pixel(x: int | Tensor, weighted_cumulative: Tensor, behind_offset: Tensor, transmittance: Tensor,
              alpha_raw: Tensor, per_weight: Tensor) -> tuple[list, list]:
        behind = (behind_offset.index_select(-1, segment) - weighted_cumulative).to(alpha_raw.dtype)
        alpha = alpha_raw.clamp(max=ALPHA_MAX)
        grad_alpha = transmittance * per_weight - behind / (1.0 - alpha)
        live = (transmittance > 0) & (alpha_raw < ALPHA_MAX)
        grad_alpha = torch.where(live, grad_alpha, 0.0)
        grad_sigma = -grad_alpha * alpha_raw
        at, qw = at0 + ap * x, qw0 + qr * x  # A·t and Q·w at each pixel
        # Σ|gσ ∂σ/∂mean_v|, Σ|gσ ∂σ/∂mean_w|, and the signed moments Σ gσ·xᵏ (k ≤ 2): t and w are linear in x
        return [], [grad_alpha * alpha_raw, (grad_sigma * at).abs(), (grad_sigma * (S * at - qw)).abs(),
                    grad_sigma, grad_sigma * x, grad_sigma * x * x]

    _, (grad_alpha_alpha, abs_v, abs_w, m0, m1, m2) = _pixel_by_pixel(
        pixel, t0.dtype, weighted_cumulative, behind_offset, transmittance, alpha_raw, per_weight)
    grad_opacity = grad_alpha_alpha / opacity
    g_at, g_qw = at0 * m0 + ap * m1, qw0 * m0 + qr * m1  # Σ gσ·A·t, Σ gσ·Q·w
    swapped = r > 0
    grad_v, grad_w = -g_at, S * g_at - g_qw
    rest = torch.stack([
        grad_opacity,
        0.5 * (at0 * t0 * m0 + 2.0 * at0 * p * m1 + ap * p * m2),  # Σ gσ·½A·t²
        -(at0 * w0 * m0 + (at0 * r + ap * w0) * m1 + ap * r * m2),  # Σ gσ·(−A·t·w)
        0.5 * (qw0 * w0 * m0 + 2.0 * qw0 * r * m1 + qr * r * m2),  # Σ gσ·½Q·w²
        torch.where(swapped, grad_w, grad_v), torch.where(swapped, grad_v, grad_w),
        torch.where(swapped, abs_w, abs_v), torch.where(swapped, abs_v, abs_w),
    ])
    return torch.cat([grad_features_ext, rest])


def row_block_spans(
    row: Tensor, owner: Tensor, mx: Tensor, my: Tensor, extent: Tensor, det_over_c2: Tensor, shear: Tensor,
    width: int, block_width: int,
) -> tuple[Tensor, Tensor]:
    """First block and number of blocks of each footprint row record (float64 math, int64 results).

    The α ≥ 1/255 ellipse σ ≤ s of Gaussian `owner` meets pixel row `row` (centre dy from the mean) in
    the x-interval xc ± half, xc = mx + (c_xy/c_yy)·dy, half = sqrt((2 s c_yy − dy²)·det/c_yy²); the
    pixels whose centres lie in it, cut into blocks of `block_width`. Per-Gaussian inputs are (N,).
    """
    dy = row.to(torch.float64) + 0.5 - my.index_select(0, owner)
    half = torch.sqrt(((extent.index_select(0, owner) - dy * dy) * det_over_c2.index_select(0, owner)).clamp_min(0.0))
    xc = mx.index_select(0, owner) + shear.index_select(0, owner) * dy
    x_lo = torch.ceil((xc - half - 0.5).clamp(-1.0, width + 1.0)).clamp(0, width).long()
    x_hi = torch.floor((xc + half - 0.5).clamp(-2.0, width)).clamp(-1, width - 1).long()
    j_lo = torch.div(x_lo, block_width, rounding_mode="floor")
    j_hi = torch.div(x_hi, block_width, rounding_mode="floor")
    return j_lo, torch.where(x_hi >= x_lo, j_hi - j_lo + 1, torch.zeros_like(j_lo))


_EAGER: dict[str, Callable] = {
    fn.__name__: fn
    for fn in (entry_geometry, alpha_and_log_one_minus, blend, upstream_per_weight, entry_gradients,
               row_block_spans)
}
_compiled: dict[Callable, Callable] = {}

PER_PIXEL_KERNELS = frozenset({"upstream_per_weight", "entry_gradients"})
"""Kernels written pixel by pixel of the block, on rows of (Q,), with their sums over the block's pixels unrolled.
As (B, Q) tensors summed over B, inductor made each of them two loops: a reduction along B and an elementwise pass,
each gathering every upstream value again (`upstream_per_weight`'s second pass scalar), or storing (B, Q)
intermediates for the other (`entry_gradients`). Per pixel, all of a kernel's outputs come out of one loop along q.
That loop has more gathers than inductor's CPU tiling heuristic vectorises (35 non-contiguous loads), so these
kernels compile with the heuristic off: scalar, `upstream_per_weight` took 1.7x the time of the (B, Q) form.
Same arithmetic in the same order, so bit-identical results (docs/results.md, "Rasterizer")."""

RECOMPILE_LIMIT = 16
"""Graphs dynamo may compile for one kernel and one set of input dtypes (its default is 8 per function, shared by all
dtypes). A kernel specialises on what dynamic shapes cannot cover: a size of 0 or 1 (of the entries Q, and for
`entry_geometry` of the Gaussians N too), and the channel count of
`upstream_per_weight` and `entry_gradients`, whose loop over the C+2 channels is unrolled. A process that renders
five channel widths in float32 and float64 (training, then the baselines' extra features, or the tests) needed 10
graphs of each, and past the eighth dynamo ran the kernel eager, saying so only in its log: that float64 render took
1.7-1.8x the time of the other float64 ones in the same process, against 1.03-1.07x with a limit per dtype
(`python benchmarks/mixed_dtypes.py --rounds 21`, docs/results.md)."""
_use_compile = os.environ.get("SPLATU_COMPILE", "0") == "1"
_compile_failed = False
"""A compile failed other than by the recompile limit (no C++ compiler, an unsupported backend): the kernels run
eager for the rest of the process, as a later `set_compile(True)` would only fail, and warn, once more per kernel."""
_compile_seconds: float | None = 0.0
_compile_began: float | None = None
_compiles_begun = 0
"""Compiles whose start callback ran: a compile that ran none shows the clock deaf to dynamo (`_stop_clock`)."""


def set_compile(enabled: bool) -> bool:
    """Route the kernels (and a differentiated projection) through torch.compile: about 1.6–1.7× faster per render
    (forward + backward, the rasterizer benchmark in docs/results.md) once compiled, but the first render of a
    process compiles for ~10 s (warm inductor cache) to about a minute (cold). Also on with the environment
    variable SPLATU_COMPILE=1. Returns the previous setting."""
    global _use_compile
    previous, _use_compile = _use_compile, enabled
    return previous


def kernels_compiled() -> bool:
    """Whether the kernels currently go through torch.compile (`set_compile` or SPLATU_COMPILE=1), which dynamo must
    not have turned off (`_dynamo_disabled`) and no compile of this process must have failed (`_compile_failed`)."""
    return _use_compile and not _compile_failed and not _dynamo_disabled()


def _dynamo_disabled() -> bool:
    """Whether torch.compile is a no-op in this process: TORCHDYNAMO_DISABLE=1, which torch.compile reads at each
    call, or TORCH_COMPILE_DISABLE=1 (torch._dynamo.config.disable), read at each call of what it made. Nothing
    compiles then, so the kernels run eager: no compiler is loaded, and the compile time stays 0 s; going through
    torch.compile, the clock saw a kernel made without its compile callbacks and stopped, warning."""
    # a private config key: a torch without it (or a patch that removed it) must not fail every kernel call
    return os.environ.get("TORCHDYNAMO_DISABLE", "") == "1" or bool(getattr(torch._dynamo.config, "disable", False))


def compile_pending() -> bool:
    """Whether the next render will compile: the kernels go through torch.compile and none has run in this process
    yet (later runs of the process, such as an ensemble's further members, reuse what the first compiled)."""
    return kernels_compiled() and not _compiled


def compile_seconds() -> float | None:
    """Seconds this process has spent compiling: loading torch's compiler for the first compiled kernel, then every
    compile dynamo ran (first calls, recompiles, a backward compiled at its first call), as its own start and end
    callbacks time them. The trainer takes it out of the time of its steps, which it would otherwise dominate.
    None once the clock could not follow dynamo (its callbacks are a private API, `_stop_clock`): the steps' time
    then includes the compiles, as it did before they were timed apart."""
    return _compile_seconds


def start_compile_clock() -> None:
    """Load torch's compiler, counting its load (dynamo times its compiles only once loaded: 0.67 s with torch 2.13,
    the median of 5 fresh processes timing `import torch._inductor.compile_fx` with time.perf_counter after `import
    torch` and `torch._dynamo.callback`, as here), and time dynamo's compiles from here on. Every compiled kernel
    call checks it, as torch._dynamo.reset() (tests) drops every callback; a torch whose callback API is missing or
    other stops the clock rather than training."""
    global _compile_seconds
    if _compile_seconds is None:
        return
    try:
        from torch._dynamo.callback import callback_handler

        if _compile_started in callback_handler.start_callbacks:
            return
        started = time.perf_counter()
        with contextlib.suppress(ImportError):  # a compiler that cannot load fails the first compile, which says so
            import torch._inductor.compile_fx  # noqa: F401 (loaded here to be counted, not inside the first compile)
        callback_handler.register_start_callback(_compile_started)
        callback_handler.register_end_callback(_compile_ended)
    except (ImportError, AttributeError, TypeError) as error:
        _stop_clock(f"torch._dynamo.callback is not as splatu knows it ({error!r})")
        return
    _compile_seconds += time.perf_counter() - started


def _stop_clock(why: str) -> None:
    """Give up timing compiles for the rest of the process, and say so once: what was timed is no longer the whole."""
    global _compile_seconds
    if _compile_seconds is not None:
        _compile_seconds = None
        warnings.warn(f"the kernels' compile time cannot be timed apart: {why}; train_compile_seconds is null and "
                      "train_step_seconds includes the compiles", stacklevel=3)


def _compile_started(*_: object, **__: object) -> None:
    """dynamo calls its callbacks around the outermost compile only, so one start is open at a time. Any arguments
    are taken: they are dynamo's to change."""
    global _compile_began, _compiles_begun
    _compile_began = time.perf_counter()
    _compiles_begun += 1


def _compile_ended(*_: object, **__: object) -> None:
    """Count the compile that `_compile_started` opened (none if the clock started while one was running)."""
    global _compile_seconds, _compile_began
    if _compile_began is not None and _compile_seconds is not None:
        _compile_seconds += time.perf_counter() - _compile_began
    _compile_began = None


def kernel(name: str) -> Callable:
    """The eager or compiled version of kernel `name`, as chosen by `set_compile`."""
    return compiled(_EAGER[name])


def compiled(fn: Callable) -> Callable:
    """`fn` itself, or, after `set_compile(True)`, its torch.compile'd version (made once, with an eager fallback).

    For any pure tensor function of the rasterizer, not only this module's kernels (the projection uses it too)."""
    if not kernels_compiled():
        return fn
    if fn not in _compiled:
        _compiled[fn] = _with_eager_fallback(fn)
    return _compiled[fn]


def _dtypes(args: tuple) -> tuple[torch.dtype, ...]:
    """The dtypes of the tensor arguments: the key of a kernel's compiled versions."""
    return tuple(arg.dtype for arg in args if isinstance(arg, Tensor))


def _dtype_names(key: tuple[torch.dtype, ...]) -> str:
    """The dtypes of a kernel's version, as a warning names them: `float64/int64`."""
    return "/".join(sorted({str(dtype).removeprefix("torch.") for dtype in key}))


def _recompile_limit_hit(error: Exception) -> bool:
    """Whether `error` is dynamo refusing a graph past the limit (`fail_on_recompile_limit_hit`), known by its class
    name: the class lives in a private module, which a torch may move."""
    return type(error).__name__ == "FailOnRecompileLimitHit"


def _with_eager_fallback(fn: Callable) -> Callable:
    """Run `fn` through one torch.compile per set of input dtypes, each with its own recompile limit (dynamo's cache
    is per code object otherwise, so float32 training and float64 renders shared one limit). If compiling fails, warn
    once and run eager torch, which gives the same results: past RECOMPILE_LIMIT graphs, for this kernel and these
    dtypes from then on (dynamo itself would run them eager with only a log line); for any other failure (no C++
    compiler, an unsupported backend), every kernel for the rest of the process (`_compile_failed`). A call that fails
    eager too (out of memory) raises eager's error and keeps the compiled version: its inputs failed, not the
    compiler. Either way what failed is never tried again, so a later session of the process (an ensemble's next
    member) neither warns nor fails again."""
    by_dtypes: dict[tuple[torch.dtype, ...], Callable] = {}

    def run(*args):
        global _compile_failed
        start_compile_clock()
        key = _dtypes(args)
        first, begun = key not in by_dtypes, _compiles_begun
        try:
            if first:
                options = {"cpp.enable_tiling_heuristics": False} if fn.__name__ in PER_PIXEL_KERNELS else None
                by_dtypes[key] = torch.compile(fn, dynamic=True, isolate_recompiles=True,
                                               recompile_limit=RECOMPILE_LIMIT, options=options)
            # a model's parameters change length as it densifies: without this, each new length recompiles
            with torch._dynamo.config.patch(force_parameter_static_shapes=False, fail_on_recompile_limit_hit=True):
                result = by_dtypes[key](*args)
        except Exception as error:  # torch.compile raises many exception types; eager gives the same results
            # (a backward that compiles lazily, at its first call, fails in loss.backward() instead, outside this)
            eager = fn(*args)  # raising too (out of memory, bad inputs), the fault is not the compiler's: no fallback
            by_dtypes[key] = fn
            if _recompile_limit_hit(error):
                warnings.warn(f"rasterizer kernel {fn.__name__} needed more than {RECOMPILE_LIMIT} compiled graphs "
                              f"for {_dtype_names(key)} inputs; it runs eager torch for them from now on", stacklevel=2)
            else:
                warnings.warn(f"torch.compile of rasterizer kernel {fn.__name__} failed ({error!r}); using eager "
                              "torch", stacklevel=2)
                _compile_failed = True
            return eager
        if first and _compiles_begun == begun:  # a new torch.compile compiles at its first call
            _stop_clock("dynamo compiled a kernel without calling its compile callbacks")
        return result

    return run
