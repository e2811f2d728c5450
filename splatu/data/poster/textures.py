"""Procedural materials: albedo and gloss at a hit point, from the box face and local coordinates.

Textures are functions of the exact hit point (no texture images), with structure at several
scales so that reconstruction has something to match: planks, wallpaper, a quilted seat, wood
grain and a poster with a gradient sky, stripes and text-like blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from splatu.data.poster.geometry import Finish, PosterScene
from splatu.data.poster.raycast import Hits


@dataclass(frozen=True)
class Surface:
    """Material at each hit: albedo (N, 3) in [0, 1], Blinn-Phong weight ks (N,) and exponent (N,)."""

    albedo: Tensor
    ks: Tensor
    shininess: Tensor


def _hash01(a: Tensor, b: Tensor, salt: int) -> Tensor:
    """A fixed integer hash of two integer grids, mapped to [0, 1)."""
    h = a.long() * 73856093 + b.long() * 19349663 + salt * 83492791
    h = h ^ (h >> 13)
    h = h * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).double() / 65536.0


def _rgb(r: float, g: float, b: float) -> Tensor:
    return torch.tensor([r, g, b], dtype=torch.float64)


def _frac(x: Tensor) -> Tensor:
    return x - torch.floor(x)


def floor_planks(x: Tensor, y: Tensor) -> Tensor:
    """Staggered wooden planks with per-plank tone, grain and dark seams."""
    plank_width, plank_length = 0.18, 1.2
    row = torch.floor(y / plank_width)
    along = x + _hash01(row, row, 1) * plank_length
    col = torch.floor(along / plank_length)
    tone = 0.75 + 0.5 * _hash01(row, col, 2)
    wobble = 0.3 * torch.sin(along * 2.0 + 6.0 * _hash01(row, col, 3))
    grain = 1.0 + 0.08 * torch.sin(2 * math.pi * (y / plank_width * 6.0 + wobble))
    seam = (_frac(y / plank_width) < 0.03) | (_frac(along / plank_length) < 0.006)
    shade = tone * grain * torch.where(seam, 0.45, 1.0)
    return shade[:, None] * _rgb(0.55, 0.36, 0.20)


_WALL_TINTS = (_rgb(0.80, 0.78, 0.70), _rgb(0.62, 0.72, 0.78), _rgb(0.78, 0.66, 0.62), _rgb(0.68, 0.76, 0.62))


def wallpaper(along: Tensor, z: Tensor, wall: Tensor) -> Tensor:
    """Striped wallpaper with a diamond motif above a plain panel and a dark rail; tinted per wall."""
    stripes = 0.86 + 0.08 * torch.sin(2 * math.pi * along / 0.25)
    motif = (_frac(along / 0.25) - 0.5).abs() + (_frac(z / 0.35) - 0.5).abs() < 0.15
    paper = stripes * torch.where(motif, 0.8, 1.0)
    tint = torch.stack(_WALL_TINTS)[wall]
    color = paper[:, None] * tint
    color = torch.where((z < 0.85)[:, None], 0.7 * tint, color)
    return torch.where(((z >= 0.85) & (z < 0.92))[:, None], _rgb(0.30, 0.20, 0.12).expand_as(color), color)


def ceiling(x: Tensor, y: Tensor) -> Tensor:
    """Light panels in a grid."""
    grid = (_frac(x / 0.6) < 0.03) | (_frac(y / 0.6) < 0.03)
    return torch.where(grid, 0.55, 0.88)[:, None] * _rgb(1.0, 1.0, 0.97)


def wood(along: Tensor, across: Tensor) -> Tensor:
    """Chair wood: grain lines along the part's length."""
    grain = 0.85 + 0.15 * torch.sin(2 * math.pi * (across * 40.0 + 2.0 * torch.sin(along * 6.0)))
    return grain[:, None] * _rgb(0.45, 0.28, 0.15)


def upholstery(x: Tensor, y: Tensor) -> Tensor:
    """Quilted red leather: diamond seams and buttons."""
    d1 = (_frac((x + y) / 0.09) - 0.5).abs()
    d2 = (_frac((x - y) / 0.09) - 0.5).abs()
    seam = torch.minimum(d1, d2) < 0.06
    button = (d1 - 0.5).abs() + (d2 - 0.5).abs() < 0.08
    shade = torch.where(seam | button, 0.6, 1.0)
    return shade[:, None] * _rgb(0.60, 0.13, 0.10)


