"""render-uncertainty and eval-ause --load on a tiny trained stand-in, every method, and the orbit."""

import dataclasses
import errno
import json
import math
import os
import re
import shutil
import signal
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from splatu import render_uncertainty
from splatu.camera import Camera, look_at
from splatu.cli import entrypoint
from splatu.data.frames import MAX_IMAGE_SIDE
from splatu.errors import SplatuError
from splatu.interrupts import Terminated, sigterm_as_ctrl_c
from splatu.orbit import capture_frame, orbit_cameras
from splatu.render_uncertainty import (
    SWAPPING,
    RenderUncertaintyConfig,
    refuse_foreign_output,
    render_eval_maps,
    swap_in,
)
from splatu.uncertainty_options import UncertaintyOptions
from tests.older_runs import OLDER_VALUES, saved_with


def _ring(n: int = 12, radius: float = 2.0, height: float = 1.0) -> list[Camera]:
    """Cameras on a ring above the origin, +z up, all looking at (0, 0, 0.2)."""
    K = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
    target = torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    cameras = []
    for k in range(n):
        a = 2 * math.pi * k / n
        position = torch.tensor([radius * math.cos(a), radius * math.sin(a), height], dtype=torch.float64)
        cameras.append(Camera(K, look_at(position, target, up).float(), 64, 48, name=f"ring_{k}"))
    return cameras


def test_orbit_recovers_the_capture_and_looks_from_below():
    ring = _ring()
    frame = capture_frame(ring)
    assert torch.allclose(frame.center, torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64), atol=1e-4)
    assert float(frame.up[2]) > 0.9  # cameras tilt down at the target, their mean up is still near +z
    orbit = orbit_cameras(ring, frames=16, max_elevation_degrees=60.0)
    elevations = [f.elevation_degrees for f in orbit]
    assert max(elevations) == pytest.approx(60.0) and min(elevations) == pytest.approx(-60.0)
    for f in orbit:
        uv, z = f.camera.project(frame.center[None].float())
        assert float(z[0]) > 0 and torch.allclose(uv[0], torch.tensor([32.0, 24.0]), atol=1e-3)
        below = float(f.camera.center()[2]) < 0.2
        assert below == (f.elevation_degrees < -1e-6) or abs(f.elevation_degrees) < 1e-6


def test_default_orbit_stays_above_the_poster_floor_and_looks_up_from_below_the_seat():
    from splatu.data.poster import PosterConfig
    from splatu.data.poster.geometry import SEAT_BOTTOM, SEAT_TOP, build_scene
    from splatu.data.poster.path import camera_path

    room = build_scene().boxes[0]
    floor, ceiling = room.center[2] - room.half[2], room.center[2] + room.half[2]
    path = camera_path(PosterConfig())  # metres, +z up: what the loader normalises by a shift and a scale only
    assert float(capture_frame(path).up[2]) == pytest.approx(1.0, abs=1e-6)  # the capture's pitch does not tilt it
    defaults = RenderUncertaintyConfig()
    orbit = orbit_cameras(path, 24, defaults.orbit_elevation, defaults.orbit_radius_scale)
    heights = {f.elevation_degrees: float(f.camera.center()[2]) for f in orbit}
    for f in orbit:
        x, y, z = (float(v) for v in f.camera.center())
        assert floor + 0.05 < z < ceiling and abs(x) < room.half[0] and abs(y) < room.half[1], (x, y, z)
    assert all(z > SEAT_TOP for e, z in heights.items() if e > 20.0)
    below = [z for e, z in heights.items() if e < -20.0]
    assert len(below) >= 6 and all(z < SEAT_BOTTOM for z in below)  # under the seat, looking up at it
    # the old default (±60° at the full radius) went through the floor
    assert min(float(f.camera.center()[2]) for f in orbit_cameras(path, 24, 60.0, 1.0)) < floor
    # cameras that all face one way (one right axis, here pitched at one point) leave the vertical undetermined:
    # their own up is kept
    rotation, centre = path[0].world_to_camera[:3, :3].double(), path[0].center().double()
    target, facing = centre + 2.0 * rotation[2], []
    for k in range(3):
        position = centre - 0.1 * k * rotation[1]  # up the first camera's image
        forward = (target - position) / (target - position).norm()
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = torch.stack([rotation[0], torch.linalg.cross(forward, rotation[0]), forward])
        w2c[:3, 3] = -w2c[:3, :3] @ position
        facing.append(dataclasses.replace(path[0], world_to_camera=w2c.to(path[0].world_to_camera.dtype)))
    mean_up = -torch.stack([c.world_to_camera[1, :3].double() for c in facing]).mean(dim=0)
    assert torch.allclose(capture_frame(facing).up, mean_up / mean_up.norm(), atol=1e-6)


# --- on a tiny trained stand-in ----------------------------------------------------------------

TINY_STEPS = 80
EXTRA_HEAD = "kind=antipodal,degree=0"
"""An extra uncertainty head of the tiny run: a view-independent u, trained beside the run's own."""


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One short training of the paper's method on a tiny stand-in, shared by this module's tests."""
    from splatu import train_command
    from splatu.data.config import DataConfig
    from splatu.data.poster import PosterConfig
    from splatu.densify import DensifyConfig
    from splatu.train_config import preset_config

    root = tmp_path_factory.mktemp("render_uncertainty")
    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setenv("SPLATU_CACHE", str(root / "cache"))
    base = preset_config("fast")
    config = dataclasses.replace(
        base, steps=TINY_STEPS, checkpoint_every=0, progress=False, compile_kernels=False, output_dir=root / "outputs",
        resolution_interval=30, model=dataclasses.replace(base.model, sh_degree_interval=20),
        data=DataConfig(data="poster", poster=PosterConfig(width=48, height=80, frames=24, eval_block=5,
                                                            interp_every=6, points=2000)),
        densify=DensifyConfig(warmup_length=10, refine_every=10, stop_split_at=50, stop_screen_size_at=25,
                              max_gaussians=2500),
        uncertainty=dataclasses.replace(base.uncertainty, extra_heads=(EXTRA_HEAD,)),
    )
    run_dir = train_command.train(config)
    yield run_dir
    monkeypatch.undo()


def _render(run_dir, *args: str):
    entrypoint(["render-uncertainty", "--load", str(run_dir), *args])


def test_render_eval_writes_every_file_with_finite_maps_in_unit_range(tiny_run, tmp_path):
    out = tmp_path / "eval"
    _render(tiny_run, "--output", str(out))
    record = json.loads((out / "render.json").read_text())
    names = [v["name"] for v in record["per_view"]]
    assert len(names) == 5  # the eval block
    for name in names:
        for key in ("rgb", "depth", "alpha", "uncertainty"):
            value = np.load(out / "npy" / f"{name}_{key}.npy")
            assert np.isfinite(value).all(), (name, key)
            assert (out / "png" / f"{name}_{key}.png").is_file()
        u = np.load(out / "npy" / f"{name}_uncertainty.npy")
        alpha = np.load(out / "npy" / f"{name}_alpha.npy")
        assert u.min() >= 0.0 and u.max() <= 1.0 + 1e-6
        assert alpha.min() >= -1e-6 and alpha.max() <= 1.0 + 1e-6
        assert (out / "panels" / f"{name}.png").is_file()
        for folder, suffix in (("rgb", "png"), ("gt", "png"), ("uncertainty", "npy"), ("unobserved", "png")):
            assert (out / "maps" / folder / f"{name}.{suffix}").is_file()
    for key in ("uncertainty", "depth", "error"):
        assert (out / f"colorbar_{key}.png").is_file()
    assert record["uncertainty_scale"] == [0.0, 1.0]
    lo, hi = record["depth_scale"]
    assert 0.0 < lo < hi  # the depths of the covered pixels, never the 0 of an empty one


def test_orbit_from_below_is_more_uncertain_than_the_training_path(tiny_run, tmp_path):
    _render(tiny_run, "--views", "orbit", "--orbit-frames", "8", "--output", str(tmp_path / "orbit"))
    _render(tiny_run, "--views", "train", "--max-views", "4", "--output", str(tmp_path / "train"))
    orbit_record = json.loads((tmp_path / "orbit" / "render.json").read_text())
    train_record = json.loads((tmp_path / "train" / "render.json").read_text())
    # the tiny run's cameras ring the scene: the circle, recorded as such; a training view has no orbit
    assert orbit_record["orbit"]["shape"] == "circle" and orbit_record["orbit"]["radius_scale"] == 0.5
    assert train_record["orbit"] is None
    orbit, train = orbit_record["per_view"], train_record["per_view"]
    below = [v["mean_uncertainty"] for v in orbit if v["elevation_degrees"] < -20.0]
    seen = [v["mean_uncertainty"] for v in train]
    assert len(below) >= 3
    # every view from below is more uncertain than every view of the training path
    assert min(below) > max(seen), (below, seen)
    assert (tmp_path / "orbit" / "orbit.gif").stat().st_size > 0
    assert not (tmp_path / "orbit" / "maps").exists()  # no ground truth on the orbit
    assert not (tmp_path / "orbit" / "colorbar_error.png").exists()  # and so no error map to give a legend


def test_eval_ause_load_scores_the_run_with_auroc(tiny_run, capsys):
    entrypoint(["eval-ause", "--load", str(tiny_run)])
    report = json.loads((tiny_run / "ause_ours.json").read_text())
    out, err = capsys.readouterr()
    assert report["stand_in"] is True and "AUSE of ours on the built-in poster stand-in" in out
    assert "stand-in" not in err  # `train` said so, once
    mean = report["mean"]
    for key in ("ause_mae", "ause_rmse", "random_ause_mae", "ause_mae_start_norm", "auroc_unobserved"):
        assert mean[key] is not None and math.isfinite(mean[key]), key
    assert "oracle_ause_mae" not in mean
    assert mean["oracle_ausc_mae"] < mean["ausc_mae"] < mean["random_ausc_mae"]
    assert 0.0 <= mean["auroc_unobserved"] <= 1.0
    assert len(report["per_image"]) == 5
    # measured over training seeds 0, 1, 2 (u-SH degree 1): ours 0.396 / 0.379 / 0.364,
    # against random 0.553 / 0.548 / 0.544
    assert mean["ause_mae"] < mean["random_ause_mae"]


def test_an_extra_uncertainty_head_renders_and_scores_on_its_own(tiny_run, capsys):
    entrypoint(["eval-ause", "--load", str(tiny_run), "--head", EXTRA_HEAD])
    head = json.loads((tiny_run / f"ause_ours-{EXTRA_HEAD}.json").read_text())
    assert head["method"] == f"ours-{EXTRA_HEAD}" and len(head["per_image"]) == 5
    own_dir, extra_dir = (render_eval_maps(tiny_run, UncertaintyOptions(head=h))[0] / "uncertainty"
                          for h in (None, EXTRA_HEAD))
    names = sorted(p.name for p in own_dir.glob("*.npy"))
    assert names == sorted(p.name for p in extra_dir.glob("*.npy")) and len(names) == 5
    own, extra = ([np.load(folder / n) for n in names] for folder in (own_dir, extra_dir))
    assert all(np.isfinite(u).all() and u.min() >= 0.0 and u.max() <= 1.0 for u in extra)
    assert any(not np.allclose(a, b) for a, b in zip(own, extra, strict=True))  # another u on the same Gaussians
    with pytest.raises(SystemExit):
        entrypoint(["render-uncertainty", "--load", str(tiny_run), "--head", "lam=0.2"])
    err = capsys.readouterr().err
    assert "no uncertainty head 'lam=0.2'" in err and EXTRA_HEAD in err and "Traceback" not in err
    for command in (["render-uncertainty", "--load", str(tiny_run), "--method", "visibility"],
                    ["eval-ause", "--maps", str(own_dir.parent)]):
        with pytest.raises(SystemExit):
            entrypoint([*command, "--head", EXTRA_HEAD])
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--head" in err and "Traceback" not in err, err


def _moved_scene_run(tiny_run, tmp_path):
    """A copy of the tiny run whose recorded scene is a copy of the stand-in, with a recorded every-6th split."""
    from splatu.checkpoint import list_checkpoints, read_checkpoint
    from splatu.data.resolve import scene_path
    from splatu.train_config import from_dict, save_config

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    path = list_checkpoints(run)[-1]
    state = read_checkpoint(path)
    config = from_dict(state["config"])
    scene = tmp_path / "scene"
    shutil.copytree(scene_path(config.data), scene)
    state["config"]["data"].update(data=str(scene), eval_split="every-n", eval_every=6)
    torch.save(state, path)
    save_config(from_dict(state["config"]), run / "config.yml")  # a run records its options in both
    return run, scene


def test_load_uses_the_recorded_scene_and_split_and_says_how_to_pass_a_moved_one(tiny_run, tmp_path, capsys):
    run, scene = _moved_scene_run(tiny_run, tmp_path)
    entrypoint(["eval-ause", "--load", str(run)])
    assert len(json.loads((run / "ause_ours.json").read_text())["per_image"]) == 4  # frames 0, 6, 12, 18
    moved = scene.rename(tmp_path / "moved")
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        entrypoint(["eval-ause", "--load", str(run)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no longer exists" in err[0] and str(scene) in err[0] and "--data" in err[0]
    with pytest.raises(SplatuError, match="no longer exists"):
        _render(run, "--debug")
    entrypoint(["eval-ause", "--load", str(run), "--data", str(moved), "--output", str(tmp_path / "moved.json")])
    assert len(json.loads((tmp_path / "moved.json").read_text())["per_image"]) == 4  # the recorded split is kept
    _render(run, "--data", str(moved), "--output", str(tmp_path / "render"))
    assert len(json.loads((tmp_path / "render" / "render.json").read_text())["per_view"]) == 4


@pytest.mark.parametrize("kind", ["run", "ensemble"])
def test_a_scene_normalised_unlike_the_training_one_is_refused_in_one_line(tiny_run, tmp_path, capsys, kind):
    """E.g. a `poster` run of the stand-in, loaded once the real capture is present: the cameras would not fit."""
    from splatu.checkpoint import list_checkpoints, read_checkpoint

    run = tmp_path / kind
    members = [run] if kind == "run" else [run / "members" / str(k) for k in range(2)]
    for member in members:
        shutil.copytree(tiny_run, member, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    if kind == "ensemble":
        (run / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"], "wall_seconds": 1.0}))
    path = list_checkpoints(members[-1])[-1]  # the ensemble's second member only
    state = read_checkpoint(path)
    state["world_transform"]["scale"] *= 1.5  # as if trained on a scene normalised differently
    torch.save(state, path)
    method = "ours" if kind == "run" else "ensemble"
    for command in (["eval-ause", "--load", str(run), "--method", method],
                    ["render-uncertainty", "--load", str(run), "--method", method]):
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            entrypoint(command)
        assert exc.value.code == 2
        err = capsys.readouterr().err  # after the line that says which poster `--data poster` found
        errors = [line for line in err.splitlines() if line.startswith("error")]
        assert len(errors) == 1 and "normalisation differs" in errors[0] and "stand-in" in errors[0], err
        assert "Traceback" not in err
    assert not list(run.glob("ause_*"))


def _folder_names(root) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()}


def test_a_second_render_with_fewer_views_leaves_no_stale_files(tiny_run, tmp_path):
    out = tmp_path / "twice"
    _render(tiny_run, "--output", str(out))
    first = _folder_names(out)
    _render(tiny_run, "--max-views", "2", "--output", str(out))
    names = [v["name"] for v in json.loads((out / "render.json").read_text())["per_view"]]
    assert len(names) == 2
    for folder in ("npy", "png", "panels", "maps/rgb", "maps/gt", "maps/uncertainty", "maps/unobserved"):
        stems = {p.name.split(".")[0].rsplit("_", 1)[0] if folder in ("npy", "png") else p.stem
                 for p in (out / folder).iterdir()}
        assert stems == set(names), folder
    assert _folder_names(out) < first
    # a render that fails before it has views (here: its scene is missing) leaves the earlier one whole
    kept = {name: (out / name).read_bytes() for name in _folder_names(out)}
    with pytest.raises(SplatuError, match="scene not found"):
        _render(tiny_run, "--max-views", "1", "--data", str(tmp_path / "moved_away"), "--output", str(out), "--debug")
    assert {name: (out / name).read_bytes() for name in _folder_names(out)} == kept
    # a folder another tool wrote is refused, not cleared
    foreign = tmp_path / "foreign"
    (foreign / "png").mkdir(parents=True)
    (foreign / "png" / "mine.png").write_bytes(b"x")
    with pytest.raises(SplatuError, match="not written by render-uncertainty"):
        _render(tiny_run, "--output", str(foreign), "--debug")
    assert (foreign / "png" / "mine.png").read_bytes() == b"x"


def test_a_render_stopped_while_writing_its_files_leaves_the_earlier_one_whole(tiny_run, tmp_path, monkeypatch):
    """A Ctrl-C or SIGTERM after the views are rendered, while their files are written: the earlier render used
    to be deleted first, leaving some of the new files beside the earlier render.json, which lists views whose
    files are gone."""
    import splatu.render_uncertainty as render_uncertainty

    out = tmp_path / "stopped"
    _render(tiny_run, "--max-views", "3", "--output", str(out))  # a view more than the stopped render has
    kept = {name: (out / name).read_bytes() for name in _folder_names(out)}
    save_panel = render_uncertainty.save_panel

    def stopped_after_one_panel(path, *args):
        if list(path.parent.iterdir()):
            raise KeyboardInterrupt
        save_panel(path, *args)

    monkeypatch.setattr(render_uncertainty, "save_panel", stopped_after_one_panel)
    with pytest.raises(SystemExit) as exc:
        _render(tiny_run, "--max-views", "2", "--output", str(out))
    assert exc.value.code == 130
    assert {name: (out / name).read_bytes() for name in _folder_names(out)} == kept  # nothing left half-written


def test_a_render_replaces_what_the_folder_holds_when_it_swaps_in(tmp_path):
    """`eval-ause --load` writes <run>/uncertainty/<label>-eval/maps too, and may do so while a render of that folder
    is running: the render's own maps/ still goes in, where a rename onto a full folder would fail."""
    out, staging = tmp_path / "out", tmp_path / "out" / ".render.tmp"
    (staging / "maps" / "rgb").mkdir(parents=True)
    (staging / "maps" / "rgb" / "new.png").write_bytes(b"new")
    (staging / "render.json").write_text("{}")
    (out / "maps" / "rgb").mkdir(parents=True)
    (out / "maps" / "rgb" / "other.png").write_bytes(b"other")  # written after the render started
    swap_in(staging, out)
    assert _folder_names(out) == {"maps/rgb/new.png", "render.json"}  # and no SWAPPING marker left


