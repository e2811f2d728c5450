"""A small PLY point reader and writer, for initial points (x, y, z with optional colours).

Reads ASCII and binary (little or big endian) vertex elements with numpy; other elements
(faces, ...) are skipped, since only the points seed the model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from splatu.errors import SplatuError
from splatu.ply_header import read_vertex_layout

POINTS_FIX = "write the points as a PLY with a vertex element holding x, y, z"


def _bad(path: Path, what: str) -> SplatuError:
    return SplatuError(f"unreadable PLY point file ({what})", f"in {path}", POINTS_FIX)


def read_ply_points(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Return (xyz float32 (M, 3), rgb float32 (M, 3) in [0, 1] or None) from a PLY file."""
    if not path.is_file():
        raise SplatuError("PLY point file not found", f"in {path}", "fix ply_file_path or remove it")
    data = path.read_bytes()
    layout = read_vertex_layout(data, path, POINTS_FIX)
    props = layout.properties
    names = [n for n, _ in props]
    if not {"x", "y", "z"} <= set(names):
        raise _bad(path, "no vertex element with x, y, z")
    if layout.format == "ascii":
        lines = data[layout.body_start:].decode("ascii", errors="replace").split("\n")
        rows = lines[layout.offset: layout.offset + layout.count]
        try:
            table = np.array([[float(v) for v in r.split()[: len(props)]] for r in rows], dtype=np.float64)
        except ValueError as err:
            raise _bad(path, f"bad number: {err}") from None
        if table.shape != (layout.count, len(props)):
            raise _bad(path, f"expected {layout.count} vertex rows of {len(props)} values")
        column = {n: table[:, i] for i, n in enumerate(names)}
    else:
        dtype = layout.dtype()
        start = layout.body_start + layout.offset
        if len(data) - start < dtype.itemsize * layout.count:
            raise _bad(path, "file shorter than its header says")
        records = np.frombuffer(data, dtype=dtype, count=layout.count, offset=start)
        column = {n: records[n].astype(np.float64) for n in names}
    xyz = np.stack([column["x"], column["y"], column["z"]], axis=1).astype(np.float32)
    if not np.isfinite(xyz).all():
        raise _bad(path, "non-finite coordinates")
    rgb = None
    if {"red", "green", "blue"} <= set(names):
        scale = _colour_scale(np.dtype(dict(props)["red"]), float(column["red"].max(initial=0)))
        rgb = (np.stack([column["red"], column["green"], column["blue"]], axis=1) / scale).astype(np.float32)
    return xyz, rgb


def _colour_scale(kind: np.dtype, largest: float) -> float:
    """What full intensity reads as: 255 for 8-bit colours, and for wider integers holding 8-bit values (as
    some tools write them); a wider type's maximum (65535 for 16-bit) otherwise; floats are in [0, 1], or in
    [0, 255] when any exceeds 1."""
    if kind.kind in "iu" and kind.itemsize > 1 and largest > 255:
        return float(np.iinfo(kind).max)
    return 255.0 if kind.kind in "iu" or largest > 1 else 1.0


def write_ply_points(path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """Write points (and colours in [0, 1], stored as uchar) as a binary little-endian PLY."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    table = np.empty(len(xyz), dtype=fields)
    for i, axis in enumerate("xyz"):
        table[axis] = xyz[:, i]
    if rgb is not None:
        rgb8 = np.clip(np.round(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8)
        for i, channel in enumerate(("red", "green", "blue")):
            table[channel] = rgb8[:, i]
    ply_type = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}"]
    header += [f"property {ply_type[t]} {n}" for n, t in fields]
    header.append("end_header")
    path.write_bytes(("\n".join(header) + "\n").encode("ascii") + table.tobytes())