def picture(u: Tensor, v: Tensor) -> Tensor:
    """The poster: sky gradient with a sun over hills, diagonal stripes, then rows of text-like blocks."""
    n = u.shape[0]
    sky_mix = ((v - 0.62) / 0.35).clamp(0, 1)[:, None]
    color = (1 - sky_mix) * _rgb(0.95, 0.55, 0.25) + sky_mix * _rgb(0.15, 0.30, 0.70)
    sun = (u - 0.7) ** 2 + (v - 0.82) ** 2 < 0.08**2
    color = torch.where(sun[:, None], _rgb(1.0, 0.9, 0.4).expand(n, 3), color)
    hills = v < 0.62 + 0.12 * (1 - (2 * _frac(u * 1.5) - 1).abs())
    color = torch.where(hills[:, None], _rgb(0.20, 0.35, 0.25).expand(n, 3), color)
    stripe = torch.where((_frac((u + v) * 8) < 0.5)[:, None], _rgb(0.90, 0.20, 0.30), _rgb(0.95, 0.90, 0.80))
    color = torch.where((v < 0.40)[:, None], _rgb(0.93, 0.90, 0.82).expand(n, 3), color)
    color = torch.where(((v >= 0.40) & (v < 0.55))[:, None], stripe.expand(n, 3), color)
    row = torch.floor((0.38 - v) / 0.045)
    col = torch.floor(u / 0.06)
    in_line = (_frac((0.38 - v) / 0.045) > 0.25) & (_frac((0.38 - v) / 0.045) < 0.75)
    ink = in_line & (row >= 0) & (u > 0.08) & (u < 0.92) & (_hash01(row, col, 5) > 0.3) & (_frac(u / 0.06) < 0.85)
    title = ink & (row == 0)
    color = torch.where(ink[:, None], _rgb(0.10, 0.10, 0.15).expand(n, 3), color)
    color = torch.where(title[:, None], _rgb(0.75, 0.10, 0.10).expand(n, 3), color)
    border = (u < 0.03) | (u > 0.97) | (v < 0.03) | (v > 0.97)
    return torch.where(border[:, None], _rgb(0.08, 0.08, 0.10).expand(n, 3), color)


def surface(scene: PosterScene, hits: Hits) -> Surface:
    """Albedo and gloss for every hit ray (rays that hit nothing get black, no gloss)."""
    n = hits.t.shape[0]
    dtype = hits.local.dtype
    albedo = torch.zeros(n, 3, dtype=dtype)
    ks = torch.zeros(n, dtype=dtype)
    shininess = torch.ones(n, dtype=dtype)
    finishes = torch.tensor([int(b.finish) for b in scene.boxes])
    finish = torch.where(hits.box >= 0, finishes[hits.box.clamp(min=0)], -1)
    x, y, z = hits.local.unbind(dim=1)
    top = (hits.axis == 2) & (hits.side > 0)
    bottom = (hits.axis == 2) & (hits.side < 0)
    room = finish == Finish.ROOM
    room_center_z = float(scene.centers[0, 2])

    def paint(mask: Tensor, color_fn, gloss: float, exponent: float) -> None:
        rows = mask.nonzero()[:, 0]
        if rows.numel():
            albedo[rows] = color_fn(rows).to(dtype)
            ks[rows] = gloss
            shininess[rows] = exponent

    paint(room & bottom, lambda r: floor_planks(x[r], y[r]), 0.25, 40.0)
    paint(room & top, lambda r: ceiling(x[r], y[r]), 0.0, 1.0)
    walls = room & (hits.axis < 2)
    wall_index = hits.axis * 2 + (hits.side > 0).long()
    paint(walls, lambda r: wallpaper(torch.where(hits.axis[r] == 0, y[r], x[r]), z[r] + room_center_z,
                                     wall_index[r]), 0.0, 1.0)
    paint((finish == Finish.SEAT) & top, lambda r: upholstery(x[r], y[r]), 0.5, 25.0)
    wooden = (finish == Finish.WOOD) | ((finish == Finish.SEAT) & ~top)
    longest = scene.halves.argmax(dim=1)[hits.box.clamp(min=0)]
    along = torch.where(longest == 0, x, torch.where(longest == 1, y, z))
    across = x + y + z - along
    paint(wooden, lambda r: wood(along[r], across[r]), 0.15, 20.0)
    halves = scene.halves[hits.box.clamp(min=0)]
    u = x / (2 * halves[:, 0]) + 0.5
    v = y / (2 * halves[:, 1]) + 0.5
    paint((finish == Finish.POSTER) & top, lambda r: picture(u[r], v[r]), 0.4, 60.0)
    paint((finish == Finish.POSTER) & ~top, lambda r: _rgb(0.92, 0.92, 0.90).expand(r.numel(), 3), 0.05, 10.0)
    return Surface(albedo=albedo, ks=ks, shininess=shininess)
