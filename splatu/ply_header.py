"""PLY header parsing shared by the initial-point reader and the 3DGS reader, so both find the vertex data at the
right byte whatever other elements the file declares, and refuse a malformed header in one line."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from splatu.errors import SplatuError

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
"""PLY scalar type names → numpy kinds, without byte order (the file's format line sets it)."""
FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
END_HEADER = re.compile(rb"^end_header[ \t]*\r?(?:\n|$)", re.MULTILINE)


@dataclass(frozen=True)
class PlyVertices:
    """Where the vertex element sits in a PLY file, and what each vertex holds."""

    format: str  # a key of FORMATS
    count: int
    properties: list[tuple[str, str]]  # (name, numpy kind) in file order
    offset: int  # binary: byte offset of the first vertex; ascii: index of its line in the body
    body_start: int  # byte offset just after end_header

    def dtype(self) -> np.dtype:
        """The binary record of one vertex, in the file's byte order."""
        order = FORMATS[self.format] or "<"
        return np.dtype([(name, order + kind) for name, kind in self.properties])


@dataclass
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str | None]]  # (name, numpy kind); kind None for a list property (variable size)

    def record_bytes(self) -> int | None:
        """Bytes per binary record, or None when a list property makes it variable."""
        kinds = [kind for _, kind in self.properties]
        return None if None in kinds else sum(np.dtype(kind).itemsize for kind in kinds)  # type: ignore[arg-type]


def read_vertex_layout(data: bytes, path: Path, fix: str) -> PlyVertices:
    """Parse the header of the PLY bytes `data`; every problem is a one-line SplatuError ending in `fix`.

    Elements declared before the vertices are skipped (by their fixed size in binary, by their line count in
    ascii); a binary one with list properties has no fixed size, so it is refused.
    """
    def bad(what: str) -> SplatuError:
        return SplatuError(what, f"in {path}", fix)

    if not data.startswith(b"ply"):
        raise bad("not a PLY file (no 'ply' magic)")
    found = END_HEADER.search(data)  # as a line of its own: a comment may mention it
    if found is None:
        raise bad("the PLY header has no end_header (is the file truncated?)")
    end, body_start = found.start(), found.end()
    fmt = None
    elements: list[_Element] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in FORMATS:
                raise bad(f"unknown PLY format line {line.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise bad(f"malformed PLY element line {line.strip()!r} (expected 'element NAME COUNT')")
            elements.append(_Element(words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise bad(f"PLY property {line.strip()!r} comes before any element")
            if len(words) == 5 and words[1] == "list":
                elements[-1].properties.append((words[4], None))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1].properties.append((words[2], PLY_TYPES[words[1]]))
            else:
                raise bad(f"unsupported PLY property line {line.strip()!r}")
    if fmt is None:
        raise bad("the PLY header has no format line")
    vertex_at = next((i for i, element in enumerate(elements) if element.name == "vertex"), None)
    if vertex_at is None:
        raise bad("the PLY file has no vertex element")
    offset = 0
    for element in elements[:vertex_at]:
        size = 1 if fmt == "ascii" else element.record_bytes()  # ascii: one line per record
        if size is None:
            raise bad(f"the PLY element {element.name!r} before the vertices has list properties, so its size "
                      "is unknown")
        offset += element.count * size
    vertex = elements[vertex_at]
    if vertex.record_bytes() is None:
        raise bad("the PLY vertex element has a list property")
    names = [name for name, _ in vertex.properties]
    if not names or len(set(names)) != len(names):
        raise bad("the PLY vertex element has no properties, or one name twice")
    return PlyVertices(fmt, vertex.count, vertex.properties, offset, body_start)  # type: ignore[arg-type]
