"""The footprint's entry list, checked on its own: complete, and in the order the compositor relies on.

The compositor reads each block's Gaussians as one contiguous run per depth round, front to back; a
missing entry would drop a pair and a misordered one would blend out of order. The exactness tests
see both only through the rendered values. These check the list itself, with one and with several
depth rounds: it holds every pair a brute-force pass over the pixels finds passing the α test, each
listed entry has a pixel within the footprint's rounding slack of passing, and the order is
(round, block, depth).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import pytest
import torch

from splatu.rasterizer import footprint, rasterize
from splatu.rasterizer.errors import RasterInputError
from splatu.rasterizer.footprint import block_entries
from splatu.rasterizer.kernels import ALPHA_MIN
from splatu.rasterizer.projection import project_gaussians
from tests.reference_rasterizer import random_scene

BLOCK_WIDTH = 8
WIDTH, HEIGHT = 37, 23  # not a multiple of the block width
BLOCKS_PER_ROW = -(-WIDTH // BLOCK_WIDTH)


@dataclass
class SortedEntries:
    """Every round of a BlockEntries as the compositor takes it when no block is skipped, one after another."""

    block: torch.Tensor
    gaussian: torch.Tensor
    round_bounds: list[int]
    num_blocks: int


def sorted_entries(entries: footprint.BlockEntries) -> SortedEntries:
    blocks, gaussians = zip(*(entries.round_entries(r) for r in range(len(entries.round_bounds) - 1)), strict=True)
    return SortedEntries(torch.cat(blocks), torch.cat(gaussians), entries.round_bounds, entries.num_blocks)


def unsorted(seed: int, n: int = 80, width: int = WIDTH, height: int = HEIGHT):
    scene = random_scene(seed, n, width, height, opacity_range=(0.002, 0.99))
    proj = project_gaussians(scene.means, scene.quats, scene.scales, scene.world_to_camera, scene.K, width, height,
                             scene.near, scene.far, False)
    entries = block_entries(proj.means2d, proj.cov2d, proj.det, scene.opacities, proj.depths, proj.visible,
                            width, height, BLOCK_WIDTH)
    return scene, proj, entries


def listed(seed: int, n: int = 80, width: int = WIDTH, height: int = HEIGHT):
    scene, proj, entries = unsorted(seed, n, width, height)
    return scene, proj, sorted_entries(entries)


def sigma_at(proj, x: torch.Tensor, y: torch.Tensor, gaussian: torch.Tensor) -> torch.Tensor:
    """σ of Gaussian(s) `gaussian` at the pixel centres (x + 0.5, y + 0.5); shapes broadcast."""
    dx = x + 0.5 - proj.means2d[gaussian, 0]
    dy = y + 0.5 - proj.means2d[gaussian, 1]
    cxx, cxy, cyy = proj.cov2d[gaussian].unbind(-1)
    return 0.5 * (cyy * dx * dx - 2 * cxy * dx * dy + cxx * dy * dy) / proj.det[gaussian]


def passing_pairs(scene, proj) -> set[tuple[int, int]]:
    """(block, Gaussian) for every pixel centre where a visible Gaussian has σ ≥ 0 and α ≥ 1/255."""
    ys, xs = torch.meshgrid(torch.arange(HEIGHT), torch.arange(WIDTH), indexing="ij")
    everyone = torch.arange(scene.opacities.numel())
    sigma = sigma_at(proj, xs.reshape(-1, 1), ys.reshape(-1, 1), everyone)
    alpha = (scene.opacities * torch.exp(-sigma)).clamp(max=0.99)
    passes = (sigma >= 0) & (alpha >= ALPHA_MIN) & proj.visible
    pixel, gaussian = torch.nonzero(passes).unbind(1)
    block = (pixel // WIDTH) * BLOCKS_PER_ROW + (pixel % WIDTH) // BLOCK_WIDTH
    return set(zip(block.tolist(), gaussian.tolist(), strict=True))


def assert_round_block_depth_order(proj, entries, rounds: int) -> None:
    """Entries sorted by (round, block, depth rank); rounds are consecutive slabs of the depth order."""
    depth_rank = torch.empty(proj.depths.numel(), dtype=torch.long)
    order = torch.sort(proj.depths, stable=True).indices  # front to back, ties by index (the reference's)
    depth_rank[order] = torch.arange(order.numel())
    rank = depth_rank[entries.gaussian]
    bounds = entries.round_bounds
    assert len(bounds) == rounds + 1 and bounds[0] == 0 and bounds[-1] == entries.block.numel()
    assert bool(((entries.block >= 0) & (entries.block < entries.num_blocks)).all()), "a block id is out of range"
    round_of = torch.repeat_interleave(torch.arange(rounds), torch.tensor(bounds).diff())
    key = (round_of * entries.num_blocks + entries.block) * (order.numel() + 1) + rank
    assert bool((key[1:] > key[:-1]).all()), "entries are not strictly ordered by (round, block, depth)"
    used = [(b, e) for b, e in itertools.pairwise(bounds) if e > b]
    deepest = [int(rank[b:e].max()) for b, e in used]
    shallowest = [int(rank[b:e].min()) for b, e in used]
    assert all(d < s for d, s in zip(deepest[:-1], shallowest[1:], strict=True)), "rounds overlap in depth"
    if rounds > 1:
        assert len(used) > 1, "only one round was used"


@pytest.mark.parametrize("rounds", [1, 5])
@pytest.mark.parametrize("seed", range(6))
def test_entries_are_every_passing_pair_in_round_block_depth_order(seed, rounds, monkeypatch):
    monkeypatch.setattr(footprint, "MAX_ROUNDS", rounds)
    monkeypatch.setattr(footprint, "ROUND_MIN_ENTRIES", 1)
    scene, proj, entries = listed(seed)
    pairs = set(zip(entries.block.tolist(), entries.gaussian.tolist(), strict=True))
    assert len(pairs) == entries.block.numel(), "an entry is listed twice"
    needed = passing_pairs(scene, proj)
    assert needed, "the scene should have passing pairs"
    assert needed <= pairs, f"missing entries: {sorted(needed - pairs)[:5]}"

    # No junk: each entry's block holds an in-image pixel centre inside the footprint σ ≤ ln(255·o),
    # up to the footprint's relative rounding slack.
    assert bool(((entries.block >= 0) & (entries.block < entries.num_blocks)).all())
    row = entries.block // BLOCKS_PER_ROW
    x = (entries.block % BLOCKS_PER_ROW)[:, None] * BLOCK_WIDTH + torch.arange(BLOCK_WIDTH)
    sigma = sigma_at(proj, x, row[:, None], entries.gaussian[:, None])
    sigma = torch.where(x < WIDTH, sigma, torch.inf).amin(1)
    reach = torch.log(255.0 * scene.opacities[entries.gaussian]).clamp_min(0.0)
    assert bool((sigma <= reach * (1 + 1e-3) + 1e-3).all()), "an entry's block has no pixel in the footprint"

    assert_round_block_depth_order(proj, entries, rounds)


@pytest.mark.parametrize("rounds", [1, 3])
@pytest.mark.parametrize(("width", "height"), [(200, 150), (2048, 160), (792, 331)])
def test_order_holds_on_lists_long_enough_for_the_radix_sort(rounds, width, height, monkeypatch):
    """torch sorts 1-D integer tensors of ≥ 32,768 elements with a different (radix) algorithm. The sort
    key is int16 below 32,768 blocks (200×150: 3,750) and int32 from there (2048×160: 40,960; 792×331:
    32,769, one past int16), where int16 keys would wrap and break the order."""
    monkeypatch.setattr(footprint, "MAX_ROUNDS", rounds)
    monkeypatch.setattr(footprint, "ROUND_MIN_ENTRIES", 1)
    _, proj, entries = listed(7, n=15_000, width=width, height=height)
    assert min(e - b for b, e in itertools.pairwise(entries.round_bounds)) >= 32_768
    if entries.num_blocks > 32_768:
        assert int(entries.block.max()) >= 32_768, "the scene should list a block id past int16"
    assert_round_block_depth_order(proj, entries, rounds)


@pytest.mark.parametrize("seed", range(3))
def test_a_round_taken_on_some_blocks_is_that_round_on_those_blocks(seed, monkeypatch):
    """The compositor sorts a later round only on the blocks still alive: that must be the whole round's list with
    the other blocks' entries left out, in the same order (so that skipping changes no render)."""
    monkeypatch.setattr(footprint, "MAX_ROUNDS", 3)
    monkeypatch.setattr(footprint, "ROUND_MIN_ENTRIES", 1)
    _, _, entries = unsorted(seed, n=200)
    keep = torch.rand(entries.num_blocks, generator=torch.Generator().manual_seed(seed)) < 0.5
    for r in range(len(entries.round_bounds) - 1):
        block, gaussian = entries.round_entries(r)
        kept_block, kept_gaussian = entries.round_entries(r, keep)
        on_kept = keep[block]
        assert 0 < int(on_kept.sum()) < block.numel(), "the test should keep some of the round's entries, not all"
        assert torch.equal(kept_block, block[on_kept]) and torch.equal(kept_gaussian, gaussian[on_kept])
        assert kept_block.dtype == kept_gaussian.dtype == torch.long
    everything = torch.ones(entries.num_blocks, dtype=torch.bool)
    assert all(torch.equal(a, b) for a, b in zip(entries.round_entries(0, everything), entries.round_entries(0),
                                                 strict=True))


