"""Standard 3DGS PLY export/import, plus `u_0..u_{Ku-1}` for the uncertainty SH of a model that trained one.

The layout is the one 3DGS viewers read: x y z, nx ny nz (zeros), f_dc_0..2, f_rest_* channel-major
(all red coefficients, then green, then blue), opacity (logit), scale_0..2 (log), rot_0..3 (wxyz);
every property a little-endian float32. Viewers ignore the extra `u_*` properties: a Gaussian's uncertainty seen from
a camera at c is sigmoid(Σ_k u_k·Y_k(d)), d = normalize(xyz − c), Y_k the colour SH's basis (no 0.5 offset). A run
trained without the uncertainty loss writes none: its u_sh never left the initial value, which a reader would take
for a measured, uniform uncertainty; such a PLY, or any plain 3DGS one, loads as a model with no uncertainty head.

Exports are in the data's own frame (`splatu.world_frame`), so the splats line up with the source
cameras and points; `load_ply` reads a file back as it is stored, in that frame.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from splatu.atomic import atomic_write
from splatu.errors import SplatuError
from splatu.model import GaussianModel, ModelConfig
from splatu.ply_header import read_vertex_layout
from splatu.sh import MAX_SH_DEGREE, num_sh_bases, sh_degree_of
from splatu.world_frame import WorldTransform, model_to_world

FORMAT_LINE = "format binary_little_endian 1.0"


def property_names(sh_rest_count: int, u_count: int) -> list[str]:
    """Vertex properties in file order for `sh_rest_count` colour-SH rest coefficients and `u_count` u_sh."""
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * sh_rest_count)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    names += [f"u_{i}" for i in range(u_count)]
    return names


def save_ply(model: GaussianModel, path: Path, to_world: WorldTransform, *, uncertainty: bool) -> None:
    """Write the model, moved by `to_world` out of training coordinates, as a binary little-endian 3DGS PLY,
    atomically (temporary file, then rename); with `uncertainty`, its own uncertainty head as `u_*` too. Pass False
    for a run trained without the uncertainty loss (its u_sh is the untrained initial value), so no reader takes
    that value for a measured one."""
    path = Path(path)
    if uncertainty and not model.has_uncertainty:
        raise ValueError("uncertainty=True, but the model has no uncertainty head to write")
    if not uncertainty:
        model = model.without_uncertainty()
    model = model_to_world(model, to_world)
    with torch.no_grad():
        n = len(model)
        rest = model.sh_rest.detach().float()
        columns = [
            model.means.detach().float(),
            torch.zeros(n, 3),
            model.sh_dc.detach().float().reshape(n, 3),
            rest.transpose(1, 2).reshape(n, -1),  # channel-major: f_rest_{c·(K−1)+k}
            model.opacity_logits.detach().float().reshape(n, 1),
            model.log_scales.detach().float(),
            model.quats.detach().float(),
            # the run's own head, or none (n, 0); extra (ablation) heads stay in checkpoints
            model.u_sh.detach().float()[..., :1].flatten(1),
        ]
        data = torch.cat(columns, dim=1).cpu().numpy().astype("<f4")
    if not np.isfinite(data).all():
        raise SplatuError("the model has NaN or Inf parameters", f"while writing {path}",
                          "export from an earlier, finite checkpoint")
    names = property_names(rest.shape[1], model.u_sh.shape[1] if model.has_uncertainty else 0)
    header = ["ply", FORMAT_LINE, f"element vertex {n}", *(f"property float {name}" for name in names), "end_header"]
    head = ("\n".join(header) + "\n").encode("ascii")
    atomic_write(path, lambda f: f.write(head + np.ascontiguousarray(data).tobytes()))


def _read_vertices(path: Path) -> np.ndarray:
    """The vertex records of a binary little-endian PLY whose vertex properties are all floats."""
    data = path.read_bytes()
    layout = read_vertex_layout(data, path, "pass a 3DGS .ply file")
    if layout.format != "binary_little_endian":
        raise SplatuError(f"PLY format is {layout.format}, not binary little endian", f"in {path}",
                          "export the PLY as binary_little_endian 1.0 (the 3DGS format)")
    for name, kind in layout.properties:
        if kind not in ("f4", "f8"):
            raise SplatuError(f"PLY property {name} is not a float (numpy kind {kind})", f"in {path}",
                              "store every vertex property as float")
    dtype = layout.dtype()
    start = layout.body_start + layout.offset
    if len(data) - start < layout.count * dtype.itemsize:
        raise SplatuError(f"PLY data holds {len(data) - start} bytes for {layout.count} vertices of "
                          f"{dtype.itemsize} bytes", f"in {path}", "the file is truncated; re-export it")
    return np.frombuffer(data, dtype=dtype, count=layout.count, offset=start)


def load_ply(path: Path, cfg: ModelConfig | None = None) -> GaussianModel:
    """Read a 3DGS PLY written by `save_ply` (or any 3DGS trainer) back into a model.

    The colour and uncertainty SH degrees come from the file (they override `cfg`, the model's other settings,
    ModelConfig()'s by default); a PLY without `u_*` properties (a plain 3DGS export, or a run trained without the
    uncertainty loss) loads as a model with no uncertainty head (`GaussianModel.has_uncertainty` is False), whose
    uncertainty cannot be rendered: none is invented for it.
    """
    path = Path(path)
    if not path.is_file():
        raise SplatuError("PLY file not found", f"at {path}", "check the path")
    vertices = _read_vertices(path)
    count = len(vertices)
    names = set(vertices.dtype.names or ())
    rest_count = sum(1 for name in names if name.startswith("f_rest_"))
    u_count = sum(1 for name in names if name.startswith("u_") and name[2:].isdigit())
    if rest_count % 3:
        raise SplatuError(f"PLY has {rest_count} f_rest properties, not a multiple of 3", f"in {path}",
                          "export all three colour channels")
    cfg = ModelConfig() if cfg is None else cfg
    u_degree = _degree_for(u_count, "u_", path) if u_count else cfg.u_sh_degree
    cfg = replace(cfg, sh_degree=_degree_for(rest_count // 3 + 1, "f_rest", path), u_sh_degree=u_degree)
    required = property_names(rest_count // 3, u_count)
    missing = [name for name in required if name not in names and name not in ("nx", "ny", "nz")]
    if missing:
        raise SplatuError(f"PLY lacks properties {missing[:4]}", f"in {path}", "pass a 3DGS .ply file")

    def columns(*keys: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([vertices[k].astype(np.float32) for k in keys], axis=1)).reshape(count, -1)

    rest = columns(*(f"f_rest_{i}" for i in range(rest_count))) if rest_count else torch.zeros(count, 0)
    tensors = {
        "means": columns("x", "y", "z"),
        "quats": columns("rot_0", "rot_1", "rot_2", "rot_3"),
        "log_scales": columns("scale_0", "scale_1", "scale_2"),
        "opacity_logits": columns("opacity").reshape(count),
        "sh_dc": columns("f_dc_0", "f_dc_1", "f_dc_2").reshape(count, 1, 3),
        "sh_rest": rest.reshape(count, 3, rest_count // 3).transpose(1, 2).contiguous(),
        "u_sh": columns(*(f"u_{i}" for i in range(u_count))).reshape(count, u_count, 1) if u_count
        else torch.zeros(count, num_sh_bases(cfg.u_sh_degree), 0),
    }
    for name, tensor in tensors.items():
        if not torch.isfinite(tensor).all():
            raise SplatuError(f"PLY property group {name} holds NaN or Inf", f"in {path}",
                              "re-export from a finite model")
    return GaussianModel(**tensors, cfg=cfg)


def _degree_for(coefficients: int, what: str, path: Path) -> int:
    """SH degree whose basis has exactly `coefficients` terms, or a one-line error naming the file."""
    try:
        degree = sh_degree_of(coefficients)
    except ValueError:
        degree = -1
    if 0 <= degree <= MAX_SH_DEGREE:
        return degree
    raise SplatuError(f"PLY {what} properties give {coefficients} SH coefficients, not (d+1)² for d ≤ 3",
                      f"in {path}", "export a 3DGS PLY with SH degree 0-3")
