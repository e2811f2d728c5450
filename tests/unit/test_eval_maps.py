"""`splatu eval-ause --maps` round trip on tiny directories, and its one-line errors."""

import dataclasses
import errno
import json
import multiprocessing
import os
import re
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest

from splatu import ause as A
from splatu import maps
from splatu.cli import entrypoint
from splatu.errors import SplatuError
from splatu.eval_ause import RANDOM_CURVE, evaluate_maps, score_entries
from splatu.maps import MapEntry, entry_names, file_stems, read_entry, safe_name, write_entry
from splatu.uncertainty_options import UncertaintyOptions


def _tiny_maps(root: Path, n: int = 3, size: tuple[int, int] = (24, 32)) -> dict[str, np.ndarray]:
    """Views whose uncertainty is exactly the MAE error (so AUSE-MAE must be 0), plus a half mask."""
    rng = np.random.default_rng(0)
    errors = {}
    for i in range(n):
        gt = rng.random((*size, 3))
        rgb = np.clip(gt + rng.normal(0, 0.2, gt.shape), 0, 1)
        unobserved = np.zeros(size, bool)
        unobserved[:, : size[1] // 2] = True
        entry = MapEntry(f"view_{i}", rgb, gt, np.zeros(size), unobserved=unobserved)
        write_entry(root, entry)
        stored = read_entry(root, entry.name)  # the 16-bit round trip quantises the images a little
        errors[entry.name] = A.pixel_errors(stored.rgb, stored.gt)
        np.save(root / "uncertainty" / f"{entry.name}.npy", errors[entry.name] + 10.0 * unobserved)
    return errors


def _run(*args: str) -> None:
    entrypoint(["eval-ause", *args])


def test_maps_round_trip_through_the_cli(tmp_path, capsys):
    _tiny_maps(tmp_path / "maps")
    out = tmp_path / "scores" / "ause.json"
    _run("--maps", str(tmp_path / "maps"), "--output", str(out))
    report = json.loads(out.read_text())
    assert set(report["per_image"]) == {"view_0", "view_1", "view_2"}
    mean = report["mean"]
    # u = e + 10·unobserved (e ≤ 3) orders the observed half by error but ranks all unobserved pixels first
    assert 0.0 < mean["ause_mae"] < 0.5 * mean["random_ause_mae"]
    assert mean["oracle_ausc_mae"] <= mean["ausc_mae"] < mean["random_ausc_mae"]
    assert {f"{k}_{m}" for k in ("ausc", "random_ausc", "oracle_ausc") for m in ("mae", "rmse")} <= set(mean)
    assert set(report["per_image"]["view_0"]) == set(mean)
    assert mean["auroc_unobserved"] == pytest.approx(1.0)
    assert {"ause_rmse", "ause_mae_start_norm", "random_ause_mae_start_norm"} <= set(mean)
    assert report["caption"] == A.CAPTION
    assert out.with_suffix(".png").is_file()
    printed = capsys.readouterr().out
    assert "mean over 3 images" in printed and "view_0" not in printed  # the per-image rows only on request
    _run("--maps", str(tmp_path / "maps"), "--output", str(out), "--per-image")
    printed = capsys.readouterr().out
    assert all(f"view_{i}" in printed for i in range(3))
    assert json.loads(out.read_text())["per_image"] == report["per_image"]


def test_maps_round_trip_in_a_folder_whose_name_is_not_utf8(tmp_path):
    """cv2.imwrite and cv2.imread crashed the process (a segfault) on such a path, and a run's folder is named
    after its scene's folder, whatever bytes that name holds."""
    root = Path(os.fsdecode(os.fsencode(tmp_path) + b"/maps\xff"))
    _tiny_maps(root, n=1)
    assert read_entry(root, "view_0").rgb.shape == (24, 32, 3)


def test_oracle_maps_score_zero_and_masks_restrict_pixels(tmp_path):
    root = tmp_path / "maps"
    errors = _tiny_maps(root, n=1)
    np.save(root / "uncertainty" / "view_0.npy", errors["view_0"])
    (root / "unobserved" / "view_0.png").unlink()
    _run("--maps", str(root))
    report = json.loads((root / "ause.json").read_text())
    assert report["mean"]["ause_mae"] == pytest.approx(0.0, abs=1e-12)
    assert report["mean"]["auroc_unobserved"] is None
    # an 8-bit mask written by another tool: only the left quarter is scored, where u is noise
    np.save(root / "uncertainty" / "view_0.npy", np.where(np.arange(32) < 8, np.random.rand(24, 32), errors["view_0"]))
    (root / "mask").mkdir()
    mask = np.zeros((24, 32), np.uint8)
    mask[:, :8] = 255
    cv2.imwrite(str(root / "mask" / "view_0.png"), mask)
    _run("--maps", str(root))
    assert json.loads((root / "ause.json").read_text())["mean"]["ause_mae"] > 0.1
    cv2.imwrite(str(root / "mask" / "view_0.png"), np.zeros((24, 32), np.uint8))
    with pytest.raises(SplatuError, match="selects no pixels"):
        entrypoint(["eval-ause", "--maps", str(root), "--debug"])


def _one_line_error(capsys, *args: str) -> str:
    with pytest.raises(SystemExit) as exc:
        _run(*args)
    assert exc.value.code == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")
    return lines[0]


def test_bad_maps_are_one_line_errors(tmp_path, capsys):
    root = tmp_path / "maps"
    _tiny_maps(root, n=2)
    (root / "gt" / "view_1.png").unlink()
    assert "gt/" in _one_line_error(capsys, "--maps", str(root))
    cv2.imwrite(str(root / "gt" / "view_1.png"), np.zeros((10, 10, 3), np.uint8))
    assert "ground truth is 10x10" in _one_line_error(capsys, "--maps", str(root))
    (root / "gt" / "view_1.png").write_bytes(b"not a png")
    line = _one_line_error(capsys, "--maps", str(root))
    assert "cannot decode image" in line and line.endswith("or remove the view from every folder")
    write_entry(root, read_entry(root, "view_0"))
    np.save(root / "uncertainty" / "view_0.npy", np.full((24, 32), np.nan))
    assert "NaN" in _one_line_error(capsys, "--maps", str(root))
    np.save(root / "uncertainty" / "view_0.npy", np.zeros((5, 7)))
    assert "uncertainty map is 7x5 float64, but the render is 32x24" in _one_line_error(capsys, "--maps", str(root))
    np.save(root / "uncertainty" / "view_0.npy", np.array([{"a": 1}]), allow_pickle=True)
    line = _one_line_error(capsys, "--maps", str(root))
    assert "not a valid .npy array of numbers" in line and "allow_pickle" not in line
    with open(root / "uncertainty" / "view_0.npy", "wb") as f:  # an .npz under a .npy name
        np.savez(f, u=np.zeros((24, 32)))
    assert "not a valid .npy array of numbers" in _one_line_error(capsys, "--maps", str(root))
    np.save(root / "uncertainty" / "view_0.npy", np.zeros((24, 32), bool))
    assert "not a valid .npy array of numbers" in _one_line_error(capsys, "--maps", str(root))
    (root / "unobserved" / "view_1.png").unlink()  # AUROC-unobserved used to average over view_0 alone
    assert "1 views have no unobserved/ map (e.g. 'view_1')" in _one_line_error(capsys, "--maps", str(root))
    (root / "unobserved" / "view_0.png").unlink()  # none at all is fine (AUROC-unobserved is not reported)
    (root / "mask").mkdir()  # a mask for some views only: the others were scored on every pixel, without a word
    cv2.imwrite(str(root / "mask" / "view_0.png"), np.full((24, 32), 255, np.uint8))
    assert "1 views have no mask/ map (e.g. 'view_1')" in _one_line_error(capsys, "--maps", str(root))
    (root / "mask" / "view_0.png").unlink()
    (root / "uncertainty" / "view_1.npy").unlink()  # it used to score view_0 alone, without a word
    assert "1 renders have no uncertainty map (e.g. 'view_1')" in _one_line_error(capsys, "--maps", str(root))
    assert "not found" in _one_line_error(capsys, "--maps", str(tmp_path / "absent"))
    assert "exactly one" in _one_line_error(capsys, "--load", str(tmp_path), "--maps", str(root))


def test_maps_pointed_at_a_render_folder_names_its_maps_folder(tmp_path, capsys):
    """render-uncertainty writes the maps layout in <render>/maps; --maps <render> said only how to lay out a maps
    directory, not that the render holds one."""
    _tiny_maps(tmp_path / "render" / "maps", n=1)
    line = _one_line_error(capsys, "--maps", str(tmp_path / "render"))
    assert "has no rgb/ folder" in line and f"pass --maps {tmp_path / 'render' / 'maps'}" in line


def test_the_maps_folder_a_render_folder_names_is_quoted_for_a_shell(tmp_path, capsys):
    """A render under a path with a space ("my runs") was named bare, and `--maps` pasted from it took only the part
    before the space."""
    _tiny_maps(tmp_path / "my runs" / "render" / "maps", n=1)
    line = _one_line_error(capsys, "--maps", str(tmp_path / "my runs" / "render"))
    assert f"pass --maps '{tmp_path / 'my runs' / 'render' / 'maps'}', the maps of this render" in line

def test_maps_pointed_at_a_runs_uncertainty_folder_names_the_renders_maps_beneath(tmp_path, capsys):
    """--maps RUN/uncertainty (or RUN itself) said only how to lay out a maps directory: the renders' maps are two
    and three levels down (RUN/uncertainty/<label>/maps), and a run is scored with --load."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for label in ("ours-eval", "spread-eval", "angle-eval", "visibility-eval"):
        _tiny_maps(run / "uncertainty" / label / "maps", n=1)
    first_two = ", ".join(str(run / "uncertainty" / f"{label}-eval" / "maps") for label in ("angle", "ours"))
    line = _one_line_error(capsys, "--maps", str(run / "uncertainty"))
    assert line.endswith(f"pass --maps with the maps of a render beneath it: {first_two} or "
                         f"{run / 'uncertainty' / 'spread-eval' / 'maps'} (3 of 4)")
    line = _one_line_error(capsys, "--maps", str(run))
    assert f"beneath it: {first_two} or" in line and line.endswith(
        f"(3 of 4), or --load {run} to render this run's eval views and score them")


def test_options_of_load_are_refused_with_maps_rather_than_ignored(tmp_path, capsys):
    root = tmp_path / "maps"
    _tiny_maps(root, n=1)
    for args in (["--seed", "1"], ["--method", "random"], ["--fisher-probes", "4"], ["--density-aware"],
                 ["--head", "degree=1"], ["--data", "poster"], ["--method", "ours"]):
        line = _one_line_error(capsys, "--maps", str(root), *args)
        assert f"{args[0]} only applies with --load" in line and f"drop {args[0]}" in line
    assert "--fisher-probes --seed only apply" in _one_line_error(capsys, "--maps", str(root), "--fisher-probes", "3",
                                                                  "--seed", "2")
    assert not (root / "ause.json").exists()
    _run("--maps", str(root), "--seed", "0")  # a default value changes nothing, so it is accepted
    assert (root / "ause.json").is_file()


def test_rgba_ground_truth_is_composited_on_the_background_the_method_renders_on():
    """An RGBA target loaded on white is scored on the render's (black) background, as training does."""
    import torch

    from splatu.baselines.model_sources import OursSource
    from splatu.model import GaussianModel, ModelConfig
    from splatu.render_uncertainty import ViewSpec, render_views
    from tests.unit.test_trainer import tiny_scene

    views = tiny_scene(n_train=1, n_eval=2).eval
    rgb, alpha = 0.6, 0.25
    views.images = torch.full_like(views.images, rgb * alpha + 1.0 * (1 - alpha))  # composited on white at load
    views.alphas = torch.full(views.images.shape[:3], alpha)
    empty = GaussianModel.empty_like_config(0, ModelConfig(sh_degree=0))
    source = OursSource(empty, 0, torch.zeros(3))
    rendered, _ = render_views(source, ViewSpec(views.cameras, views.names, views, [0, 1]))
    for view in rendered:
        np.testing.assert_allclose(view.gt, rgb * alpha, atol=1e-6)
        np.testing.assert_allclose(view.maps["rgb"], 0.0, atol=1e-12)


def test_a_view_its_mask_excludes_entirely_is_left_out_of_the_maps_not_fatal():
    from splatu.render_uncertainty import RenderedView, map_entries

    rng = np.random.default_rng(1)
    views = []
    for name, keep in (("kept", True), ("masked_out", False)):
        maps = {"rgb": rng.random((6, 8, 3)), "uncertainty": rng.random((6, 8))}
        views.append(RenderedView(name, maps, gt=rng.random((6, 8, 3)), mask=np.full((6, 8), keep)))
    assert [entry.name for entry in map_entries(views)] == ["kept"]


def test_eval_ause_says_so_when_every_eval_view_is_masked_out(tmp_path, monkeypatch):
    """It used to render, write no maps, then report the maps folder as missing."""
    from types import SimpleNamespace

    from splatu import render_uncertainty as R

    blank = R.RenderedView("v", {"rgb": np.zeros((4, 4, 3)), "uncertainty": np.zeros((4, 4))},
                           gt=np.zeros((4, 4, 3)), mask=np.zeros((4, 4), bool))
    scene = SimpleNamespace(eval=None, train=None)
    monkeypatch.setattr(R, "_load", lambda load, options: (SimpleNamespace(member_steps=None), options.for_run(False)))
    monkeypatch.setattr(R, "_setup", lambda *args: (scene, SimpleNamespace(source=None)))
    monkeypatch.setattr(R, "view_spec", lambda *args: None)
    monkeypatch.setattr(R, "render_views", lambda source, spec: ([blank], [0.1]))
    with pytest.raises(SplatuError, match="no eval view has a pixel to score"):
        R.render_eval_maps(tmp_path, UncertaintyOptions())
    assert not (tmp_path / "uncertainty" / "ours-eval" / "maps").exists()


def test_an_output_that_is_not_json_is_refused_before_the_plot_could_overwrite_it(tmp_path, capsys):
    _tiny_maps(tmp_path / "maps", n=1)
    line = _one_line_error(capsys, "--maps", str(tmp_path / "maps"), "--output", str(tmp_path / "scores.png"))
    assert "--output must name a .json file" in line and "scores.json" in line
    assert not (tmp_path / "scores.png").exists()


def test_an_output_whose_plot_path_is_a_folder_is_refused_before_anything_is_written(tmp_path, capsys):
    """The JSON used to be written, then the plot raised IsADirectoryError with a traceback."""
    _tiny_maps(tmp_path / "maps", n=1)
    (tmp_path / "scores.png").mkdir()
    line = _one_line_error(capsys, "--maps", str(tmp_path / "maps"), "--output", str(tmp_path / "scores.json"))
    assert "is a folder" in line and "scores.png" in line
    assert not (tmp_path / "scores.json").exists()

def test_a_full_disk_while_the_plot_is_written_is_one_line(tmp_path, capsys, monkeypatch):
    """matplotlib raises the disk's OSError as it is: it was a traceback after the JSON was written."""
    from matplotlib.figure import Figure

    _tiny_maps(tmp_path / "maps", n=1)

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", disk_full)
    line = _one_line_error(capsys, "--maps", str(tmp_path / "maps"))
    assert "could not write ause.png (No space left on device)" in line and "free space" in line


def test_scores_that_cannot_be_written_leave_no_folder_made_for_them(tmp_path, capsys, monkeypatch):
    """--output's folders are made for the JSON and plot: a full disk there left them empty."""
    from matplotlib.figure import Figure

    _tiny_maps(tmp_path / "maps", n=1)

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", disk_full)
    _one_line_error(capsys, "--maps", str(tmp_path / "maps"), "--output", str(tmp_path / "new" / "deep" / "a.json"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]

def test_an_rgba_mask_is_read_by_its_colour_or_by_its_alpha_when_the_colour_is_uniform(tmp_path):
    root = tmp_path / "maps"
    _tiny_maps(root, n=1)
    (root / "mask").mkdir()
    top_half = np.zeros((24, 32), bool)
    top_half[:12] = True
    bgra = np.zeros((24, 32, 4), np.uint8)
    bgra[..., 3] = 255  # opaque everywhere: the colour is the mask (alpha used to make every pixel count)
    bgra[top_half, :3] = 255
    cv2.imwrite(str(root / "mask" / "view_0.png"), bgra)
    assert np.array_equal(read_entry(root, "view_0").mask, top_half)
    bgra[..., :3] = 255  # white everywhere: the alpha is the mask
    bgra[..., 3] = np.where(top_half, 255, 0)
    cv2.imwrite(str(root / "mask" / "view_0.png"), bgra)
    assert np.array_equal(read_entry(root, "view_0").mask, top_half)


def test_a_ground_truth_with_transparent_pixels_is_refused(tmp_path, capsys):
    root = tmp_path / "maps"
    _tiny_maps(root, n=1)
    bgra = np.full((24, 32, 4), 255, np.uint8)
    bgra[0, 0, 3] = 0
    cv2.imwrite(str(root / "gt" / "view_0.png"), bgra)
    assert "transparent pixels" in _one_line_error(capsys, "--maps", str(root))


def test_view_names_become_file_stems_and_two_that_would_share_files_are_refused():
    assert safe_name("images/frame_001.png") == "images_frame_001"
    assert safe_name("test.v2/r_0") == "test.v2_r_0"  # the folder's dot is not an extension
    assert file_stems(["test.v2/r_0", "test.v2/r_1"]) == ["test.v2_r_0", "test.v2_r_1"]
    for clash in (["a/b.png", "a_b.png"], ["r_0.png", "r_0.jpg"]):
        with pytest.raises(SplatuError, match="would both be written as"):
            file_stems(clash)


def test_no_view_name_becomes_a_hidden_file():
    """A --cameras file_path of `../../x` was written as `.._.._x_*.npy`, which `ls` hides: "." and ".." are dropped
    and a leading dot becomes `_`, and two names that then meet are refused as any other pair."""
    names = ["../../x", ".hidden.png", "./a/../b.jpg", "..y", "..\\z.png", "c/.d"]
    stems = file_stems(names)
    assert stems == ["x", "_hidden", "a_b", "__y", "z", "c__d"]
    assert not any(stem.startswith(".") for stem in stems)
    with pytest.raises(SplatuError, match=re.escape("'../x' and 'x' would both be written as 'x'")):
        file_stems(["../x", "x"])


@pytest.mark.parametrize(("name", "problem"), [("", "has no file name"), (".", "has no file name"),
                                               ("/", "has no file name"), ("../..", "has no file name"),
                                               ("a\0b", "NUL"),
                                               ("x" * 240, "longer than the 239 bytes")])
def test_a_view_name_no_file_can_take_is_one_line_naming_the_camera_file(name, problem):
    # a --cameras file_path of "" or "." was a pathlib ValueError traceback, a NUL one open()'s, and one of 300
    # characters an OSError whose advice was to free disk space
    with pytest.raises(SplatuError, match=problem) as raised:
        file_stems(["candidate", name], "in cams.json")
    assert raised.value.where == "in cams.json" and "file_path" in raised.value.fix
    assert file_stems(["x" * 239]) == ["x" * 239]


def test_every_option_that_changes_a_methods_maps_is_in_its_file_names():
    def label(**options) -> str:
        return UncertaintyOptions(**options).for_run(ensemble=False).label()

    assert label() == "ours"
    assert label(head="degree=1") == "ours-degree=1"
    # one head, spelt two ways, is one set of files (it used to be two, with identical maps)
    spelt = [label(head=spec) for spec in ("degree=1,lam=0.10", "lam=0.1, degree=1")]
    assert spelt == ["ours-lam=0.1,degree=1"] * 2
    assert label(method="ensemble", density_aware=True) == "ensemble-density-aware"
    assert label(method="fisher", fisher_probes=4, seed=1) == "fisher-4-probes-seed-1"
    # the data a run is rendered on is not in the name: --data moves the scene, not the maps' method
    assert label(data="elsewhere") == "ours"
    # an ensemble run's default is named as --method ensemble is
    assert UncertaintyOptions(density_aware=True).for_run(ensemble=True).label() == "ensemble-density-aware"


def test_the_recorded_options_are_every_option_including_the_scene():
    """render.json and the scores' JSON keep what made their maps, --data too: the label leaves it out, so the
    record is the one place that says which scene the maps were rendered on."""
    options = UncertaintyOptions(data="elsewhere", method="fisher", fisher_probes=4, seed=1)
    assert options.record() == {"data": "elsewhere", "method": "fisher", "head": None, "density_aware": False,
                                "fisher_probes": 4, "seed": 1}


def _rewrite_maps(root: Path, entries: list[MapEntry], tag: str, times: int) -> None:
    for _ in range(times):
        maps.write_maps_dir(root, entries, {"writer.txt": tag})


def test_two_processes_replacing_one_maps_directory_both_finish_and_leave_one_whole(tmp_path):
    """Two `eval-ause --load` runs of one method write the same maps folder. The swap used to delete the folder
    and then rename over it, so one process could find it half-deleted or refilled and fail with a traceback."""
    source = tmp_path / "source"
    _tiny_maps(source, n=2)
    entries = [read_entry(source, name) for name in entry_names(source)]
    root = tmp_path / "run" / "maps"
    context = multiprocessing.get_context("fork")
    writers = [context.Process(target=_rewrite_maps, args=(root, entries, tag, 40)) for tag in ("a", "b")]
    for writer in writers:
        writer.start()
    for writer in writers:
        writer.join(timeout=120)
    assert [writer.exitcode for writer in writers] == [0, 0]
    assert entry_names(root) == ["view_0", "view_1"] and (root / "writer.txt").read_text() in ("a", "b")
    assert sorted(p.name for p in root.parent.iterdir()) == ["maps"]  # no staging or set-aside folder left


def test_a_maps_directory_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    """A render that fails part-way used to leave some views written and others missing, or a view without its
    mask, which eval-ause --maps would score as if nothing were wrong."""
    root = tmp_path / "maps"
    _tiny_maps(root, n=2)
    before = {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()}
    fresh = [dataclasses.replace(read_entry(root, name), name=f"new_{name}") for name in ("view_0", "view_1")]
    written = []

    def fail_on_the_second(where: Path, entry: MapEntry) -> None:
        if written:
            raise OSError("disk full")
        written.append(entry.name)
        write_entry(where, entry)

    monkeypatch.setattr(maps, "write_entry", fail_on_the_second)
    with pytest.raises(SplatuError, match="disk full"):  # one line, naming the folder
        maps.write_maps_dir(root, fresh)
    assert {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]  # no staging folder left behind
    monkeypatch.undo()
    stored = maps.write_maps_dir(root, fresh)
    assert entry_names(root) == ["new_view_0", "new_view_1"]  # the earlier views are gone, not mixed in
    for entry in stored:  # what it returns for scoring is what eval-ause --maps would read
        again = read_entry(root, entry.name)
        for field in ("rgb", "gt", "uncertainty", "mask", "unobserved"):
            assert np.array_equal(getattr(entry, field), getattr(again, field)), field


def test_maps_pngs_hold_their_colours_in_the_order_every_tool_reads_them(tmp_path):
    """The stored PNGs are ordinary images: OpenCV (BGR) finds red where the render is red, and a PNG another tool
    wrote reads back as the colours it shows, so a red/blue swap on either side would change every score."""
    rgb = np.zeros((4, 6, 3))
    rgb[..., 0] = 1.0  # pure red
    gt = np.zeros((4, 6, 3))
    gt[..., 2] = 1.0  # pure blue
    write_entry(tmp_path, MapEntry("v", rgb, gt, np.zeros((4, 6))))
    stored = cv2.imread(str(tmp_path / "rgb" / "v.png"), cv2.IMREAD_UNCHANGED)
    assert stored.dtype == np.uint16
    assert np.all(stored[..., 2] == 65535) and np.all(stored[..., :2] == 0)  # OpenCV's order: B, G, R
    entry = read_entry(tmp_path, "v")
    np.testing.assert_array_equal(entry.rgb, rgb)
    np.testing.assert_array_equal(entry.gt, gt)
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 0] = 255  # an 8-bit file holding pure blue, in OpenCV's channel order
    cv2.imwrite(str(tmp_path / "rgb" / "v.png"), bgr)
    np.testing.assert_array_equal(read_entry(tmp_path, "v").rgb, gt)


@pytest.mark.parametrize(("dtype", "value"), [(np.uint8, 1), (np.uint16, 1), (np.uint8, 127)])
def test_every_non_zero_mask_value_marks_the_pixel(tmp_path, dtype, value):
    """mask/ and unobserved/: non-zero = marked, however faint (a 0/1 mask saved as 8 or 16 bits reads the same)."""
    root = tmp_path / "maps"
    _tiny_maps(root, n=1)
    left = np.zeros((24, 32), bool)
    left[:, :10] = True
    (root / "mask").mkdir()
    cv2.imwrite(str(root / "mask" / "view_0.png"), (left * value).astype(dtype))
    cv2.imwrite(str(root / "unobserved" / "view_0.png"), (~left * value).astype(dtype))
    entry = read_entry(root, "view_0")
    assert np.array_equal(entry.mask, left) and np.array_equal(entry.unobserved, ~left)


def test_stored_uncertainty_keeps_the_order_and_range_of_the_render(tmp_path):
    """The stored map ranks pixels exactly as the rendered one: nearby values stay apart and large ones (a Fisher
    variance) stay finite, to float32 precision."""
    u = np.array([[1.0, 1.0001, 1.0002, 1e5], [3e-8, 2e-8, -7.25, 1e6]])
    write_entry(tmp_path, MapEntry("v", np.zeros((2, 4, 3)), np.zeros((2, 4, 3)), u))
    stored = read_entry(tmp_path, "v").uncertainty
    np.testing.assert_allclose(stored, u, rtol=1e-7)
    assert np.array_equal(np.argsort(stored, axis=None), np.argsort(u, axis=None))


def test_the_plotted_mean_curves_are_the_ones_the_table_reports():
    """The plot shows each image's curves / O(0), averaged over images (random's also over every seed the table
    averages), on the pixels the mask scores, for the chosen metric. Start-normalised AUSE is linear in those
    curves, so the area between the plotted pair is exactly the table's mean start-normalised AUSE."""
    rng = np.random.default_rng(5)
    entries = []
    for i in range(3):
        gt = rng.random((12, 16, 3))
        rgb = np.clip(gt + rng.normal(0.0, 0.15, gt.shape), 0.0, 1.0)
        error = A.pixel_errors(rgb, gt)
        mask = np.zeros((12, 16), bool)
        mask[:, 4 * i: 4 * i + 9] = True
        uncertainty = np.where(mask, error + 0.1 * rng.random(error.shape), -error)  # masked-out: anti-correlated
        entries.append(MapEntry(f"v{i}", rgb, gt, uncertainty, mask=None if i == 2 else mask))
    for metric in ("mae", "rmse"):
        report, curves = score_entries(entries, metric)
        for name, key in (("uncertainty", f"ause_{metric}_start_norm"),
                          (RANDOM_CURVE, f"random_ause_{metric}_start_norm")):
            curve = curves[name]
            assert curve.oracle[0] == pytest.approx(1.0) and curve.sparsification[0] == pytest.approx(1.0)
            area = np.trapezoid(curve.sparsification - curve.oracle, A.FRACTIONS)
            assert area == pytest.approx(report["mean"][key], rel=1e-9, abs=1e-12), (metric, name)


def test_a_view_without_error_keeps_the_plotted_curves_at_one_where_they_start():
    """Kept pixels of an error-free view err exactly as much as all of them: its curves / O(0) are 1, not 0, so
    the mean over views still starts at 1, as the plot's axis ("MAE of kept / MAE of all") says; its AUSE stays 0."""
    rng = np.random.default_rng(2)
    gt = rng.random((10, 12, 3))
    noisy = MapEntry("noisy", np.clip(gt + rng.normal(0.0, 0.2, gt.shape), 0.0, 1.0), gt, rng.random((10, 12)))
    exact = MapEntry("exact", gt[:1, :1], gt[:1, :1], np.zeros((1, 1)))
    report, curves = score_entries([noisy, exact], "mae")
    for curve in curves.values():
        assert curve.oracle[0] == pytest.approx(1.0) and curve.sparsification[0] == pytest.approx(1.0)
    assert report["per_image"]["exact"]["ause_mae_start_norm"] == 0.0


def test_the_random_method_and_the_random_baseline_are_both_plotted(tmp_path, monkeypatch):
    """`--method random` labels its curve "random": the baseline's curve must not take its place in the plot."""
    plotted = {}
    monkeypatch.setattr("splatu.eval_ause.plot_sparsification",
                        lambda path, curves, title, metric: plotted.update(curves))
    _tiny_maps(tmp_path / "maps", n=1)
    evaluate_maps(tmp_path / "maps", label="random", output=tmp_path / "ause.json")
    assert set(plotted) == {"random", RANDOM_CURVE}


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_while_the_plot_is_written_waits_for_the_scores_beside_it(tmp_path, monkeypatch, capsys, stop):
    """A Ctrl-C or kill between the plot and the JSON used to leave the new curves beside the earlier scores (or the
    reverse): the stop now waits for both, then exits as that stop."""
    from splatu import eval_ause

    _tiny_maps(tmp_path / "maps", n=1)
    out = tmp_path / "ause.json"
    out.write_text("{}")  # an earlier score
    plot = eval_ause.plot_sparsification

    def stop_then_plot(*args):
        os.kill(os.getpid(), stop)
        plot(*args)

    monkeypatch.setattr(eval_ause, "plot_sparsification", stop_then_plot)
    with pytest.raises(SystemExit) as exc:
        _run("--maps", str(tmp_path / "maps"), "--output", str(out))
    assert exc.value.code == 128 + stop
    assert json.loads(out.read_text())["images"] == 1 and out.with_suffix(".png").stat().st_size > 0
    assert "interrupted" in capsys.readouterr().err


def test_a_plot_the_disk_refuses_is_one_line_and_keeps_the_earlier_scores(tmp_path, monkeypatch, capsys):
    from splatu import figures

    _tiny_maps(tmp_path / "maps", n=1)
    out = tmp_path / "ause.json"
    out.write_text("{}")

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(figures.plt.Figure, "savefig", full_disk)
    line = _one_line_error(capsys, "--maps", str(tmp_path / "maps"), "--output", str(out))
    assert "ause.png" in line and "free space" in line
    assert out.read_text() == "{}" and not out.with_suffix(".png").exists()
    assert not list(tmp_path.glob(".ause.png.tmp-*"))


def _maps_scored_before(tmp_path, earlier: bool) -> tuple[Path, bytes | None]:
    """A one-view maps folder, scored once already when `earlier`: its report's path and bytes (None if none)."""
    _tiny_maps(tmp_path / "maps", n=1)
    output = tmp_path / "maps" / "ause.json"
    if earlier:
        _run("--maps", str(tmp_path / "maps"))
    return output, output.read_bytes() if earlier else None


def _stopped_in(module, name: str, tmp_path, monkeypatch, capsys) -> str:
    """What `eval-ause --maps` prints when a Ctrl-C comes in `module.name`; it must exit 130."""
    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(module, name, stop)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stopped:
        _run("--maps", str(tmp_path / "maps"))
    assert stopped.value.code == 130
    return capsys.readouterr().err


@pytest.mark.parametrize("earlier", [True, False])
def test_a_ctrl_c_while_scoring_says_no_scores_were_written(tmp_path, monkeypatch, capsys, earlier):
    """It said only "interrupted"; the scores are written last, so a stop before them leaves an earlier report."""
    from splatu import eval_ause

    output, before = _maps_scored_before(tmp_path, earlier)
    said = (f"no report written; the earlier report in {output} is unchanged" if earlier
            else f"no report written to {output}")
    assert _stopped_in(eval_ause, "score_entries", tmp_path, monkeypatch, capsys) == f"interrupted: {said}\n"
    assert (output.read_bytes() if output.exists() else None) == before


@pytest.mark.parametrize("earlier", [True, False])
def test_a_second_stop_between_the_plot_and_the_scores_says_the_plot_is_new(tmp_path, monkeypatch, capsys, earlier):
    """The plot is written first: a second stop before the scores said "the earlier X.json is unchanged", true, but
    silent on X.png, which was already replaced by the new curves."""
    from splatu import eval_ause

    output, before = _maps_scored_before(tmp_path, earlier)
    kept = f"the earlier {output} is unchanged" if earlier else f"{output} is not written"
    # a second stop aborts at once (`finish_first`), here after the plot
    said = _stopped_in(eval_ause, "atomic_write_text", tmp_path, monkeypatch, capsys)
    assert said == (f"interrupted: a second stop cut short the write of the scores: their plot "
                    f"{output.with_suffix('.png')} is new, but {kept}; run the command again to write both\n")
    assert (output.read_bytes() if output.exists() else None) == before