def test_more_entries_than_int32_indices_hold_is_one_clear_error(monkeypatch):
    """Past MAX_ENTRIES the int32 owners would wrap; the limit is lowered here so the test allocates nothing large."""
    assert torch.iinfo(torch.int32).max == footprint.MAX_ENTRIES
    monkeypatch.setattr(footprint, "MAX_ENTRIES", 100)
    owner, value = footprint._expand(torch.tensor([5, 9], dtype=torch.int32), torch.tensor([40, 60]))
    assert owner.dtype == torch.int32 and value.tolist() == [*range(5, 45), *range(9, 69)]
    with pytest.raises(RasterInputError, match=r"make 101 entries, more than the 100 int32 indices.*lower resolution"):
        footprint._expand(torch.zeros(2, dtype=torch.int32), torch.tensor([40, 61]))


def test_no_candidates_give_an_empty_list():
    scene, proj, _ = listed(0, n=5)
    entries = block_entries(proj.means2d, proj.cov2d, proj.det, torch.zeros_like(scene.opacities), proj.depths,
                            proj.visible, WIDTH, HEIGHT, BLOCK_WIDTH)
    assert entries.key.numel() == entries.gaussian.numel() == 0
    block, gaussian = entries.round_entries(0)
    assert block.numel() == gaussian.numel() == 0
    assert entries.round_bounds == [0, 0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("seed", range(3))
def test_a_pixel_centre_exactly_on_the_alpha_contour_is_not_dropped(seed, dtype, monkeypatch):
    """Each Gaussian's opacity is e^σ/255 for σ at a pixel centre near it, so α there is 1/255 to the last bits and
    the compositor's α test passes or fails on rounding. Where it passes, the footprint must list the pair: the
    render equals one whose footprint is widened far past the contour (its extra entries fail the α test).
    Without the footprint's rounding slack each of these scenes lost 4 to 12 of its ~150 such pairs.

    The brute-force reference cannot judge these pairs: its σ rounds differently, so it draws other ones."""
    n, width, height = 400, 64, 48
    scene = random_scene(seed, n, width, height, anisotropy=20.0)
    gaussians = [getattr(scene, name).to(dtype) for name in ("means", "quats", "scales")]
    camera = (scene.world_to_camera.to(dtype), scene.K.to(dtype), width, height)
    proj = project_gaussians(*gaussians, *camera, scene.near, scene.far, False)
    offset = torch.randn(n, 2, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 2.0
    x, y = (proj.means2d.double() + offset).floor().unbind(1)
    x, y = x.clamp(0, width - 1), y.clamp(0, height - 1)
    sigma = sigma_at(proj, x, y, torch.arange(n))
    on_contour = proj.visible & (sigma > 0.05) & (sigma < 5.0)  # so that o = e^σ/255 is in (0, 1)
    assert int(on_contour.sum()) >= 100
    opacities = torch.where(on_contour, torch.exp(sigma) / 255, 0.0).to(dtype)
    features = torch.eye(n, dtype=dtype)  # the image holds every pair's weight

    def render():
        return rasterize(*gaussians, opacities, features, *camera, near=scene.near, far=scene.far)

    exact = render()
    monkeypatch.setattr(footprint, "FOOTPRINT_SLACK", 0.5)
    widened = render()
    assert exact.num_contributing_pairs == widened.num_contributing_pairs
    torch.testing.assert_close(exact.image, widened.image, rtol=0.0, atol=1e-15)
