"""What render-uncertainty's files say: colour bars of the maps that exist, a depth PNG that reads back."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest

from splatu.cli import entrypoint
from splatu.data.images import read_image
from splatu.render_uncertainty import RenderedView, RenderUncertaintyConfig, write_render
from splatu.uncertainty_options import UncertaintyOptions


def _config(views: str) -> RenderUncertaintyConfig:
    """The options as the command hands them to write_render: the method resolved for the run (`for_run`)."""
    return RenderUncertaintyConfig(views=views, uncertainty=UncertaintyOptions(method="ours"))


def _view(name: str, with_gt: bool) -> RenderedView:
    """A 2x3 view: depths 2, 3 and 4 (data units) fully covered, 2.5 half covered, and two pixels of nothing."""
    depth = np.array([[2.0, 3.0, 4.0], [2.5, 0.0, 0.0]])
    alpha = np.array([[1.0, 1.0, 1.0], [0.5, 0.0, 0.0]])
    maps = {"rgb": np.full((2, 3, 3), 0.5), "depth": depth, "alpha": alpha, "uncertainty": np.full((2, 3), 0.3)}
    return RenderedView(name, maps, gt=np.zeros((2, 3, 3)) if with_gt else None, elevation_degrees=0.0)


def _write(tmp_path, views: str, with_gt: bool) -> dict:
    write_render(tmp_path, [_view("a", with_gt), _view("b", with_gt)], _config(views),
                 {"train_step_seconds": None, "train_wall_seconds": None}, 0.0, [0.1, 0.1])
    return json.loads((tmp_path / "render.json").read_text())


def test_an_orbit_writes_no_error_colour_bar_as_it_has_no_error_map(tmp_path):
    """colorbar_error.png was written for an orbit, which has no ground truth and so no error map."""
    _write(tmp_path / "orbit", "orbit", with_gt=False)
    assert sorted(path.name for path in (tmp_path / "orbit").glob("colorbar_*.png")) == [
        "colorbar_depth.png", "colorbar_uncertainty.png"]
    _write(tmp_path / "eval", "eval", with_gt=True)
    assert (tmp_path / "eval" / "colorbar_error.png").is_file()


def test_render_json_gives_the_depth_pngs_scale_and_nothing_drawn_is_black(tmp_path):
    """render.json recorded the uncertainty PNGs' scale only; and alpha-0 pixels, raw depth 0, took the colour of the
    nearest depth."""
    record = _write(tmp_path, "orbit", with_gt=False)
    lo, hi = record["depth_scale"]
    # the 1st to 99th percentile of the pixels at least half covered, in both views
    assert (lo, hi) == tuple(np.percentile([2.0, 3.0, 4.0, 2.0, 3.0, 4.0], (1.0, 99.0)))
    png = read_image(tmp_path / "png" / "a_depth.png")[..., :3]
    viridis = matplotlib.colormaps["viridis"]
    for row, col, depth in ((0, 0, 2.0), (0, 1, 3.0), (0, 2, 4.0)):  # read back on the recorded scale, clamped
        expected = np.round(np.array(viridis(np.clip((depth - lo) / (hi - lo), 0.0, 1.0))[:3]) * 255.0)
        np.testing.assert_allclose(png[row, col], expected, atol=1)
    assert (png[1, 1:] == 0).all()  # nothing drawn: black, a colour viridis never takes
    assert not (png[0, 0] == 0).all()  # the nearest depth is not
    assert np.load(tmp_path / "npy" / "a_depth.npy")[1, 1] == 0.0  # the raw map keeps 0 where alpha is 0


def test_a_few_floaters_do_not_set_the_depth_scale(tmp_path):
    """The scale ran from the nearest to the farthest covered pixel, so one floater far behind (fox: 24.7 with half the
    pixels nearer than 4.5) left the scene one dark colour; the 1st to 99th percentiles leave it out."""
    depth = np.linspace(2.0, 4.0, 400).reshape(20, 20)
    depth[0, 0] = 1000.0
    maps = {"rgb": np.full((20, 20, 3), 0.5), "depth": depth, "alpha": np.ones((20, 20)),
            "uncertainty": np.full((20, 20), 0.3)}
    write_render(tmp_path, [RenderedView("a", maps, gt=None, elevation_degrees=0.0)],
                 _config("orbit"), {"train_step_seconds": None, "train_wall_seconds": None},
                 0.0, [0.1])
    lo, hi = json.loads((tmp_path / "render.json").read_text())["depth_scale"]
    assert 2.0 <= lo < 2.1 and 3.9 < hi <= 4.0
    maps["depth"][0, :] = np.inf  # non-finite depths (5% of the pixels) gave a scale of NaN, which colours nothing
    write_render(tmp_path / "inf", [RenderedView("a", maps, gt=None, elevation_degrees=0.0)],
                 _config("orbit"), {"train_step_seconds": None, "train_wall_seconds": None},
                 0.0, [0.1])
    lo, hi = json.loads((tmp_path / "inf" / "render.json").read_text())["depth_scale"]
    assert 2.1 <= lo < 2.2 and 3.9 < hi <= 4.0  # the finite depths' percentiles (the first row, 2.0-2.1, is gone)


def _stub_run_and_scene(monkeypatch, tmp_path) -> list[str]:
    """`splatu render-uncertainty` arguments that render views a and b of a stubbed run into tmp_path/render."""
    from splatu import render_uncertainty as R

    run_info = SimpleNamespace(member_steps=None, models=[None],
                               config=SimpleNamespace(data=SimpleNamespace(downscale=1)))
    scene = SimpleNamespace(train=SimpleNamespace(cameras=[], names=[]))
    spec = SimpleNamespace(note=None, cameras=[SimpleNamespace(world_to_camera=None, name=n) for n in "ab"],
                           depth_unit=1.0, orbit=None)
    monkeypatch.setattr(R, "pinned_load", lambda load, written: load)
    monkeypatch.setattr(R, "_load", lambda load, options: (run_info, options.for_run(False)))
    monkeypatch.setattr(R, "_setup", lambda *args: (scene, SimpleNamespace(source=None, setup_seconds=0.0)))
    monkeypatch.setattr(R, "view_spec", lambda *args: spec)
    monkeypatch.setattr(R, "render_views", lambda source, spec: ([_view("a", True), _view("b", True)], [0.1, 0.1]))
    nearest = SimpleNamespace(_asdict=lambda: {"name": "t.png", "angle_degrees": 1.0, "distance": 0.1})
    monkeypatch.setattr(R, "nearest_training_views", lambda *args: [nearest] * 2)
    monkeypatch.setattr(R, "train_timing", lambda run: {"train_step_seconds": None, "train_wall_seconds": None})
    return ["render-uncertainty", "--load", str(tmp_path), "--output", str(tmp_path / "render")]


def _files(folder: Path) -> dict[Path, bytes]:
    return {path.relative_to(folder): path.read_bytes() for path in folder.rglob("*") if path.is_file()}


@pytest.mark.parametrize("earlier", [True, False])
def test_a_ctrl_c_while_writing_says_that_no_render_was_written(tmp_path, monkeypatch, capsys, earlier):
    """It said only "interrupted", though the render is staged and swapped in whole: the earlier one is intact."""
    from splatu import render_uncertainty as R

    argv = _stub_run_and_scene(monkeypatch, tmp_path)
    out = tmp_path / "render"
    if earlier:
        entrypoint(argv)
    before = _files(out) if earlier else None

    def stopped(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(R, "write_view", stopped)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        entrypoint(argv)
    assert stop.value.code == 130
    said = (f"no render written; the earlier render in {out} is unchanged" if earlier
            else f"no render written to {out}")
    assert capsys.readouterr().err == f"interrupted: {said}\n"
    if earlier:
        assert _files(out) == before
    else:
        assert not out.exists()


def test_a_ctrl_c_during_the_swap_says_the_new_render_is_whole(tmp_path, monkeypatch, capsys):
    """A stop during the swap waits for its end: the new render is then in place, and the line says so."""
    from splatu import render_uncertainty as R

    argv = _stub_run_and_scene(monkeypatch, tmp_path)
    entrypoint(argv)
    remove = R.remove

    def ctrl_c_then_remove(paths):
        if (tmp_path / "render" / R.SWAPPING).exists():  # in the swap; the first call clears leftover staging
            os.kill(os.getpid(), signal.SIGINT)
        remove(paths)

    monkeypatch.setattr(R, "remove", ctrl_c_then_remove)
    monkeypatch.setattr(R, "write_view", lambda out, view, scales: (out / "png" / f"{view.name}_new.png").touch())
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        entrypoint(argv)
    assert stop.value.code == 130
    out = tmp_path / "render"
    assert capsys.readouterr().err == f"interrupted: the new render was already written in full to {out}\n"
    assert sorted(path.name for path in (out / "png").iterdir()) == ["a_new.png", "b_new.png"]