def _staged_over_an_earlier_render(tmp_path: Path) -> tuple[Path, Path]:
    """(staging, out): a new render of two files staged inside `out`, which holds an earlier one."""
    out, staging = tmp_path / "out", tmp_path / "out" / ".render.tmp"
    (out / "png").mkdir(parents=True)
    (out / "png" / "old.png").write_bytes(b"old")
    (out / "render.json").write_text("earlier")
    (staging / "png").mkdir(parents=True)
    (staging / "png" / "new.png").write_bytes(b"new")
    (staging / "render.json").write_text("new")
    return staging, out


def test_no_moment_of_a_swap_has_a_render_json_beside_files_it_does_not_list(tmp_path, monkeypatch):
    """A kill may land between any two renames: the earlier render.json must be gone before the first, and the new
    one must come in with the last."""
    staging, out = _staged_over_an_earlier_render(tmp_path)
    moves, replace = [], os.replace

    def watched(src, dst):
        moves.append((Path(src).name, (out / "render.json").exists()))
        replace(src, dst)

    monkeypatch.setattr(os, "replace", watched)
    swap_in(staging, out)
    assert moves == [("png", False), ("render.json", False)]
    assert (out / "render.json").read_text() == "new"


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_during_the_swap_waits_for_its_end(tmp_path, monkeypatch, stop):
    staging, out = _staged_over_an_earlier_render(tmp_path)
    replace = os.replace

    def stopped_midway(src, dst):
        replace(src, dst)
        if Path(dst).name == "png":  # the first of the two renames
            os.kill(os.getpid(), stop)

    monkeypatch.setattr(os, "replace", stopped_midway)
    with pytest.raises(KeyboardInterrupt) as exc, sigterm_as_ctrl_c():  # as the command runs it
        swap_in(staging, out)
    assert isinstance(exc.value, Terminated) == (stop == signal.SIGTERM)
    assert _folder_names(out) == {"png/new.png", "render.json"}  # whole, and no SWAPPING marker left


def test_a_folder_left_half_swapped_is_still_known_as_a_render(tmp_path):
    """A second Ctrl-C (or a kill) during the swap leaves neither render whole and no render.json: the same command
    must be able to render there again, not refuse the folder as another tool's."""
    out = tmp_path / "out"
    (out / "png").mkdir(parents=True)
    with pytest.raises(SplatuError, match="not written by render-uncertainty"):
        refuse_foreign_output(out, default_folder=False)
    (out / SWAPPING).touch()
    refuse_foreign_output(out, default_folder=False)


def test_a_staging_folder_a_killed_render_left_is_neither_kept_nor_rendered_from(tiny_run, tmp_path):
    """A render killed outright (SIGKILL, OOM) leaves its staging folder; one under the next render's process id
    used to have its files swapped in with the new render's."""
    out = tmp_path / "after_kill"
    for pid in (os.getpid(), 4242):
        (out / f".render.tmp-{pid}" / "npy").mkdir(parents=True)
        (out / f".render.tmp-{pid}" / "npy" / "killed_view_rgb.npy").write_bytes(b"stale")
    _render(tiny_run, "--output", str(out))
    assert not any("killed_view" in name or ".render.tmp" in name for name in _folder_names(out))
    assert not list(out.glob(".render.tmp-*"))


def test_a_full_disk_while_files_are_written_is_one_line_and_keeps_the_earlier_render(tiny_run, tmp_path,
                                                                                       monkeypatch, capsys):
    """np.save and matplotlib raise the disk's OSError as it is: both commands ended in a traceback."""
    out = tmp_path / "full"
    _render(tiny_run, "--max-views", "2", "--output", str(out))
    kept = {name: (out / name).read_bytes() for name in _folder_names(out)}

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "save", disk_full)
    for command in (["render-uncertainty", "--load", str(tiny_run), "--output", str(out)],
                    ["eval-ause", "--load", str(tiny_run), "--output", str(tmp_path / "scores.json")]):
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            entrypoint(command)
        err = capsys.readouterr().err
        errors = err.splitlines()  # the error alone: loading the stand-in says nothing
        assert exc.value.code == 2 and len(errors) == 1 and "Traceback" not in err, err
        assert "No space left on device" in errors[0] and "free space" in errors[0]
    assert {name: (out / name).read_bytes() for name in _folder_names(out)} == kept
    assert not (tmp_path / "scores.json").exists()


def test_a_full_disk_while_the_maps_are_written_names_the_output_folder(tiny_run, tmp_path, monkeypatch, capsys):
    """The maps go into the render's staging folder, which is gone when the error is read: it must name --output."""
    out = tmp_path / "maps_full"

    def disk_full(root, entry):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(render_uncertainty, "write_entry", disk_full)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        _render(tiny_run, "--output", str(out))
    [line] = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error")]
    assert exc.value.code == 2 and f"in {out}," in line and ".render.tmp" not in line, line


def test_a_write_refused_midway_leaves_no_folder_the_render_made_and_keeps_one_that_was_there(tiny_run, tmp_path,
                                                                                             monkeypatch, capsys):
    """The render made its output folder (and the missing ones above it) to write into, and left them empty when a
    write failed after some views' files were written."""
    save_panel, panels = render_uncertainty.save_panel, []

    def disk_full_at_the_second_panel(path, *args):
        panels.append(path)
        if len(panels) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        save_panel(path, *args)

    monkeypatch.setattr(render_uncertainty, "save_panel", disk_full_at_the_second_panel)
    existing = tmp_path / "existing"
    existing.mkdir()
    for out in (tmp_path / "new" / "render", existing):
        panels.clear()
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            _render(tiny_run, "--output", str(out))
        err = capsys.readouterr().err
        errors = [line for line in err.splitlines() if line.startswith("error")]
        assert exc.value.code == 2 and len(errors) == 1 and "Traceback" not in err, err
        assert "No space left on device" in errors[0] and f"in {out}," in errors[0]
        assert len(panels) == 2  # it failed after writing the first view's files
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing"] and not list(existing.iterdir())


