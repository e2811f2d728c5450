"""Exact k-nearest-neighbour distances of a point cloud, without a (N × N) distance matrix.

3DGS initialises each Gaussian's scale from the mean distance to its nearest neighbours; an SfM cloud
has 10⁴–10⁶ points, so a uniform grid gives each point its candidates, in bounded memory.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

MAX_DISTANCE = 1e18
"""Neighbour distances are capped here: float32 squares overflow from about 1.8e19, and an outlier point 1e20
from the rest once got an infinite initial scale (a numerics review). The capped Gaussian is huge, and is culled
as such."""


def mean_neighbour_distance(points: Tensor, k: int, max_pairs: int = 4_000_000) -> Tensor:
    """(N,) mean Euclidean distance of each point to its k nearest other points, exact.

    A uniform grid whose cell is about the typical k-th neighbour distance (estimated on a sample) gives each
    point candidates in its 27 surrounding cells; an answer is exact when its k-th distance is within one cell.
    The points where it is not are retried with a cell twice as large, and brute force finishes the last few
    (far outliers). Memory stays O(max_pairs). Coincident points are floored at a tiny positive distance, far
    outliers capped at MAX_DISTANCE, and a lone point gets 1, so log-scales stay finite.
    """
    n = points.shape[0]
    if n <= 1:
        return points.new_ones(n)
    k = min(k, n - 1)
    extent = float((points.max(0).values - points.min(0).values).max())
    floor = max(_bulk_extent(points), 1.0) * 1e-7
    result = torch.zeros(n)
    pending = torch.arange(n)
    if n * n <= max_pairs:  # small clouds: one brute-force pass is cheaper than building a grid
        return _brute_knn_mean(points, pending, k, max_pairs).clamp(floor, MAX_DISTANCE)
    cell = _typical_kth_distance(points, k)
    for _ in range(4):
        if pending.numel() == 0 or not 0 < cell < extent:
            break
        mean, kth = _grid_knn_mean(points, pending, k, cell, max_pairs)
        exact = kth <= cell
        result[pending[exact]] = mean[exact]
        pending = pending[~exact]
        cell *= 2.0
    if pending.numel() > 0:
        result[pending] = _brute_knn_mean(points, pending, k, max_pairs)
    return result.clamp(floor, MAX_DISTANCE)


def _bulk_extent(points: Tensor) -> float:
    """The largest side of the box holding the middle 98% of the points along each axis: the floor for coincident
    points scales with it, not with the full box, which one outlier 1e20 away made the floor of every point."""
    sample = points[torch.linspace(0, points.shape[0] - 1, min(points.shape[0], 100_000)).long()].double()
    low, high = torch.quantile(sample, torch.tensor([0.01, 0.99], dtype=torch.float64), dim=0)
    return float((high - low).max())


def _typical_kth_distance(points: Tensor, k: int) -> float:
    """90th percentile of the exact k-th neighbour distance over a fixed sample of 256 points."""
    n = points.shape[0]
    idx = torch.linspace(0, n - 1, min(256, n)).long()
    d = torch.cdist(points[idx], points)
    d[torch.arange(idx.numel()), idx] = math.inf
    kth = d.topk(k, dim=1, largest=False).values[:, -1]
    return float(torch.quantile(kth, 0.9))


def _brute_knn_mean(points: Tensor, queries: Tensor, k: int, max_pairs: int) -> Tensor:
    out = torch.empty(queries.numel())
    chunk = max(1, max_pairs // points.shape[0])
    for start in range(0, queries.numel(), chunk):
        q = queries[start:start + chunk]
        d = (points[q].unsqueeze(1) - points.unsqueeze(0)).norm(dim=-1)
        d[torch.arange(q.numel()), q] = math.inf
        out[start:start + chunk] = d.topk(k, dim=1, largest=False).values.mean(-1)
    return out


def _grid_knn_mean(points: Tensor, queries: Tensor, k: int, cell: float, max_pairs: int) -> tuple[Tensor, Tensor]:
    """For `queries` (indices): mean k-NN distance and k-th distance among the points in the 27 cells around
    each query (k-th is inf when there are fewer than k candidates)."""
    ijk = torch.floor((points - points.min(0).values) / cell).long() + 1  # +1: neighbours never go below 0
    dims = ijk.max(0).values + 2
    key = ijk[:, 0] + dims[0] * (ijk[:, 1] + dims[1] * ijk[:, 2])
    key_sorted, order = torch.sort(key)
    cell_keys, cell_counts = torch.unique_consecutive(key_sorted, return_counts=True)
    cell_starts = torch.cumsum(cell_counts, 0) - cell_counts
    steps = torch.tensor([-1, 0, 1])
    offsets = torch.cartesian_prod(steps, steps, steps)
    offset_keys = offsets[:, 0] + dims[0] * (offsets[:, 1] + dims[1] * offsets[:, 2])
    neighbour_keys = key[queries].unsqueeze(1) + offset_keys.unsqueeze(0)  # (Q, 27)
    slot = torch.searchsorted(cell_keys, neighbour_keys).clamp_max(cell_keys.numel() - 1)
    present = cell_keys[slot] == neighbour_keys
    starts = torch.where(present, cell_starts[slot], 0)
    counts = torch.where(present, cell_counts[slot], 0)
    per_query = counts.sum(1)

    q_total = queries.numel()
    mean = torch.zeros(q_total)
    kth = torch.full((q_total,), math.inf)
    q_start = 0
    while q_start < q_total:
        budget = torch.cumsum(per_query[q_start:], 0)
        q_end = min(q_total, q_start + max(1, int(torch.searchsorted(budget, torch.tensor(max_pairs), right=True))))
        c = counts[q_start:q_end].reshape(-1)
        s = starts[q_start:q_end].reshape(-1)
        slot_of_pair = torch.arange(q_end - q_start).repeat_interleave(27).repeat_interleave(c)
        first = torch.cumsum(c, 0) - c
        within = torch.arange(int(c.sum())) - first.repeat_interleave(c)
        cand = order[s.repeat_interleave(c) + within]
        query = queries[q_start:q_end][slot_of_pair]
        dist = (points[query] - points[cand]).norm(dim=-1).double()
        # One sort orders pairs by query, then by distance: fraction in [0, 0.5], self last at 0.75.
        fraction = torch.where(cand == query, 0.75, 0.5 * dist / dist.max().clamp_min(1e-300))
        sorted_pairs = torch.argsort(slot_of_pair.double() + fraction)
        dist = dist[sorted_pairs].float()
        seg_len = per_query[q_start:q_end]
        seg_first = torch.cumsum(seg_len, 0) - seg_len
        rows = torch.nonzero(seg_len > k).squeeze(-1)  # more than k: the query itself is among its candidates
        nearest = dist[seg_first[rows].unsqueeze(1) + torch.arange(k)]  # (R, k), ascending
        mean[q_start + rows] = nearest.mean(-1)
        kth[q_start + rows] = nearest[:, -1]
        q_start = q_end
    return mean, kth
