"""A small PLY point reader and writer, for initial points (x, y, z with optional colours).

Reads ASCII and binary (little or big endian) vertex elements with numpy; other elements
(faces, ...) after the vertices are ignored, since only the points seed the model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from splatu.errors import SplatuError

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def _bad(path: Path, what: str) -> SplatuError:
    return SplatuError(f"unreadable PLY point file ({what})", f"in {path}",
                       "write the points as a PLY with a vertex element holding x, y, z")


def read_ply_points(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Return (xyz float32 (M, 3), rgb float32 (M, 3) in [0, 1] or None) from a PLY file."""
    if not path.is_file():
        raise SplatuError("PLY point file not found", f"in {path}", "fix ply_file_path or remove it")
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise _bad(path, "no PLY header")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = ""
    vertex_count = -1
    props: list[tuple[str, str]] = []
    in_vertex = False
    for line in header:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            in_vertex = words[1] == "vertex"
            if in_vertex:
                vertex_count = int(words[2])
        elif words[0] == "property" and in_vertex:
            if words[1] == "list" or words[1] not in _PLY_TYPES:
                raise _bad(path, f"unsupported vertex property {' '.join(words[1:])!r}")
            props.append((words[2], _PLY_TYPES[words[1]]))
    names = [n for n, _ in props]
    if vertex_count < 0 or not {"x", "y", "z"} <= set(names):
        raise _bad(path, "no vertex element with x, y, z")
    if fmt == "ascii":
        rows = data[body_start:].decode("ascii", errors="replace").split("\n")[:vertex_count]
        try:
            table = np.array([[float(v) for v in r.split()[: len(props)]] for r in rows], dtype=np.float64)
        except ValueError as err:
            raise _bad(path, f"bad number: {err}") from None
        if table.shape != (vertex_count, len(props)):
            raise _bad(path, f"expected {vertex_count} vertex rows of {len(props)} values")
        column = {n: table[:, i] for i, n in enumerate(names)}
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, order + t) for n, t in props])
        if len(data) - body_start < dtype.itemsize * vertex_count:
            raise _bad(path, "file shorter than its header says")
        table = np.frombuffer(data, dtype=dtype, count=vertex_count, offset=body_start)
        column = {n: table[n].astype(np.float64) for n in names}
    else:
        raise _bad(path, f"unknown format {fmt!r}")
    xyz = np.stack([column["x"], column["y"], column["z"]], axis=1).astype(np.float32)
    if not np.isfinite(xyz).all():
        raise _bad(path, "non-finite coordinates")
    rgb = None
    if {"red", "green", "blue"} <= set(names):
        scale = 255.0 if dict(props)["red"] in ("u1", "i1") or column["red"].max(initial=0) > 1 else 1.0
        rgb = (np.stack([column["red"], column["green"], column["blue"]], axis=1) / scale).astype(np.float32)
    return xyz, rgb


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