def test_eval_ause_leaves_no_folder_it_made_when_its_maps_cannot_be_written(tiny_run, tmp_path, monkeypatch, capsys):
    """eval-ause --load writes the maps it scores beside its --output: the folder made for them was left empty."""
    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "save", disk_full)
    with pytest.raises(SystemExit) as exc:
        entrypoint(["eval-ause", "--load", str(tiny_run), "--output", str(tmp_path / "new" / "scores.json")])
    assert exc.value.code == 2 and "No space left on device" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def _one_line(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        entrypoint(argv)
    assert exc.value.code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def test_unwritable_outputs_are_one_line_errors(tiny_run, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    line = _one_line(capsys, ["render-uncertainty", "--load", str(tiny_run), "--output", str(a_file / "out")])
    assert "cannot write" in line and "--output" in line
    line = _one_line(capsys, ["eval-ause", "--load", str(tiny_run), "--output", str(a_file / "ause.json")])
    assert "cannot write" in line and "--output" in line
    line = _one_line(capsys, ["eval-ause", "--load", str(tiny_run), "--output", str(tmp_path)])
    assert "is a folder" in line
    if os.geteuid() != 0:  # root writes into read-only folders anyway
        read_only = tmp_path / "read_only"
        read_only.mkdir(mode=0o555)
        line = _one_line(capsys, ["render-uncertainty", "--load", str(tiny_run), "--output", str(read_only)])
        assert "cannot write" in line


def test_a_damaged_summary_is_a_one_line_error(tiny_run, tmp_path, capsys):
    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    for damaged in ('{"train_sec', '{"train_seconds": "slow"}', '{"train_seconds": 1.0, "wall_seconds": [1]}',
                    '{"train_seconds": 1.0, "train_compile_seconds": NaN}'):
        (copy / "summary.json").write_text(damaged)
        for command in ("render-uncertainty", "eval-ause"):
            line = _one_line(capsys, [command, "--load", str(copy)])
            assert "summary.json" in line, line


@pytest.mark.parametrize("method", ["visibility", "fisher", "random", "spread", "ours-spread", "residual",
                                    "ours-residual", "angle", "ours-residual-angle",
                                    "ours-view-residual-angle"])
def test_every_baseline_renders_and_scores(tiny_run, method):
    entrypoint(["eval-ause", "--load", str(tiny_run), "--method", method])
    mean = json.loads((tiny_run / f"ause_{method}.json").read_text())["mean"]
    assert math.isfinite(mean["ause_mae"]) and math.isfinite(mean["random_ause_mae"])
    maps = tiny_run / "uncertainty" / f"{method}-eval" / "maps" / "uncertainty"
    for path in maps.glob("*.npy"):
        u = np.load(path)
        assert np.isfinite(u).all() and u.min() >= 0.0 and u.max() <= 1.0 + 1e-6


def test_eval_ause_passes_its_seed_to_the_random_method_and_files_each_seed_apart(tiny_run, capsys):
    def scored(seed: str) -> dict:
        entrypoint(["eval-ause", "--load", str(tiny_run), "--method", "random", "--seed", seed])
        return json.loads((tiny_run / ("ause_random.json" if seed == "0" else f"ause_random-seed-{seed}.json"))
                          .read_text())

    first, other, again = scored("0"), scored("1"), scored("0")
    assert first["per_image"] == again["per_image"]  # seed 1's report and maps went beside seed 0's, not over them
    assert any(first["per_image"][name]["ause_mae"] != other["per_image"][name]["ause_mae"]
               for name in first["per_image"])
    assert (other["method"], other["options"]["seed"], first["options"]["seed"]) == ("random-seed-1", 1, 0)
    assert (tiny_run / "uncertainty" / "random-seed-1-eval" / "maps").is_dir()
    assert "--seed only applies with --method random or --method fisher" in _one_line(
        capsys, ["eval-ause", "--load", str(tiny_run), "--method", "visibility", "--seed", "2"])


def test_ours_and_the_ensemble_report_their_cost_in_the_same_measure(tiny_run, tmp_path):
    """render.json and eval-ause's timing.json gave a single run's time inside training steps (summary.json's
    train_seconds) but an ensemble's wall time (ensemble.json's), both as train_seconds, so comparing their costs
    mixed two measures. Each now gives the time in steps (an ensemble: its members' summed) as train_step_seconds,
    and the wall time beside it as train_wall_seconds; the kernels' compile time, which the steps leave out, is
    train_compile_seconds, null for a run saved before it was recorded (whose steps' time includes it)."""
    ensemble = tmp_path / "ensemble"
    for k in range(2):
        shutil.copytree(tiny_run, ensemble / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    summary = json.loads((tiny_run / "summary.json").read_text())
    (ensemble / "members" / "1" / "summary.json").write_text(json.dumps({**summary, "train_seconds": 40.0,
                                                                         "train_compile_seconds": 9.0}))
    (ensemble / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"],
                                                        "wall_seconds": 1000.0}))
    old = tmp_path / "old"
    shutil.copytree(tiny_run, old, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    (old / "summary.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "train_compile_seconds"}))
    compiling = summary["train_compile_seconds"]
    for run, method, name, steps, compiled, wall in (
            (tiny_run, "ours", "ours", summary["train_seconds"], compiling, summary["wall_seconds"]),
            (ensemble, "ensemble", "ensemble", summary["train_seconds"] + 40.0, compiling + 9.0, 1000.0),
            (old, "ours", "old", summary["train_seconds"], None, summary["wall_seconds"])):
        _render(run, "--method", method, "--max-views", "1", "--output", str(tmp_path / name))
        entrypoint(["eval-ause", "--load", str(run), "--method", method, "--output", str(tmp_path / f"{name}.json")])
        rendered = json.loads((tmp_path / name / "render.json").read_text())
        timing = json.loads((tmp_path / f"{name}-maps" / "timing.json").read_text())
        for record in (rendered, timing):
            assert "train_seconds" not in record
            assert (record["train_step_seconds"], record["train_compile_seconds"], record["train_wall_seconds"]) == (
                steps, compiled, wall)


def test_a_run_saved_with_values_refused_since_still_renders_and_scores(tiny_run, tmp_path):
    """Uncertainty threshold 0 and a u_init_logit beyond ±30, which older splatu trained with, are refused for new
    runs only: a saved run with them renders and is scored, with finite maps (a loaded model reads neither)."""
    old = tmp_path / "old"
    shutil.copytree(tiny_run, old, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    saved_with(old, **OLDER_VALUES)
    _render(old, "--max-views", "1", "--output", str(tmp_path / "render"))
    view = json.loads((tmp_path / "render" / "render.json").read_text())["per_view"][0]["name"]
    assert np.isfinite(np.load(tmp_path / "render" / "npy" / f"{view}_uncertainty.npy")).all()
    entrypoint(["eval-ause", "--load", str(old), "--output", str(tmp_path / "ause.json")])
    assert math.isfinite(json.loads((tmp_path / "ause.json").read_text())["mean"]["ause_mae"])


def test_ensemble_of_identical_members_has_zero_std_and_density_aware_adds_empty_space(tiny_run, tmp_path):
    ensemble = tmp_path / "ensemble"
    for k in range(2):
        shutil.copytree(tiny_run, ensemble / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty"))
    (ensemble / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"],
                                                        "wall_seconds": 12.5}))
    _render(ensemble, "--method", "ensemble", "--max-views", "2", "--output", str(tmp_path / "plain"))
    _render(ensemble, "--method", "ensemble", "--density-aware", "--max-views", "2",
            "--output", str(tmp_path / "aware"))
    record = json.loads((tmp_path / "plain" / "render.json").read_text())
    member = json.loads((tiny_run / "summary.json").read_text())  # each member's
    assert (record["train_step_seconds"], record["train_wall_seconds"]) == (2 * member["train_seconds"], 12.5)
    assert (record["method"], record["density_aware"]) == ("ensemble", False)
    assert json.loads((tmp_path / "aware" / "render.json").read_text())["density_aware"] is True
    for view in record["per_view"]:
        plain = np.load(tmp_path / "plain" / "npy" / f"{view['name']}_uncertainty.npy")
        aware = np.load(tmp_path / "aware" / "npy" / f"{view['name']}_uncertainty.npy")
        alpha = np.load(tmp_path / "aware" / "npy" / f"{view['name']}_alpha.npy")
        assert np.abs(plain).max() < 1e-6
        assert np.allclose(aware, (1.0 - alpha) ** 2, atol=1e-5)


def test_wrong_method_for_the_run_is_one_line(tiny_run, capsys):
    with pytest.raises(SystemExit) as exc:
        _render(tiny_run, "--method", "ensemble")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ensemble" in err[0]


def test_without_method_a_run_renders_and_scores_its_own_uncertainty(tiny_run, tmp_path, capsys):
    """An ensemble run was refused without --method ensemble ("--method ours needs a single run"): with no --method
    it renders and scores its std, under the names --method ensemble writes; a single run still gives ours."""
    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    _render(ensemble, "--max-views", "1")
    entrypoint(["eval-ause", "--load", str(ensemble)])
    assert "with ensemble" in capsys.readouterr().out
    written = _folder_names(ensemble)
    assert {"uncertainty/ensemble-eval/render.json", "ause_ensemble.json"} <= written
    assert json.loads((ensemble / "uncertainty" / "ensemble-eval" / "render.json").read_text())["method"] == "ensemble"
    report = json.loads((ensemble / "ause_ensemble.json").read_text())
    assert (report["method"], report["options"]["method"]) == ("ensemble", "ensemble")
    _render(ensemble, "--max-views", "1", "--method", "ensemble")
    entrypoint(["eval-ause", "--load", str(ensemble), "--method", "ensemble"])
    assert _folder_names(ensemble) == written
    _render(tiny_run, "--max-views", "1", "--output", str(tmp_path / "single"))
    assert json.loads((tmp_path / "single" / "render.json").read_text())["method"] == "ours"
    entrypoint(["eval-ause", "--load", str(tiny_run), "--output", str(tmp_path / "single.json")])
    report = json.loads((tmp_path / "single.json").read_text())
    assert (report["method"], report["options"]["method"]) == ("ours", "ours")


def test_an_option_of_one_method_without_method_follows_the_run(tiny_run, tmp_path, capsys):
    """Without --method, --density-aware applies to an ensemble run (its default is the ensemble) and is refused for a
    single run, in one line that says what that run renders with and suggests nothing it cannot render."""
    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    _render(ensemble, "--density-aware", "--max-views", "1")
    record = json.loads((ensemble / "uncertainty" / "ensemble-density-aware-eval" / "render.json").read_text())
    assert (record["method"], record["density_aware"]) == ("ensemble", True)
    for command in ("render-uncertainty", "eval-ause"):
        line = _one_line(capsys, [command, "--load", str(tiny_run), "--density-aware"])
        assert line == ("error: --density-aware only applies with --method ensemble; this is a single run, rendered "
                        "with ours without --method, in the command's options, drop --density-aware (it applies to "
                        "an ensemble run)")
    assert not (tiny_run / "uncertainty" / "ours-density-aware-eval").exists()
    line = _one_line(capsys, ["render-uncertainty", "--load", str(ensemble), "--seed", "1"])
    assert "this is an ensemble run, rendered with ensemble" in line and line.endswith("(it applies to a single run)")
    line = _one_line(capsys, ["eval-ause", "--load", str(ensemble), "--method", "ours"])  # typed: refused as before
    assert "--method ours needs a single run, this is an ensemble" in line and "drop --method" in line


def test_open_run_without_method_renders_the_runs_own_uncertainty(tiny_run, tmp_path):
    """open_run refused an ensemble run without method="ensemble"; like render-uncertainty, it now takes the run's
    own: the ensemble's std (with density_aware too), or ours for a single run."""
    from splatu.query import open_run

    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    assert [open_run(ensemble, density_aware=aware).method for aware in (False, True)] == ["ensemble"] * 2
    assert open_run(tiny_run).method == "ours"


def test_load_may_name_a_checkpoint_file_and_writes_beside_its_run_under_its_own_name(tiny_run):
    """The error messages offer `--load RUN_OR_CHECKPOINT`; a checkpoint used to make the default output folder a
    path under the .pt file, and then the run's own folder, where an earlier checkpoint's render and scores
    replaced the final model's."""
    from splatu.checkpoint import list_checkpoints

    checkpoint = list_checkpoints(tiny_run)[-1]
    _render(tiny_run, "--max-views", "1")
    final = tiny_run / "uncertainty" / "ours-eval"
    kept = {name: (final / name).read_bytes() for name in _folder_names(final)}
    _render(checkpoint, "--max-views", "2")
    entrypoint(["eval-ause", "--load", str(checkpoint)])
    mine = tiny_run / "uncertainty" / f"ours-{checkpoint.stem}-eval" / "render.json"
    assert len(json.loads(mine.read_text())["per_view"]) == 2
    assert (tiny_run / f"ause_ours-{checkpoint.stem}.json").is_file()
    assert {name: (final / name).read_bytes() for name in _folder_names(final)} == kept


def test_training_into_an_output_folder_that_is_a_file_fails_before_the_scene_loads(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    line = _one_line(capsys, ["train", "--data", str(tmp_path / "no_such_scene"), "--output-dir", str(a_file)])
    assert "cannot write" in line and "--output-dir" in line  # not "scene not found": checked first


def _listing(folder: Path) -> list[tuple[str, int]]:
    return sorted((str(p.relative_to(folder)), p.stat().st_mtime_ns) for p in folder.rglob("*"))


def test_eval_ause_with_an_output_writes_nothing_into_the_run(tiny_run, tmp_path, capsys):
    """A run folder that cannot be written to (a colleague's, a read-only share) can be scored: with --output, the
    maps it scores go beside the JSON, not into <run>/uncertainty/."""
    before = _listing(tiny_run)
    out = tmp_path / "scores" / "ause.json"
    entrypoint(["eval-ause", "--load", str(tiny_run), "--output", str(out)])
    assert _listing(tiny_run) == before
    report = json.loads(out.read_text())
    assert report["images"] == 5 and out.with_suffix(".png").is_file()
    maps = out.with_name("ause-maps")
    assert len(list((maps / "uncertainty").glob("*.npy"))) == 5 and (maps / "timing.json").is_file()
    entrypoint(["eval-ause", "--load", str(tiny_run), "--output", str(out)])  # its own maps are replaced
    assert json.loads(out.read_text())["mean"] == report["mean"]


def test_eval_ause_never_replaces_a_folder_it_did_not_write(tiny_run, tmp_path, capsys):
    theirs = tmp_path / "ause-maps"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine")
    with pytest.raises(SystemExit) as exc:
        entrypoint(["eval-ause", "--load", str(tiny_run), "--output", str(tmp_path / "ause.json")])
    assert exc.value.code == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "holds something else" in lines[0] and str(theirs) in lines[0]
    assert (theirs / "notes.txt").read_text() == "mine" and not (tmp_path / "ause.json").exists()


def test_export_of_the_last_checkpoint_is_the_runs_own_ply_and_an_earlier_one_goes_to_exports(tiny_run, tmp_path,
                                                                                             capsys):
    """`splatu export` writes what training writes at its end, for any checkpoint: a run stopped early, or an earlier
    step, can be opened in a viewer too."""
    from splatu.checkpoint import list_checkpoints

    out = tmp_path / "final.ply"
    entrypoint(["export", "--load", str(tiny_run), "--output", str(out)])
    assert out.read_bytes() == (tiny_run / "splat.ply").read_bytes()
    assert "wrote" in capsys.readouterr().out
    checkpoints = list_checkpoints(tiny_run)
    entrypoint(["export", "--load", str(checkpoints[-1])])
    assert (tiny_run / "exports" / f"splat-{checkpoints[-1].stem}.ply").read_bytes() == out.read_bytes()
    with pytest.raises(SystemExit) as exc:
        entrypoint(["export", "--load", str(tiny_run), "--output", str(tmp_path / "model.txt")])
    assert exc.value.code == 2 and "--output must name a .ply file" in capsys.readouterr().err
    entrypoint(["export", "--load", str(tiny_run), "--output", str(tmp_path / "FINAL.PLY")])  # was refused
    assert (tmp_path / "FINAL.PLY").read_bytes() == out.read_bytes()
    copy = tmp_path / "best (copy).pt"  # a checkpoint a user renamed: its name is not a step
    shutil.copy(checkpoints[-1], copy)
    entrypoint(["export", "--load", str(copy), "--output", str(tmp_path / "best.ply")])
    assert (tmp_path / "best.ply").read_bytes() == out.read_bytes() and "best (copy).pt" in capsys.readouterr().out


def _data_frame_camera(camera: Camera, frame) -> np.ndarray:
    """`camera` (in the model's normalised frame) as a data-frame world-to-camera, the inverse of the query's move:
    x_norm = Rᵀ(x_data − t)/s, so p_cam = Rc·Rᵀ·x_data/s + (tc − Rc·Rᵀ·t/s), times s for the same pixels."""
    rotation, translation = camera.world_to_camera[:3, :3].double(), camera.world_to_camera[:3, 3].double()
    R, t, s = frame.rotation.double(), frame.translation.double(), frame.scale
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = rotation @ R.T
    w2c[:3, 3] = s * translation - rotation @ R.T @ t
    return w2c.numpy()


def test_a_candidate_view_in_the_data_frame_renders_as_render_uncertainty_renders_it(tiny_run):
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    run = open_run(tiny_run)
    camera = load_scene(run_data(load_any_run(tiny_run))).eval.cameras[0]
    assert run.frame.scale != 1.0 and run.frame.translation.abs().max() > 0  # the frames differ, so this tests a move
    view = run.render(_data_frame_camera(camera, run.frame), camera.K.numpy(), camera.width, camera.height)
    expected = run.models[0].render(camera, run.config.model.sh_degree, torch.zeros(3), with_uncertainty=True)
    assert np.allclose(view.rgb, expected.rgb.detach().numpy(), atol=1e-5)
    assert np.allclose(view.alpha, expected.alpha.detach().numpy(), atol=1e-5)
    assert np.allclose(view.uncertainty, expected.uncertainty.detach().numpy(), atol=1e-5)
    assert np.allclose(view.depth, expected.depth.detach().double().numpy() * run.frame.scale, rtol=1e-5, atol=1e-6)
    assert view.uncertainty.min() >= 0 and view.uncertainty.max() <= 1 and view.alpha.max() > 0.5
    assert view.mean_uncertainty == pytest.approx(float(view.uncertainty.mean()))
    with warnings.catch_warnings():  # tensors (a planner's, on any device) were read through numpy's deprecated path
        warnings.simplefilter("error")
        as_tensors = run.render(torch.from_numpy(_data_frame_camera(camera, run.frame)), camera.K, camera.width,
                                camera.height)
    assert np.array_equal(as_tensors.uncertainty, view.uncertainty)
    away = _data_frame_camera(dataclasses.replace(camera, world_to_camera=look_at(
        torch.tensor([0.0, 0.0, -50.0]), torch.tensor([0.0, 0.0, -100.0]), torch.tensor([0.0, 1.0, 0.0]))), run.frame)
    empty = run.render(away, camera.K.numpy(), camera.width, camera.height)  # looking into empty space
    assert empty.mean_uncertainty == pytest.approx(1.0) and view.mean_uncertainty < empty.mean_uncertainty
    assert empty.coverage == 0.0 and view.coverage == pytest.approx(float(view.alpha.mean())) and view.coverage > 0.5


@pytest.mark.parametrize(("change", "message"), [
    (lambda w2c, K: (w2c * np.nan, K), "pose has non-finite values"),
    (lambda w2c, K: (w2c * 2.0, K), "pose's last row is [0.0, 0.0, 0.0, 2.0]"),
    (lambda w2c, K: (w2c[:2], K), "pose is not a 3x4 or 4x4 matrix"),
    (lambda w2c, K: (w2c, K[:2]), "K must be a (3, 3) matrix, got shape (2, 3)"),
    (lambda w2c, K: (w2c, np.where(np.eye(3) == 1, K, np.nan)), "K has non-finite entries (NaN or Inf)"),
    (lambda w2c, K: (w2c, -K), "focal lengths must be positive"),
    (lambda w2c, K: (w2c, K * 1e9), "longer than any camera"),
    (lambda w2c, K: (np.concatenate([np.eye(4)[:, :3], [[1e39], [0.0], [0.0], [1.0]]], axis=1), K),
     "beyond float32's range"),
    # the rasterizer reads fx, fy, cx, cy only: a skew, or a K scaled as a whole (K / 8), rendered another view
    (lambda w2c, K: (w2c, K + np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])), "K has a skew"),
    (lambda w2c, K: (w2c, K / 8), "K's last row is [0.0, 0.0, 0.125]"),
    # K of the full-resolution images at a --downscale 8 size (or the reverse) rendered a shifted, zoomed view
    (lambda w2c, K: (w2c, np.diag([8.0, 8.0, 1.0]) @ K), "K's principal point (192, 320) lies outside the 48x80 image"),
    (lambda w2c, K: (w2c, K - np.array([[0.0, 0.0, 30.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
     "K's principal point (-6, 40) lies outside"),
    # cx past the width but within the height, and cy alone off the image: each side against its own size
    (lambda w2c, K: (w2c, K + np.array([[0.0, 0.0, 36.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
     "K's principal point (60, 40) lies outside the 48x80 image"),
    (lambda w2c, K: (w2c, K + np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0], [0.0, 0.0, 0.0]])),
     "K's principal point (24, 90) lies outside the 48x80 image"),
    # a 2x2 grid's tiles: the top-left one (its point on its corner at (1, 1)) refused as the other three are
    (lambda w2c, K: (w2c, np.diag([2.0, 2.0, 1.0]) @ K), "K's principal point (48, 80) lies on the edge of the 48x80 "
     "image, as for a K made for an image 2 times this size, in RunQuery.render"),
    (lambda w2c, K: (w2c, K - np.array([[0.0, 0.0, 24.0], [0.0, 0.0, 40.0], [0.0, 0.0, 0.0]])),
     "K's principal point (0, 0) lies on the edge of the 48x80 image, in RunQuery.render, pass the K of this size"),
    (lambda w2c, K: (w2c, K + np.array([[0.0, 0.0, 24.0], [0.0, 0.0, -40.0], [0.0, 0.0, 0.0]])),
     "; for a tile or crop of a larger photo (a tile scene's own cameras too), pass off_centre_ok=True"),
    # K of an 80×48 image (width and height passed the wrong way round), and of a half-size one: inside the image
    (lambda w2c, K: (w2c, K[[1, 0, 2]][:, [1, 0, 2]]), "K's principal point (40, 24) is 33% of the width off the "
     "centre of the 48x80 image, but at the centre of a 80x48 one"),
    (lambda w2c, K: (w2c, np.diag([0.5, 0.5, 1.0]) @ K), "K's principal point (12, 20) is at 25% x 25% of the 48x80 "
     "image, as for a K made for an image 0.5 times this size"),
    (lambda w2c, K: ([*w2c.tolist()[:3], [0.0, 1.0]], K), "pose is not a 3x4 or 4x4 matrix"),  # ragged
    (lambda w2c, K: ([["a"] * 4] * 4, K), "pose holds 'a', which is not a number"),
    (lambda w2c, K: (w2c, "K"), "K is not an array of numbers"),
])
def test_a_bad_candidate_camera_is_one_clear_error(tiny_run, change, message):
    from splatu.query import open_run

    K = np.array([[40.0, 0.0, 24.0], [0.0, 40.0, 40.0], [0.0, 0.0, 1.0]])
    with pytest.raises(SplatuError, match=re.escape(message)):
        open_run(tiny_run).render(*change(np.eye(4), K), 48, 80)


def test_a_near_square_candidate_with_width_and_height_swapped_is_refused(tiny_run):
    """A K made for 60x80 passed with 80x60 (a 4:3 swap, the point 17% off-centre) rendered a shifted view without a
    word; it is refused as the wider swaps are, and renders on the caller's word (off_centre_ok=True)."""
    from splatu.query import open_run

    run = open_run(tiny_run)
    K = np.array([[60.0, 0.0, 30.0], [0.0, 60.0, 40.0], [0.0, 0.0, 1.0]])
    assert run.render(np.eye(4), K, 60, 80).rgb.shape == (80, 60, 3)
    with pytest.raises(SplatuError, match=re.escape("K's principal point (30, 40) is 17% of the height off the centre "
                                                    "of the 80x60 image, but at the centre of a 60x80 one")) as caught:
        run.render(np.eye(4), K, 80, 60)
    assert caught.value.fix.startswith("pass the width before the height, or swap K's cx and cy")
    assert run.render(np.eye(4), K, 80, 60, off_centre_ok=True).rgb.shape == (60, 80, 3)


def test_a_pose_as_a_file_rounds_it_renders_and_a_scaled_one_is_refused(tiny_run):
    """A pose written with 5 decimals (R·Rᵀ off by ~1e-5, as a transforms.json or a float32 export gives it) is what
    the loaders train with (they allow 1e-3), so the query renders it; a pose with a 1% scale is refused."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    run = open_run(tiny_run)
    camera = load_scene(run_data(load_any_run(tiny_run))).eval.cameras[0]
    exact = _data_frame_camera(camera, run.frame)
    rounded = np.round(exact, 5)
    assert np.abs(rounded[:3, :3] @ rounded[:3, :3].T - np.eye(3)).max() > 1e-6  # beyond float64 noise
    view, expected = (run.render(w2c, camera.K.numpy(), camera.width, camera.height) for w2c in (rounded, exact))
    assert np.abs(view.rgb - expected.rgb).mean() < 1e-3
    scaled = exact.copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(SplatuError, match="pose rotation is not a rotation matrix"):
        run.render(scaled, camera.K.numpy(), camera.width, camera.height)


def test_an_image_size_as_numpy_gives_it_or_an_integral_float_renders_and_a_bool_or_fraction_is_refused(tiny_run):
    """Sizes read from an array of them (np.int64) are whole numbers and render, as is 48.0 (W * scale gives one);
    True (a 1), 48.5 or "80" are not sizes, and the error says which (it said "got 48×80" of a string)."""
    from splatu.query import open_run

    run = open_run(tiny_run)
    K = np.array([[40.0, 0.0, 24.0], [0.0, 40.0, 40.0], [0.0, 0.0, 1.0]])
    width, height = np.array([48, 80])
    assert isinstance(width, np.int64)
    view = run.render(np.eye(4), K, width, height)
    assert view.rgb.shape == (80, 48, 3) and np.array_equal(view.rgb, run.render(np.eye(4), K, 48, 80).rgb)
    # an integral float (W * scale) is a size; a string, a bool or a fraction says what it is
    assert np.array_equal(run.render(np.eye(4), K, 48.0, np.float32(80.0)).rgb, view.rgb)
    for size, message in (((True, True), "the image width is a bool (True), not a number of pixels"),
                          ((48.5, 80), "the image width 48.5 is not a whole number of pixels"),
                          ((48, "80"), "the image height is a str ('80'), not a number of pixels"),
                          ((48, float("nan")), "the image height nan is not a whole number of pixels"),
                          ((48.0, -80.0), "positive integers up to")):
        with pytest.raises(SplatuError, match=re.escape(message)):
            run.render(np.eye(4), K, *size)
    wide = np.array([[4e4, 0.0, 24.0], [0.0, 4e4, 4.0], [0.0, 0.0, 1.0]])  # a plausible focal length for that width
    with pytest.raises(SplatuError, match=f"positive integers up to {MAX_IMAGE_SIDE}"):  # larger than the loaders take
        run.render(np.eye(4), wide, MAX_IMAGE_SIDE + 1, 8)


def test_a_size_the_machine_has_not_the_memory_for_is_refused_before_rendering(tiny_run, tmp_path, monkeypatch,
                                                                               capsys):
    """Each side was checked alone: a 14400×25600 render was taken and grew to 21 GB before the OS killed it. The
    query and --cameras refuse a size whose render would not fit in the machine's memory, naming both; checked
    against a machine said to have 23 GB, so nothing large is allocated."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data import frames
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    monkeypatch.setattr(frames, "usable_memory", lambda: 23 * 10**9)
    run = open_run(tiny_run)
    K = np.array([[4e4, 0.0, 7200.0], [0.0, 4e4, 12800.0], [0.0, 0.0, 1.0]])
    with pytest.raises(SplatuError, match=re.escape("a 14400×25600 render needs about 89.5 GB (~240 bytes per pixel), "
                                                    "more than the 23.0 GB of memory this process may use")) as error:
        run.render(np.eye(4), K, 14400, 25600)
    assert "smaller width and height" in error.value.fix
    assert run.render(np.eye(4), K / np.array([[100.0], [100.0], [1.0]]), 144, 256).rgb.shape == (256, 144, 3)
    source = json.loads(Path(load_scene(run_data(load_any_run(tiny_run))).source).read_text())
    candidates = tmp_path / "huge.json"
    frame = dict(source["frames"][0], file_path="huge")
    big = {"w": 14400, "h": 25600, "fl_x": 4e4, "fl_y": 4e4, "cx": 7200.0, "cy": 12800.0}
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"}, **big, "frames": [frame]}))
    line = _one_line(capsys, ["render-uncertainty", "--load", str(tiny_run), "--cameras", str(candidates),
                              "--output", str(tmp_path / "out")])
    assert "a 14400×25600 render needs about 89.5 GB" in line and f"in {candidates}" in line and "fl_x" in line


def test_the_scenes_own_cameras_render_as_the_run_saw_them(tiny_run, tmp_path):
    """`scene_cameras` names every view with its data-frame pose, K and size, so `render(*camera)` is the run's own
    render of it; a scene that is not there, or another one, is one line."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene
    from splatu.query import open_run
    from tests.synthetic_scenes import write_nerfstudio_scene

    run = open_run(tiny_run)
    scene = load_scene(run_data(load_any_run(tiny_run)))
    cameras = run.scene_cameras()
    assert set(cameras) == set(scene.train.names) | set(scene.eval.names) | {
        n for views in scene.extra_eval.values() for n in views.names}
    camera = scene.eval.cameras[0]
    view = run.render(*cameras[scene.eval.names[0]])
    expected = run.models[0].render(camera, run.config.model.sh_degree, torch.zeros(3), with_uncertainty=True)
    assert np.allclose(view.rgb, expected.rgb.detach().numpy(), atol=1e-5)
    assert np.allclose(view.uncertainty, expected.uncertainty.detach().numpy(), atol=1e-5)
    with pytest.raises(SplatuError, match="the run's scene is not at"):
        run.scene_cameras(tmp_path / "gone")
    write_nerfstudio_scene(tmp_path / "other")
    with pytest.raises(SplatuError, match="normalisation differs"):
        run.scene_cameras(tmp_path / "other")


def _tile_scene(run, root: Path) -> dict[str, tuple[str, int, int]]:
    """A nerfstudio scene (files only, no image) of the run's own views each cut into 2x2 tiles, as aerial grids
    are: every tile with its photo's pose and K shifted to the tile, so each has its principal point on a corner.
    Tiles share their photos' centres, so the scene normalises as the run's: its cameras are the run's to query.
    Returns each tile's (photo, column, row)."""
    from tests.synthetic_scenes import write_transforms

    tiles, names, where = [], [], {}
    for photo, (w2c, K, width, height) in sorted(run.scene_cameras().items()):
        for row in range(2):
            for col in range(2):
                tile_K = K.copy()
                tile_K[0, 2] -= col * width // 2
                tile_K[1, 2] -= row * height // 2
                tiles.append(Camera(torch.from_numpy(tile_K), torch.from_numpy(w2c), width // 2, height // 2))
                names.append(f"tiles/{Path(photo).stem}_{row}{col}.png")
                where[names[-1]] = (photo, col * width // 2, row * height // 2)
    root.mkdir()
    write_transforms(root / "transforms.json", tiles, names)
    return where


def test_a_tile_scenes_own_cameras_render_with_off_centre_ok_as_their_part_of_the_whole_photo(tiny_run, tmp_path):
    """A scene of tiles trains (with a warning), and `SceneCamera` promises `run.render(*camera)`: its cameras,
    whose principal points sit on their corners, were refused as "outside" with no way to render them. They are
    still refused without a word from the caller (a candidate's K of another size looks the same), with the fix
    naming off_centre_ok=True; with it each tile renders as its part of the whole photo's render."""
    from splatu.query import open_run

    run = open_run(tiny_run)
    where = _tile_scene(run, tmp_path / "tiles")
    tiles = run.scene_cameras(tmp_path / "tiles")
    assert set(tiles) == set(where)
    whole = run.scene_cameras()
    for name in sorted(tiles)[:4]:  # one photo's four tiles
        with pytest.raises(SplatuError, match="lies on the edge of the 24x40 image") as caught:
            run.render(*tiles[name])
        assert caught.value.fix.endswith("for a tile or crop of a larger photo (a tile scene's own cameras too), "
                                         "pass off_centre_ok=True")
        photo, left, top = where[name]
        tile = run.render(*tiles[name], off_centre_ok=True)
        full = run.render(*whole[photo])
        assert tile.rgb.shape == (40, 24, 3)
        # its own part of the photo, not another, up to the Gaussians its narrower clamp range bends
        # (docs/usage.md, Data)
        error = {(x, y): float(np.abs(tile.rgb - full.rgb[y:y + 40, x:x + 24]).mean())
                 for x in (0, 24) for y in (0, 40)}
        assert min(error, key=error.__getitem__) == (left, top) and error[left, top] < 5e-3, error


def test_a_tile_scenes_own_cameras_render_from_a_camera_file_with_off_centre_ok(tiny_run, tmp_path, capsys):
    """`--views cameras` refused a tile scene's own cameras, its fix saying only to cut each tile out of the whole
    photo's render; the refusal now names --off-centre-ok, which renders them as the query does."""
    from splatu.query import open_run

    run = open_run(tiny_run)
    assert run.config.data.downscale in (None, 1)  # so the tiles' K is the scene's at full resolution, as the file's
    _tile_scene(run, tmp_path / "tiles")
    content = json.loads((tmp_path / "tiles" / "transforms.json").read_text())
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**content, "frames": content["frames"][:4]}))
    options = ["render-uncertainty", "--load", str(tiny_run), "--views", "cameras", "--cameras", str(candidates),
               "--output", str(tmp_path / "out")]
    line = _one_line(capsys, options)
    assert "lies on the edge of the 24x40 image" in line and line.endswith(
        "for tiles or crops of a larger photo (a tile scene's own cameras too), pass --off-centre-ok")
    entrypoint([*options, "--off-centre-ok"])
    tiles = run.scene_cameras(tmp_path / "tiles")
    per_view = json.loads((tmp_path / "out" / "render.json").read_text())["per_view"]
    assert len(per_view) == 4
    for view in per_view:
        expected = run.render(*tiles[view["source_name"]], off_centre_ok=True)
        for key in ("rgb", "uncertainty"):
            got = np.load(tmp_path / "out" / "npy" / f"{view['name']}_{key}.npy")
            assert np.allclose(got, getattr(expected, key), atol=1e-5), (view["name"], key)


def test_open_run_errors_give_a_python_caller_a_way_on(tiny_run, tmp_path):
    """An ensemble's members trained without the loss, so it renders only as method="ensemble", and that method only
    an ensemble; an unknown head or method is named with the argument a Python caller passes (head=, method=)."""
    from splatu.query import open_run

    (tmp_path / "ensemble.json").write_text("{}")
    with pytest.raises(SplatuError) as error:
        open_run(tmp_path, method="ours")
    assert "ensemble" in error.value.what and 'method="ensemble"' in error.value.fix and "ensemble.json" not in str(
        error.value)
    with pytest.raises(SplatuError, match='method="ensemble" needs an ensemble run'):
        open_run(tiny_run, method="ensemble")
    # random is no typo: it is left out on purpose, which "unknown method 'random'" hid
    for method, message in (("random", 'method="random" is not offered from Python: its uniform noise would rank'),
                            ("angel", "unknown method 'angel'")):
        with pytest.raises(SplatuError, match=re.escape(message)) as error:
            open_run(tiny_run, method=method)
        assert "angle" in error.value.fix and "random" not in error.value.fix
    with pytest.raises(SplatuError, match="no uncertainty head 'kind=mean'") as error:
        open_run(tiny_run, head="kind=mean")
    assert "head=" in error.value.fix and "--head" not in error.value.fix and EXTRA_HEAD in error.value.fix
    assert open_run(tiny_run, head=EXTRA_HEAD).config.model.u_sh_degree == 0


def test_an_ensemble_renders_its_members_disagreement_through_the_query(tiny_run, tmp_path):
    """Two identical members disagree nowhere: std 0, and (1 − alpha)² with density_aware, as eval-ause scores it."""
    from splatu.query import open_run

    ensemble = tmp_path / "ensemble"
    for k in range(2):
        shutil.copytree(tiny_run, ensemble / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty"))
    (ensemble / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"]}))
    single = open_run(tiny_run)
    camera = next(iter(single.scene_cameras().values()))
    plain, aware = (open_run(ensemble, method="ensemble", density_aware=aware).render(*camera)
                    for aware in (False, True))
    assert np.abs(plain.uncertainty).max() < 1e-6 and plain.alpha.mean() > 0.5
    assert np.allclose(aware.uncertainty, (1.0 - aware.alpha) ** 2, atol=1e-5)
    assert np.allclose(plain.rgb, single.render(*camera).rgb, atol=1e-6)


def test_the_readmes_python_example_runs(tiny_run, capsys):
    """The README's `splatu.query` example runs as pasted, on the tiny run: it takes its camera from the run itself,
    a held-out one, and renders it and a turned copy of it."""
    from splatu.query import open_run

    readme = (Path(__file__).parents[2] / "README.md").read_text()
    example = readme.split("### Python:", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    assert 'open_run("outputs/poster/splatu/latest")' in example
    names: dict = {}
    exec(example.replace("outputs/poster/splatu/latest", str(tiny_run)), names)
    run = open_run(tiny_run)
    training = run.training_cameras()
    camera = next(camera for name, camera in run.scene_cameras().items() if name not in training)
    assert np.array_equal(names["world_to_camera"], camera.world_to_camera)
    assert names["view"].uncertainty.shape == (camera.height, camera.width)
    assert 0.0 < names["view"].mean_uncertainty < 1.0 and not np.allclose(names["turned"], camera.world_to_camera)
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and all(line.startswith("mean U ") and "° from " in line for line in lines)


def test_a_run_still_training_renders_its_newest_checkpoint_under_that_checkpoints_name(tiny_run, tmp_path, capsys):
    """While `splatu train` holds the run (its lock), its newest checkpoint is an intermediate model: rendering, scoring
    and ranking it went on without a word, and wrote `uncertainty/ours-train` and `ause_ours.json` as if of the
    finished run. Now each says so and names what it writes after the checkpoint, as `--load <that file>` does."""
    import warnings

    from splatu.checkpoint import list_checkpoints
    from splatu.query import open_run
    from splatu.run_dir import training_lock

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    newest = list_checkpoints(copy)[-1]
    with training_lock(copy):  # as a `splatu train` of this run holds it
        _render(copy, "--views", "train", "--max-views", "1")
        assert f"{newest.name}, is the model used; what is written is named after it" in capsys.readouterr().err
        entrypoint(["eval-ause", "--load", str(copy)])
        assert f"{newest.name}, is the model used; the report is named after it" in capsys.readouterr().err
        with pytest.warns(UserWarning, match=re.escape(f"its newest checkpoint so far, {newest.name}, is the model")):
            open_run(copy)
    label = f"ours-{newest.stem}"
    assert (copy / "uncertainty" / f"{label}-train" / "render.json").is_file()
    assert (copy / f"ause_{label}.json").is_file() and not (copy / "ause_ours.json").exists()
    assert not (copy / "uncertainty" / "ours-train").exists()
    _render(copy, "--views", "train", "--max-views", "1")
    assert "still training" not in capsys.readouterr().err and (copy / "uncertainty" / "ours-train").is_dir()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_run(copy)


def test_render_json_names_each_candidate_as_its_file_does(tiny_run, tmp_path, capsys):
    """A candidate's file_path `near0.5` is written as `near0_*.npy`: render.json also gives the name the file gave
    it, so a planner can match the ranking back to its candidates (render.json named only the stem `near0`).
    `--cameras` alone asks for them: it implies `--views cameras` (it was refused without it)."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene

    scene = load_scene(run_data(load_any_run(tiny_run)))
    source = json.loads(Path(scene.source).read_text())
    frames = [dict(source["frames"][0], file_path="near0.5"), dict(source["frames"][0], file_path="far/2.0")]
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"}, "frames": frames}))
    _render(tiny_run, "--cameras", str(candidates), "--output", str(tmp_path / "out"))
    record = json.loads((tmp_path / "out" / "render.json").read_text())
    assert record["views"] == "cameras"
    per_view = record["per_view"]
    assert [(v["name"], v["source_name"]) for v in per_view] == [("near0", "near0.5"), ("far_2", "far/2.0")]
    assert all((tmp_path / "out" / "npy" / f"{v['name']}_uncertainty.npy").is_file() for v in per_view)
    most, other = (v["source_name"] for v in sorted(per_view, key=lambda v: -v["mean_uncertainty"]))
    out = capsys.readouterr().out
    assert f"the most uncertain is {most} (" in out
    assert f"\n  1. {most} (mean U " in out and f"\n  2. {other} (mean U " in out and "° from " in out


def test_the_command_lists_the_views_of_highest_mean_u_not_only_the_first_of_a_tie():
    """Candidates of empty space tie at U = 1, and the summary named one of them: the command lists five, each
    with its coverage and nearest training view, most uncertain first, ties in the file's order."""
    def view(name: str, u: float, coverage: float) -> dict:
        return {"source_name": name, "mean_uncertainty": u, "coverage": coverage,
                "nearest_training_view": {"name": "train/3.png", "angle_degrees": 12.345, "distance": 0.5}}

    per_view = [view("seen", 0.2, 0.9), *(view(f"empty{k}", 1.0, 0.0) for k in range(4)), view("edge", 0.6, 0.4),
                view("side", 0.4, 0.7)]
    lines = render_uncertainty.ranking(per_view)
    assert lines[0] == "by mean U (5 of 7; render.json lists every view):"
    assert [line.split()[1] for line in lines[1:]] == ["empty0", "empty1", "empty2", "empty3", "edge"]
    assert lines[5] == "  5. edge (mean U 0.600, coverage 40%, 12.3° from train/3.png)"
    assert render_uncertainty.ranking(per_view[:1]) == []  # the summary line names a single view


def test_candidates_that_see_none_of_the_model_get_a_note_on_their_frame(tiny_run, tmp_path, capsys):
    """Poses from another scene or a viewer's frame see nothing, and their ranking then ranks empty space: the command
    says so once none covers 1% of its pixels, and says nothing when one sees the model."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene

    scene = load_scene(run_data(load_any_run(tiny_run)))
    source = json.loads(Path(scene.source).read_text())
    seen = source["frames"][0]
    away = []
    for k in (1, 2):  # moved far along the camera's back axis (OpenGL: +z): the scene lies far in front, unseen
        matrix = np.array(seen["transform_matrix"])
        matrix[:3, 3] += 1e4 * k * matrix[:3, 2]
        away.append(dict(seen, file_path=f"away{k}", transform_matrix=matrix.tolist()))
    header = {k: v for k, v in source.items() if k != "frames"}
    blind, mixed = tmp_path / "blind.json", tmp_path / "mixed.json"
    blind.write_text(json.dumps({**header, "frames": away}))
    mixed.write_text(json.dumps({**header, "frames": [*away, seen]}))
    _render(tiny_run, "--cameras", str(blind), "--output", str(tmp_path / "blind"))
    err = capsys.readouterr().err
    assert f"note: none of the 2 candidate cameras of {blind} sees the model" in " ".join(err.split())
    _render(tiny_run, "--cameras", str(mixed), "--output", str(tmp_path / "mixed"))
    assert "sees the model" not in capsys.readouterr().err


def test_candidate_cameras_from_a_file_render_as_the_same_training_views_do(tiny_run, tmp_path, capsys):
    """`--views cameras`: poses straight from a transforms.json (the data's frame), here three of the stand-in's own
    training frames, give the maps `--views train` gives those views."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.nerfstudio import frame_name
    from splatu.data.resolve import load_scene
    from splatu.maps import file_stems

    scene = load_scene(run_data(load_any_run(tiny_run)))
    source = json.loads(Path(scene.source).read_text())
    # three training views, spread over the path: those --max-views picks, so the train render draws them alone
    _render(tiny_run, "--views", "train", "--max-views", "3", "--output", str(tmp_path / "train"))
    chosen = {v["source_name"] for v in json.loads((tmp_path / "train" / "render.json").read_text())["per_view"]}
    assert chosen <= set(scene.train.names)
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"},
                                      "frames": [f for f in source["frames"] if frame_name(f["file_path"]) in chosen]}))
    capsys.readouterr()
    _render(tiny_run, "--views", "cameras", "--cameras", str(candidates), "--output", str(tmp_path / "cameras"))
    assert "the most uncertain is" in capsys.readouterr().out
    record = json.loads((tmp_path / "cameras" / "render.json").read_text())
    assert record["cameras"] == str(candidates.resolve())  # which file's cameras it ranks: every file shares a folder
    per_view = record["per_view"]
    assert len(per_view) == len(chosen) == 3
    for view in per_view:  # a view of empty space reads U = 1, so a ranking needs how much each view sees
        alpha = np.load(tmp_path / "cameras" / "npy" / f"{view['name']}_alpha.npy")
        assert view["coverage"] == pytest.approx(float(alpha.mean()), rel=1e-6) and view["coverage"] > 0.5
        nearest = view["nearest_training_view"]  # each is a training pose: its own view, at no angle or distance
        assert nearest["name"] in chosen and file_stems([nearest["name"]]) == [view["name"]]
        assert nearest["angle_degrees"] < 1e-3 and nearest["distance"] < 1e-5
    for view in per_view:
        for key in ("rgb", "depth", "uncertainty"):
            got = np.load(tmp_path / "cameras" / "npy" / f"{view['name']}_{key}.npy")
            want = np.load(tmp_path / "train" / "npy" / f"{view['name']}_{key}.npy")
            assert np.allclose(got, want, atol=1e-5), (view["name"], key)


@pytest.mark.parametrize(("args", "message"), [
    (("--views", "cameras"), "--views cameras renders the candidate cameras of a file, and none was given"),
    (("--views", "eval", "--cameras", "c.json"), "--cameras FILE renders candidate cameras, not --views eval"),
    (("--views", "orbit", "--cameras", "c.json"), "--cameras FILE renders candidate cameras, not --views orbit"),
    (("--views", "cameras", "--cameras", "missing.json"), "camera file not found"),
    (("--cameras", "missing.json"), "camera file not found"),
    (("--off-centre-ok",), "--off-centre-ok only applies with --cameras FILE, in the command's options, drop "
                          "--off-centre-ok, or pass --cameras FILE"),
])
def test_candidate_camera_options_are_refused_in_one_line(tiny_run, tmp_path, capsys, args, message):
    assert message in _one_line(capsys, ["render-uncertainty", "--load", str(tiny_run), *args,
                                         "--output", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_a_camera_file_with_a_bad_frame_is_one_line(tiny_run, tmp_path, capsys):
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({"w": 48, "h": 80, "fl_x": 40.0, "frames": [{"file_path": "a"}]}))
    line = _one_line(capsys, ["render-uncertainty", "--load", str(tiny_run), "--views", "cameras", "--cameras",
                              str(candidates), "--output", str(tmp_path / "out")])
    assert "no transform_matrix" in line and str(candidates) in line


@pytest.mark.parametrize("method", ["ours", "angle", "visibility", "ours-spread"])
def test_candidate_cameras_render_with_the_depths_the_query_gives_in_the_datas_units(tiny_run, tmp_path, method):
    """The same pose through `--views cameras --method M` and `splatu.query` with method=M gives the same maps:
    depth too, in the data's units (render-uncertainty wrote the model's normalised depth, off from the query's by
    the scene's scale), and the angular gap and visibility count built from the same training views."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.nerfstudio import read_cameras
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    scene = load_scene(run_data(load_any_run(tiny_run)))
    source = json.loads(Path(scene.source).read_text())
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"},
                                      "frames": [{**source["frames"][0], "file_path": "candidate"}]}))
    _render(tiny_run, "--views", "cameras", "--cameras", str(candidates), "--output", str(tmp_path / "out"),
            "--method", method)
    run = open_run(tiny_run, method=method)
    assert abs(run.frame.scale - 1.0) > 0.1  # the two units differ here
    (camera,) = read_cameras(candidates)
    view = run.render(camera.world_to_camera.numpy(), camera.K.numpy(), camera.width, camera.height)
    assert 0.0 < view.mean_uncertainty < 1.0 and np.ptp(view.uncertainty) > 0.01  # a map, not a constant
    for key in ("rgb", "alpha", "uncertainty", "depth"):
        written = np.load(tmp_path / "out" / "npy" / f"candidate_{key}.npy")
        assert np.allclose(written, getattr(view, key), rtol=1e-5, atol=1e-5), key


def test_the_nearest_training_view_is_the_closest_viewing_direction_with_its_angle_and_distance():
    from splatu.nearest_view import nearest_training_views

    origin = torch.zeros(3, dtype=torch.float64)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)

    def pose(position) -> torch.Tensor:
        return look_at(torch.tensor(position, dtype=torch.float64), origin, up)

    turned = math.radians(30.0)  # 30° from east towards north, twice as far out
    (nearest,) = nearest_training_views([pose([6 * math.cos(turned), 6 * math.sin(turned), 0.0])],
                                        [pose([3.0, 0.0, 0.0]), pose([0.0, 3.0, 0.0])], ["east", "north"], 2.0)
    assert nearest.name == "east" and nearest.angle_degrees == pytest.approx(30.0)
    expected = 2.0 * math.dist((6 * math.cos(turned), 6 * math.sin(turned)), (3.0, 0.0))  # in the data's units
    assert nearest.distance == pytest.approx(expected)
    # looking down at 45° from above east: the same right (x) and a different forward (z) axis as east's, so only
    # the forward axis (the rotation's third row) tells the two apart
    (nearest,) = nearest_training_views([pose([3.0, 0.0, 2.0])], [pose([3.0, 0.0, 0.0]), pose([3.0, 0.0, 3.0])],
                                        ["east", "above"])
    assert nearest.name == "above"


def test_open_run_refuses_an_option_its_method_never_reads(tiny_run):
    """render-uncertainty refuses --density-aware without --method ensemble and --head with a method that reads no
    head; open_run ignored density_aware=True and head= there, so a ranking asked to count empty space, or to use an
    extra head, came back as plain ours (or the baseline) without a word."""
    from splatu.query import open_run

    with pytest.raises(SplatuError, match='density_aware only applies with method="ensemble"') as error:
        open_run(tiny_run, density_aware=True)
    assert "--" not in error.value.fix
    with pytest.raises(SplatuError, match="head picks an uncertainty head of ours; method=\"angle\" has none") as error:
        open_run(tiny_run, method="angle", head=EXTRA_HEAD)
    assert "--" not in error.value.fix and "ours-spread" in error.value.fix
    assert open_run(tiny_run, method="ours-spread", head=EXTRA_HEAD).method == "ours-spread"


def test_open_run_tells_an_ensemble_opened_by_default_that_head_and_data_are_of_no_use(tmp_path):
    """With no method=, an ensemble is rendered as "ensemble": head= and data= were refused as of method="ensemble",
    which the caller never passed, with the advice to pass an ours-family method, which an ensemble refuses."""
    from splatu.query import open_run

    (tmp_path / "ensemble.json").write_text("{}")  # refused before the members load
    with pytest.raises(SplatuError) as error:
        open_run(tmp_path, head=EXTRA_HEAD)
    assert error.value.what == ("head picks an uncertainty head of ours; an ensemble run, rendered with its members' "
                                "std by default, has no uncertainty head") and error.value.fix == "drop head"
    with pytest.raises(SplatuError) as error:
        open_run(tmp_path, data=tmp_path / "moved")
    assert error.value.what == ("data= is where the scene is, which an ensemble run, rendered with its members' std "
                                "by default, never reads")
    assert "method=" not in error.value.fix and "run.training_cameras()" in error.value.fix
    with pytest.raises(SplatuError, match='method="ensemble" has none'):  # typed, it is named as typed
        open_run(tmp_path, method="ensemble", head=EXTRA_HEAD)


def test_open_run_refuses_data_for_a_method_that_never_reads_the_scene(tiny_run, tmp_path):
    """ours renders the model alone: open_run read no scene for it, so data= (the scene's new place) was dropped
    without a word, and a planner that passed it believed it checked. The methods that read the scene read it there."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    with pytest.raises(SplatuError, match='data= is where the scene is, which method="ours" never reads') as error:
        open_run(tiny_run, data=tmp_path / "moved")
    assert "run.training_cameras()" in error.value.fix and "--" not in error.value.fix
    with pytest.raises(SplatuError, match="scene not found") as error:
        open_run(tiny_run, method="angle", data=tmp_path / "moved")
    assert str(tmp_path / "moved") in error.value.where
    moved = tmp_path / "scene"  # the stand-in, named by its path as a moved scene is
    shutil.copytree(Path(load_scene(run_data(load_any_run(tiny_run))).source).parent, moved)
    assert open_run(tiny_run, method="angle", data=moved).method == "angle"


def test_a_render_without_ground_truth_decodes_no_image_unless_its_method_compares_with_them(tiny_run, tmp_path,
                                                                                            monkeypatch):
    """Candidate cameras and the orbit need the training cameras alone, and ours, fisher, angle and visibility
    never look at the training images: decoding fox's photos took longer than rendering four candidates of it. The
    residuals, which compare renders with the training images, and the eval views, whose ground truth they are,
    still decode them."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data import assemble
    from splatu.data.resolve import load_scene
    from splatu.query import open_run

    scene = load_scene(run_data(load_any_run(tiny_run)))
    source = json.loads(Path(scene.source).read_text())
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"},
                                      "frames": [{**source["frames"][0], "file_path": "candidate"}]}))
    decoded: list[str] = []
    load_pixels = assemble.load_pixels

    def counted(recipe, cache):
        decoded.append(recipe.kind)
        return load_pixels(recipe, cache)

    monkeypatch.setattr(assemble, "load_pixels", counted)
    for method in ("ours", "fisher"):
        _render(tiny_run, "--views", "cameras", "--cameras", str(candidates), "--method", method,
                "--output", str(tmp_path / method))
    _render(tiny_run, "--views", "orbit", "--orbit-frames", "2", "--output", str(tmp_path / "orbit"))
    for method in ("ours", "angle", "visibility"):
        open_run(tiny_run, method=method)
    assert decoded == []
    _render(tiny_run, "--views", "cameras", "--cameras", str(candidates), "--method", "residual",
            "--output", str(tmp_path / "residual"))
    assert decoded.count("color") >= len(scene.train)
    decoded.clear()
    open_run(tiny_run, method="ours-residual")
    assert decoded.count("color") > 0
    decoded.clear()
    _render(tiny_run, "--views", "eval", "--max-views", "1", "--output", str(tmp_path / "eval"))
    assert decoded.count("color") > 0


def test_empty_space_reads_as_the_view_uncertainty_docstring_says(tiny_run):
    """ViewUncertainty said U reads 1 where nothing is seen for every method but the ensemble; `residual` alone reads
    its worst, 1 / (1 + the typical training residual), there: below 1, so the docstring names it too."""
    from splatu.baselines.residual import residual_map
    from splatu.query import QUERY_METHODS, ViewUncertainty, open_run

    w2c, K, width, height = next(iter(open_run(tiny_run).scene_cameras().values()))
    nothing = w2c.copy()
    nothing[2, 3] -= 1e4  # the whole scene far behind the camera
    for method in (m for m in QUERY_METHODS if m != "ensemble"):
        run = open_run(tiny_run, method=method)
        view = run.render(nothing, K, width, height)
        assert view.alpha.max() == 0.0
        expected = 1.0 if method != "residual" else float(residual_map(torch.tensor(1.0), run.source.typical))
        assert np.allclose(view.uncertainty, expected, atol=1e-6), method
        assert (expected < 1.0) == (method == "residual")
    assert "residual" in " ".join(ViewUncertainty.__doc__.split())


def test_the_still_training_note_names_the_checkpoint_open_run_loaded(tiny_run, tmp_path, monkeypatch):
    """open_run named "the newest checkpoint so far" only after building the method, which for visibility, fisher,
    angle and the residuals reads the scene and passes over every training view: a checkpoint the training wrote
    meanwhile was named, though the model used was the one before it."""
    import shutil as shutil_module

    from splatu import query
    from splatu.checkpoint import list_checkpoints
    from splatu.run_dir import training_lock

    run_dir = tmp_path / "run"
    shutil_module.copytree(tiny_run, run_dir, ignore=shutil_module.ignore_patterns("uncertainty"))
    loaded = list_checkpoints(run_dir)[-1]
    build_method = query.build_method

    def a_checkpoint_lands_meanwhile(*args, **kwargs):
        shutil_module.copy(loaded, loaded.with_name("step-9999999.pt"))  # as the training saves its next one
        return build_method(*args, **kwargs)

    monkeypatch.setattr(query, "build_method", a_checkpoint_lands_meanwhile)
    with training_lock(run_dir), pytest.warns(UserWarning, match="still training") as caught:
        query.open_run(run_dir, method="angle")
    (note,) = [str(w.message) for w in caught if "still training" in str(w.message)]
    assert f"{loaded.name}, is the model used" in note and "9999999" not in note


def test_the_query_names_a_candidates_nearest_training_view_as_render_json_does(tiny_run, tmp_path):
    """`nearest_training_view` against `run.training_cameras()` (the run's own split, in the data's frame) gives what
    render.json gives the same candidate; a camera-to-world pose passed by mistake stands out by its distance."""
    from splatu.baselines.load import load_any_run, run_data
    from splatu.data.nerfstudio import read_cameras
    from splatu.data.resolve import load_scene
    from splatu.query import nearest_training_view, open_run

    scene = load_scene(run_data(load_any_run(tiny_run)))
    run = open_run(tiny_run)
    training = run.training_cameras()
    assert list(training) == scene.train.names  # the split the run trained on, not every camera
    own = training[scene.train.names[2]]
    name, angle, distance = nearest_training_view(own.world_to_camera, training)
    assert name == scene.train.names[2] and angle < 1e-9 and distance < 1e-12
    source = json.loads(Path(scene.source).read_text())
    candidates = tmp_path / "candidates.json"
    candidates.write_text(json.dumps({**{k: v for k, v in source.items() if k != "frames"},
                                      "frames": [{**source["frames"][k], "file_path": f"c{k}"} for k in (0, 9, 20)]}))
    _render(tiny_run, "--views", "cameras", "--cameras", str(candidates), "--output", str(tmp_path / "out"))
    record = json.loads((tmp_path / "out" / "render.json").read_text())
    for camera, view in zip(read_cameras(candidates), record["per_view"], strict=True):
        nearest = nearest_training_view(camera.world_to_camera.numpy(), training)
        assert nearest.name == view["nearest_training_view"]["name"]
        assert nearest.angle_degrees == pytest.approx(view["nearest_training_view"]["angle_degrees"], abs=1e-4)
        assert nearest.distance == pytest.approx(view["nearest_training_view"]["distance"], rel=1e-5, abs=1e-6)
    flipped = np.linalg.inv(own.world_to_camera)  # camera-to-world, in the wrong argument
    centres = np.stack([-c.world_to_camera[:3, :3].T @ c.world_to_camera[:3, 3] for c in training.values()])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.eye(len(centres)) * 1e9
    spacing = float(np.median(gaps.min(axis=1)))  # between neighbouring training cameras
    assert nearest_training_view(flipped, training).distance > 3 * spacing
    with pytest.raises(SplatuError, match="no training cameras"):
        nearest_training_view(own.world_to_camera, {})


def test_open_run_renders_a_baseline_or_an_ensemble_of_runs_trained_without_the_uncertainty_loss(tiny_run, tmp_path,
                                                                                                 monkeypatch):
    """Only the methods that read the run's uncertainty SH need the loss: a plain splatfacto run renders with a
    baseline, and an ensemble (whose members all train without the loss) with method="ensemble"."""
    from splatu import query

    load = query.load_any_run

    def trained_without_the_loss(*args, **kwargs):
        run = load(*args, **kwargs)
        plain = dataclasses.replace(run.config.uncertainty, off=True, extra_heads=())  # as splatfacto's config reads
        run.config = dataclasses.replace(run.config, uncertainty=plain)
        return run

    monkeypatch.setattr(query, "load_any_run", trained_without_the_loss)
    with pytest.raises(SplatuError, match="trained without the uncertainty loss"):
        query.open_run(tiny_run)
    camera = next(iter(query.open_run(tiny_run, method="angle").scene_cameras().values()))
    assert 0.0 < query.open_run(tiny_run, method="angle").render(*camera).mean_uncertainty < 1.0
    ensemble = tmp_path / "ensemble"
    for k in range(2):
        shutil.copytree(tiny_run, ensemble / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty"))
    (ensemble / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"]}))
    assert query.open_run(ensemble, method="ensemble").render(*camera).alpha.mean() > 0.5


def test_open_run_renders_the_checkpoint_it_named_though_a_newer_one_lands_before_loading(tiny_run, tmp_path,
                                                                                         monkeypatch):
    """The note names the checkpoint pinned while the run trains; a checkpoint saved between the pinning and the
    loading must not be the model used instead (the note would then name another model than the one rendered)."""
    from splatu import query
    from splatu.checkpoint import list_checkpoints
    from splatu.run_dir import training_lock

    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run, run_dir, ignore=shutil.ignore_patterns("uncertainty"))
    pinned = list_checkpoints(run_dir)[-1]
    later = torch.load(pinned, weights_only=True)
    later["model"]["means"] = later["model"]["means"] + 1.0  # the model trained on: another render
    pin = query.pinned_unless_finished

    def a_checkpoint_lands_meanwhile(load):
        found = pin(load)
        torch.save(later, pinned.with_name("step-9999999.pt"))  # as the training saves its next one
        return found

    monkeypatch.setattr(query, "pinned_unless_finished", a_checkpoint_lands_meanwhile)
    with training_lock(run_dir), pytest.warns(UserWarning, match=re.escape(f"{pinned.name}, is the model used")):
        run = query.open_run(run_dir)
    monkeypatch.setattr(query, "pinned_unless_finished", pin)
    assert torch.equal(run.models[0].means, query.open_run(pinned).models[0].means)


def _finished_ensemble(tiny_run, folder: Path) -> Path:
    """An ensemble run of two copies of `tiny_run`, as `splatu train --method ensemble --ensemble 2` leaves it."""
    for k in range(2):
        shutil.copytree(tiny_run, folder / "members" / str(k), ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    (folder / "ensemble.json").write_text(json.dumps({"members": ["members/0", "members/1"]}))
    return folder


def test_an_ensemble_in_training_renders_its_members_newest_checkpoints_with_a_note(tiny_run, tmp_path):
    """An ensemble being trained (a member's folder locked, as its `--resume` holds it) has no checkpoint of its own
    to pin: each member keeps its newest, and the note says so."""
    from splatu.query import open_run
    from splatu.run_dir import training_lock

    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    with training_lock(ensemble / "members" / "1"), pytest.warns(UserWarning, match="newest checkpoints so far"):
        run = open_run(ensemble, method="ensemble")
    assert len(run.models) == 2


@pytest.mark.parametrize("how", ["resumed", "left unfinished"])
def test_an_ensemble_not_whole_is_rendered_and_scored_under_its_members_steps_not_its_finished_name(
        tiny_run, tmp_path, capsys, how):
    """A finished ensemble (ensemble.json) whose member a `--resume` retrains, or whose member such a resume left
    unfinished (its summary.json set aside), was rendered and scored from that member's intermediate checkpoint into
    `uncertainty/ensemble-eval` and `ause_ensemble.json`, the finished ensemble's names, overwriting its own (with no
    note at all when the member folder itself was resumed). Now they are named after the members' steps."""
    from contextlib import nullcontext

    from splatu.checkpoint import checkpoint_path, list_checkpoints
    from splatu.run_dir import training_lock

    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    for command in (["render-uncertainty", "--max-views", "1"], ["eval-ause"]):  # the finished ensemble's outputs
        entrypoint([command[0], "--load", str(ensemble), "--method", "ensemble", *command[1:]])
    finished = {path: path.read_bytes() for path in (*ensemble.glob("ause_*"), *ensemble.rglob("uncertainty/**/*"))
                if path.is_file()}
    assert (ensemble / "ause_ensemble.json") in finished and len(finished) > 10
    member = ensemble / "members" / "1"
    newest = list_checkpoints(member)[-1]
    newest.rename(checkpoint_path(member, 7))  # as a resume from an earlier checkpoint left it
    (member / "summary.json").rename(tmp_path / "summary.json")
    capsys.readouterr()
    with training_lock(member) if how == "resumed" else nullcontext():
        for command in (["render-uncertainty", "--max-views", "1"], ["eval-ause"]):
            entrypoint([command[0], "--load", str(ensemble), "--method", "ensemble", *command[1:]])
            assert "their newest checkpoints so far are the models used" in capsys.readouterr().err
    label = f"ensemble-steps-{TINY_STEPS}-7"
    assert (ensemble / "uncertainty" / f"{label}-eval" / "render.json").is_file()
    assert (ensemble / f"ause_{label}.json").is_file()
    assert all(path.read_bytes() == data for path, data in finished.items()), "the finished outputs were overwritten"


def test_open_run_advises_data_not_the_command_lines_flag_for_a_scene_normalised_otherwise(tiny_run, tmp_path):
    """A baseline that reads the training views checks their frame against the run's; a Python caller is told to pass
    data=, as for a moved scene, not the command line's --data."""
    from splatu.checkpoint import list_checkpoints, read_checkpoint
    from splatu.query import open_run

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    path = list_checkpoints(run)[-1]
    state = read_checkpoint(path)
    state["world_transform"]["scale"] *= 1.5  # as if trained on a scene normalised differently
    torch.save(state, path)
    with pytest.raises(SplatuError, match="normalisation differs") as caught:
        open_run(run, method="angle")
    assert "data=" in caught.value.fix and "--data" not in caught.value.fix, caught.value.fix


def test_an_ensemble_training_its_members_is_named_as_such_not_as_a_run_without_checkpoints(tiny_run, tmp_path,
                                                                                             capsys):
    """A fresh ensemble writes ensemble.json only once its last member finishes: while it trains, its folder holds
    config.yml and members/ but no checkpoints/, and pinning its newest checkpoint told to 'train it first'."""
    from splatu.run_dir import training_lock

    ensemble = tmp_path / "ensemble"
    shutil.copytree(tiny_run, ensemble / "members" / "0", ignore=shutil.ignore_patterns("uncertainty"))
    shutil.copy(tiny_run / "config.yml", ensemble / "config.yml")
    with training_lock(ensemble):
        for command in ("render-uncertainty", "eval-ause"):
            capsys.readouterr()
            with pytest.raises(SystemExit) as exc:
                entrypoint([command, "--load", str(ensemble), "--method", "ensemble"])
            assert exc.value.code == 2
            err = capsys.readouterr().err
            assert "this ensemble is still training" in err and "members/<k>" in err, err
            assert "Traceback" not in err


def test_a_view_of_nothing_ranks_first_for_an_ensemble_only_when_density_aware_as_the_docs_say(tiny_run, tmp_path,
                                                                                               capsys):
    """The docs said empty space reads U = 1 for every method, so a view of nothing ranks first; an ensemble's std
    reads 0 there (such a view ranked last), and only density_aware counts it: the docs now say so where they rank."""
    from splatu.query import ViewUncertainty, open_run

    ensemble = _finished_ensemble(tiny_run, tmp_path / "ensemble")
    w2c, K, width, height = next(iter(open_run(tiny_run).scene_cameras().values()))
    nothing = w2c.copy()
    nothing[2, 3] -= 1e4  # the whole scene far behind the camera
    plain = open_run(ensemble).render(nothing, K, width, height)
    aware = open_run(ensemble, density_aware=True).render(nothing, K, width, height)
    assert plain.coverage == 0.0 and plain.mean_uncertainty == 0.0 and aware.mean_uncertainty == pytest.approx(1.0)
    with pytest.raises(SystemExit):
        entrypoint(["render-uncertainty", "--help"])
    cameras_help = " ".join(capsys.readouterr().out.replace("│", " ").split())  # the help box wraps each option
    assert "so such a view ranks last unless --density-aware" in cameras_help
    assert "density_aware=True" in ViewUncertainty.mean_uncertainty.__doc__


def test_the_query_offers_every_uncertainty_method_but_random():
    """QueryMethod spells the methods out for type checkers: a method added to render-uncertainty must reach open_run
    too."""
    from splatu.baselines import UNCERTAINTY_METHODS
    from splatu.query import QUERY_METHODS

    offered = QUERY_METHODS
    assert offered == tuple(m for m in UNCERTAINTY_METHODS if m != "random")


@pytest.mark.parametrize("where", ["run", "ensemble member"])
def test_an_unfinished_run_renders_its_newest_checkpoint_under_that_checkpoints_name(tiny_run, tmp_path, capsys,
                                                                                     where):
    """A run stopped before its end (no summary.json) and not training now rendered and scored its newest checkpoint
    into `uncertainty/ours-eval` and `ause_ours.json`, the finished run's names, without a word; a `--resume` to the
    end then left them there as if of the finished model. Now it is pinned to that checkpoint as a run in training
    is, with a note that says it is unfinished."""
    from splatu.checkpoint import list_checkpoints
    from splatu.query import open_run

    folder = tmp_path / "run" if where == "run" else _finished_ensemble(tiny_run, tmp_path / "ensemble") / "members/1"
    if where == "run":
        shutil.copytree(tiny_run, folder, ignore=shutil.ignore_patterns("uncertainty", "ause_*"))
    (folder / "summary.json").rename(tmp_path / "summary.json")  # as a Ctrl-C or a kill leaves it
    newest = list_checkpoints(folder)[-1]
    capsys.readouterr()
    _render(folder, "--max-views", "1")
    err = capsys.readouterr().err
    assert "is unfinished" in err and f"{newest.name}, is the model used; what is written is named after it" in err
    assert "still training" not in err
    entrypoint(["eval-ause", "--load", str(folder)])
    assert f"{newest.name}, is the model used; the report is named after it" in capsys.readouterr().err
    with pytest.warns(UserWarning, match=r"is unfinished \(.*--resume.*\); its newest checkpoint, "
                      + re.escape(f"{newest.name}, is the model used")):
        open_run(folder)
    label = f"ours-{newest.stem}"
    assert (folder / "uncertainty" / f"{label}-eval" / "render.json").is_file()
    assert (folder / f"ause_{label}.json").is_file()
    assert not (folder / "uncertainty" / "ours-eval").exists() and not (folder / "ause_ours.json").exists()
