"""PLY export/import: the standard 3DGS layout plus u_* properties, and clear errors on bad files."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from splatu.errors import SplatuError
from splatu.model import GaussianModel, ModelConfig
from splatu.ply import load_ply, property_names, save_ply
from splatu.world_frame import WorldTransform

IDENTITY = WorldTransform(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), 1.0)


def _random_model(sh_degree: int, u_degree: int, n: int = 37) -> GaussianModel:
    g = torch.Generator().manual_seed(sh_degree * 10 + u_degree)
    cfg = ModelConfig(sh_degree=sh_degree, u_sh_degree=u_degree)
    model = GaussianModel.empty_like_config(n, cfg)
    with torch.no_grad():
        for name in GaussianModel.PARAM_NAMES:
            param = getattr(model, name)
            param.copy_(torch.randn(param.shape, generator=g))
    return model


def _header(path) -> list[str]:
    lines = []
    with open(path, "rb") as f:
        while (line := f.readline().decode("ascii").strip()) != "end_header":
            lines.append(line)
    return lines


@pytest.mark.parametrize(("sh_degree", "u_degree"), [(3, 1), (0, 0), (2, 3)])
def test_round_trip_restores_every_parameter(tmp_path, sh_degree, u_degree):
    model = _random_model(sh_degree, u_degree)
    path = tmp_path / "point_cloud.ply"
    save_ply(model, path, IDENTITY, uncertainty=True)
    loaded = load_ply(path)  # degrees come from the file; the other settings ModelConfig()'s
    assert (loaded.cfg.sh_degree, loaded.cfg.u_sh_degree) == (sh_degree, u_degree)
    for name in GaussianModel.PARAM_NAMES:
        assert torch.equal(getattr(loaded, name), getattr(model, name)), name
    assert list(tmp_path.iterdir()) == [path]  # the temporary file was renamed away


def test_header_has_the_standard_3dgs_properties_in_order(tmp_path):
    model = _random_model(3, 1, n=5)
    path = tmp_path / "m.ply"
    save_ply(model, path, IDENTITY, uncertainty=True)
    header = _header(path)
    assert header[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    names = [line.split()[-1] for line in header[3:]]
    assert all(line.startswith("property float ") for line in header[3:])
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert names[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
                          "u_0", "u_1", "u_2", "u_3"]
    assert path.stat().st_size == len(path.read_bytes().split(b"end_header\n", 1)[0]) + 11 + 5 * 66 * 4


def test_f_rest_is_channel_major_as_3dgs_viewers_expect(tmp_path):
    model = _random_model(1, 1, n=2)
    with torch.no_grad():
        for k in range(3):
            for c in range(3):
                model.sh_rest[:, k, c] = 10 * c + k  # coefficient k of channel c
    path = tmp_path / "m.ply"
    save_ply(model, path, IDENTITY, uncertainty=True)
    names = property_names(3, 4)
    data = np.frombuffer(path.read_bytes().split(b"end_header\n", 1)[1], dtype="<f4").reshape(2, len(names))
    row = dict(zip(names, data[0], strict=True))
    assert [row[f"f_rest_{i}"] for i in range(9)] == [0, 1, 2, 10, 11, 12, 20, 21, 22]


def _header_names(path) -> list[str]:
    return [line.split()[-1] for line in _header(path) if line.startswith("property")]


def test_plain_3dgs_ply_without_u_loads_with_no_uncertainty_rather_than_an_invented_one(tmp_path):
    """A PLY without u_* loaded as the config's initial u everywhere (sigmoid(2) = 0.88), which a caller rendered as
    if measured; it is a model with no uncertainty head now, and rendering its uncertainty is refused."""
    model = _random_model(1, 1, n=4)
    path = tmp_path / "m.ply"
    save_ply(model, path, IDENTITY, uncertainty=True)
    header, body = path.read_bytes().split(b"end_header\n", 1)
    names = property_names(3, 4)
    data = np.frombuffer(body, dtype="<f4").reshape(4, len(names))[:, :-4]
    lines = [line for line in header.decode().split("\n") if not line.startswith("property float u_")]
    (tmp_path / "plain.ply").write_bytes(("\n".join(lines) + "end_header\n").encode() + data.tobytes())
    loaded = load_ply(tmp_path / "plain.ply", ModelConfig(u_sh_degree=2, u_init_logit=1.5))
    assert not loaded.has_uncertainty and loaded.u_sh.shape[-1] == 0
    assert model.has_uncertainty
    with pytest.raises(SplatuError, match="has no uncertainty"), torch.no_grad():
        loaded.uncertainty(torch.randn(4, 3))
    assert torch.equal(loaded.means, model.means) and torch.equal(loaded.sh_rest, model.sh_rest)


def test_a_model_whose_uncertainty_was_not_trained_exports_no_u_and_round_trips(tmp_path):
    """A run trained without the uncertainty loss wrote u_0..u_15 at their initial value (u_0 = 7.09, the rest 0),
    which reads as a measured, uniform uncertainty; with uncertainty=False no u_* property is written."""
    model = _random_model(2, 3, n=6)
    save_ply(model, tmp_path / "plain.ply", IDENTITY, uncertainty=False)
    names = _header_names(tmp_path / "plain.ply")
    assert names == property_names(8, 0) and not any(name.startswith("u_") for name in names)
    loaded = load_ply(tmp_path / "plain.ply", ModelConfig())
    assert not loaded.has_uncertainty and loaded.cfg.sh_degree == 2
    for name in GaussianModel.PARAM_NAMES[:-1]:
        assert torch.equal(getattr(loaded, name), getattr(model, name)), name
    save_ply(loaded, tmp_path / "again.ply", IDENTITY, uncertainty=False)  # the loaded model exports the same file
    assert (tmp_path / "again.ply").read_bytes() == (tmp_path / "plain.ply").read_bytes()
    with pytest.raises(ValueError, match="no uncertainty head"):
        save_ply(loaded, tmp_path / "never.ply", IDENTITY, uncertainty=True)
    assert not (tmp_path / "never.ply").exists()


def test_bad_files_are_user_errors(tmp_path):
    good = tmp_path / "good.ply"
    save_ply(_random_model(1, 1, n=6), good, IDENTITY, uncertainty=True)
    raw = good.read_bytes()
    cases = {
        "missing.ply": None,
        "truncated.ply": raw[:-10],
        "ascii.ply": raw.replace(b"binary_little_endian", b"ascii"),
        "not_a_ply.ply": b"hello\n",
        "nan.ply": raw[: raw.index(b"end_header\n") + 11] + np.full(6 * 30, np.nan, dtype="<f4").tobytes(),
    }
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(SplatuError):
            load_ply(path, ModelConfig())


def test_saving_a_non_finite_model_refuses_and_leaves_the_old_file(tmp_path):
    path = tmp_path / "m.ply"
    model = _random_model(0, 1, n=3)
    save_ply(model, path, IDENTITY, uncertainty=True)
    before = path.read_bytes()
    with torch.no_grad():
        model.means[1, 0] = float("inf")
    with pytest.raises(SplatuError):
        save_ply(model, path, IDENTITY, uncertainty=True)
    assert path.read_bytes() == before


def test_a_model_with_extra_uncertainty_heads_exports_only_its_own(tmp_path):
    cfg = ModelConfig(sh_degree=1, u_sh_degree=2)
    model = GaussianModel.empty_like_config(12, cfg, u_heads=3)
    with torch.no_grad():
        for name in GaussianModel.PARAM_NAMES:
            getattr(model, name).copy_(torch.randn(getattr(model, name).shape, generator=torch.Generator()))
    save_ply(model, tmp_path / "heads.ply", IDENTITY, uncertainty=True)
    loaded = load_ply(tmp_path / "heads.ply", cfg)
    assert loaded.u_sh.shape == (12, 9, 1)
    assert torch.equal(loaded.u_sh, model.u_sh[..., :1])


def test_the_u_properties_give_the_uncertainty_by_the_formula_the_readme_states(tmp_path):
    """A reader with the PLY alone computes U = sigmoid(Σ_k u_k·Y_k(d)), d from a camera in the data's frame to the
    Gaussian's x y z (README, Outputs): the same U the model renders, the file being in the data's frame (rotated,
    moved and scaled here) and the model in its normalised one."""
    from splatu.sh import sh_basis

    model = _random_model(2, 2)
    angle = 0.7
    rotation = torch.tensor([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0],
                             [0.0, 0.0, 1.0]], dtype=torch.float64)
    frame = WorldTransform(rotation, torch.tensor([3.0, -1.0, 2.0], dtype=torch.float64), 2.5)
    save_ply(model, tmp_path / "u.ply", frame, uncertainty=True)
    head, body = (tmp_path / "u.ply").read_bytes().split(b"end_header\n", 1)
    names = [line.split()[-1] for line in head.decode().splitlines() if line.startswith("property")]
    rows = np.frombuffer(body, dtype=np.dtype([(n, "<f4") for n in names]))
    camera_normalised = torch.tensor([0.3, -2.0, 1.1], dtype=torch.float64)
    camera_data = frame.points(camera_normalised[None])[0]
    xyz = torch.from_numpy(np.stack([rows["x"], rows["y"], rows["z"]], axis=1)).double()
    d = torch.nn.functional.normalize(xyz - camera_data, dim=1)
    u = torch.from_numpy(np.stack([rows[f"u_{k}"] for k in range(9)], axis=1)).double()
    from_file = torch.sigmoid((u * sh_basis(d, 2)).sum(dim=1))
    rendered = model.uncertainty(model.means.detach().double() - camera_normalised).double()
    assert torch.allclose(from_file, rendered, atol=1e-5)


def _with_element_before_vertices(raw: bytes) -> bytes:
    """The same PLY with a 2-record `camera` element (two floats each) declared, and stored, before the vertices."""
    head, body = raw.split(b"end_header\n", 1)
    head = head.replace(b"element vertex", b"element camera 2\nproperty float a\nproperty float b\nelement vertex")
    return head + b"end_header\n" + np.arange(4, dtype="<f4").tobytes() + body


def test_elements_before_or_after_the_vertices_do_not_shift_them(tmp_path):
    """The reader assumed the vertices came first: an element before them was read as vertex data, silently."""
    model = _random_model(1, 1, n=5)
    save_ply(model, tmp_path / "plain.ply", IDENTITY, uncertainty=True)
    raw = (tmp_path / "plain.ply").read_bytes()
    before = tmp_path / "before.ply"
    before.write_bytes(_with_element_before_vertices(raw))
    after = tmp_path / "after.ply"
    after.write_bytes(raw.replace(b"end_header\n", b"element face 1\nproperty list uchar int vertex_indices\n"
                                  b"end_header\n") + bytes([3]) + np.arange(3, dtype="<i4").tobytes())
    for path in (before, after):
        loaded = load_ply(path, ModelConfig())
        for name in GaussianModel.PARAM_NAMES:
            assert torch.equal(getattr(loaded, name), getattr(model, name)), (path.name, name)


def test_malformed_headers_are_user_errors(tmp_path):
    save_ply(_random_model(1, 1, n=2), tmp_path / "good.ply", IDENTITY, uncertainty=True)
    raw = (tmp_path / "good.ply").read_bytes()
    cases = {
        "count.ply": raw.replace(b"element vertex 2", b"element vertex 2x"),
        "no_count.ply": raw.replace(b"element vertex 2", b"element vertex"),
        "list_before.ply": raw.replace(b"element vertex", b"element face 1\nproperty list uchar int idx\n"
                                       b"element vertex"),
        "int_property.ply": raw.replace(b"property float opacity", b"property uchar opacity"),
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(SplatuError, match=re.escape(str(tmp_path / name))):
            load_ply(tmp_path / name, ModelConfig())


def test_f_rest_properties_that_are_not_a_multiple_of_three_are_named(tmp_path):
    """f_rest holds every red coefficient, then every green, then every blue: 25 of them cannot be three channels."""
    n = 4
    names = [*property_names(8, 1), "f_rest_24"]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
              *(f"property float {name}" for name in names), "end_header"]
    path = tmp_path / "odd.ply"
    path.write_bytes(("\n".join(header) + "\n").encode("ascii") + np.zeros((n, len(names)), "<f4").tobytes())
    with pytest.raises(SplatuError, match="PLY has 25 f_rest properties, not a multiple of 3"):
        load_ply(path, ModelConfig())


def test_an_export_output_that_is_a_folder_is_told_a_file_in_it(tmp_path):
    """`splatu export --output DIR` was told "pass a path such as DIR.ply", a file beside the folder meant."""
    from splatu.export import export_path

    with pytest.raises(SplatuError) as caught:
        export_path(tmp_path, tmp_path / "checkpoints" / "step-0000300.pt", tmp_path)
    assert caught.value.fix == f"pass a path such as {tmp_path}/splat-step-0000300.ply"


@pytest.mark.parametrize(("earlier", "written", "said"), [
    (True, False, "no export written; the earlier export in {} is unchanged"),
    (False, False, "no export written to {}"),
    (True, True, "the new export was already written in full to {}")])
def test_a_ctrl_c_during_export_says_what_it_left(tmp_path, monkeypatch, capsys, earlier, written, said):
    """It said only "interrupted"; the PLY is renamed into place whole, so the line says whether that happened."""
    from types import SimpleNamespace

    from splatu import export
    from splatu.cli import entrypoint

    output = tmp_path / "splat.ply"
    if earlier:
        output.write_bytes(b"earlier export")

    def stopped(model, path, frame, uncertainty):
        if written:  # as a Ctrl-C landing just after the rename
            path.with_name("new.ply").write_bytes(b"new export")
            path.with_name("new.ply").replace(path)
        raise KeyboardInterrupt

    monkeypatch.setattr(export, "resolve_checkpoint", lambda load: tmp_path / "step-0000001.pt")
    monkeypatch.setattr(export, "load_run", lambda checkpoint: SimpleNamespace(
        model=None, frame=object(), config=SimpleNamespace(uncertainty=SimpleNamespace(off=False))))
    monkeypatch.setattr(export, "save_ply", stopped)
    with pytest.raises(SystemExit) as stop:
        entrypoint(["export", "--load", str(tmp_path), "--output", str(output)])
    assert stop.value.code == 130
    assert capsys.readouterr().err == f"interrupted: {said.format(output)}\n"
    assert (output.read_bytes() if output.exists() else None) == (
        b"new export" if written else b"earlier export" if earlier else None)
