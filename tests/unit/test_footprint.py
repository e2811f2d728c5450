"""The footprint's entry list, checked on its own: complete, and in the order the compositor relies on.

The compositor reads each block's Gaussians as one contiguous run per depth round, front to back; a
missing entry would drop a pair and a misordered one would blend out of order. The exactness tests
see both only through the rendered values; these check the list itself against a brute-force pass
over every pixel, with one and with several depth rounds.
"""

from __future__ import annotations

import itertools

import pytest
import torch

from splatu.rasterizer import footprint
from splatu.rasterizer.footprint import ALPHA_MIN, block_entries
from splatu.rasterizer.projection import project_gaussians
from tests.reference_rasterizer import random_scene

BLOCK_WIDTH = 8
WIDTH, HEIGHT = 37, 23  # not a multiple of the block width


def listed(seed: int, n: int = 80):
    scene = random_scene(seed, n, WIDTH, HEIGHT, opacity_range=(0.002, 0.99))
    proj = project_gaussians(scene.means, scene.quats, scene.scales, scene.world_to_camera, scene.K, WIDTH, HEIGHT,
                             scene.near, scene.far, False)
    entries = block_entries(proj.means2d, proj.cov2d, proj.det, scene.opacities, proj.depths, proj.visible,
                            WIDTH, HEIGHT, BLOCK_WIDTH)
    return scene, proj, entries


def passing_pairs(scene, proj) -> set[tuple[int, int]]:
    """(block, Gaussian) for every pixel centre where a visible Gaussian has σ ≥ 0 and α ≥ 1/255."""
    ys, xs = torch.meshgrid(torch.arange(HEIGHT), torch.arange(WIDTH), indexing="ij")
    dx = xs.reshape(-1, 1) + 0.5 - proj.means2d[:, 0]
    dy = ys.reshape(-1, 1) + 0.5 - proj.means2d[:, 1]
    a, b, c = proj.conics.unbind(-1)
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = (scene.opacities * torch.exp(-sigma)).clamp(max=0.99)
    passes = (sigma >= 0) & (alpha >= ALPHA_MIN) & proj.visible
    pixel, gaussian = torch.nonzero(passes).unbind(1)
    blocks_per_row = -(-WIDTH // BLOCK_WIDTH)
    block = (pixel // WIDTH) * blocks_per_row + (pixel % WIDTH) // BLOCK_WIDTH
    return set(zip(block.tolist(), gaussian.tolist(), strict=True))


@pytest.mark.parametrize("rounds", [1, 5])
@pytest.mark.parametrize("seed", range(6))
def test_entries_cover_every_passing_pair_in_round_block_depth_order(seed, rounds, monkeypatch):
    monkeypatch.setattr(footprint, "MAX_ROUNDS", rounds)
    monkeypatch.setattr(footprint, "ROUND_MIN_ENTRIES", 1)
    scene, proj, entries = listed(seed)
    pairs = list(zip(entries.block.tolist(), entries.gaussian.tolist(), strict=True))
    assert len(set(pairs)) == len(pairs), "an entry is listed twice"
    needed = passing_pairs(scene, proj)
    assert needed, "the scene should have passing pairs"
    assert needed <= set(pairs), f"missing entries: {sorted(needed - set(pairs))[:5]}"

    # Front to back = by depth, ties by index (the reference's stable order).
    depth_rank = torch.empty_like(entries.gaussian)
    order = torch.sort(proj.depths, stable=True).indices
    depth_rank[order] = torch.arange(order.numel())
    rank = depth_rank[entries.gaussian]
    bounds = entries.round_bounds
    assert len(bounds) == rounds + 1 and bounds[0] == 0 and bounds[-1] == len(pairs)
    round_of = torch.repeat_interleave(torch.arange(rounds), torch.tensor(bounds).diff())
    key = [(int(r), b, int(k)) for r, (b, _), k in zip(round_of, pairs, rank, strict=True)]
    assert key == sorted(key), "entries are not ordered by (round, block, depth)"
    # A round is a slab of the depth order: all of a Gaussian's entries share one, deeper ones come later.
    deepest = [int(rank[b:e].max()) for b, e in itertools.pairwise(bounds) if e > b]
    shallowest = [int(rank[b:e].min()) for b, e in itertools.pairwise(bounds) if e > b]
    assert all(d < s for d, s in zip(deepest[:-1], shallowest[1:], strict=True))
    if rounds > 1:
        assert sum(e > b for b, e in itertools.pairwise(bounds)) > 1, "only one round was used"


def test_no_candidates_give_an_empty_list():
    scene, proj, _ = listed(0, n=5)
    entries = block_entries(proj.means2d, proj.cov2d, proj.det, torch.zeros_like(scene.opacities), proj.depths,
                            proj.visible, WIDTH, HEIGHT, BLOCK_WIDTH)
    assert entries.block.numel() == entries.gaussian.numel() == 0
    assert entries.round_bounds == [0, 0]
