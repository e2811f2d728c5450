import os

import pytest
import torch

from splatu.atomic import atomic_write, atomic_write_text, leftover_temporaries, temporary_sibling
from splatu.checkpoint import list_checkpoints, read_checkpoint, save_checkpoint
from splatu.errors import SplatuError


def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "summary.json"
    atomic_write_text(path, "old")

    def half_then_crash(f):
        f.write(b"ne")
        raise OSError("disk full")

    with pytest.raises(SplatuError, match=r"could not write summary\.json \(disk full\)"):
        atomic_write(path, half_then_crash)
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_a_crash_before_the_rename_leaves_the_previous_checkpoint_readable(tmp_path, monkeypatch):
    save_checkpoint(tmp_path, 1, {"weights": torch.ones(3)})

    def killed(src, dst):
        raise KeyboardInterrupt  # the process dies between writing the temporary and renaming it

    monkeypatch.setattr("splatu.atomic.os.replace", killed)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(tmp_path, 2, {"weights": torch.zeros(3)})
    [only] = list_checkpoints(tmp_path)
    assert torch.equal(read_checkpoint(only)["weights"], torch.ones(3))
    assert [p.name for p in (tmp_path / "checkpoints").iterdir()] == [only.name]


def test_it_creates_the_folder_and_replaces_whole_files(tmp_path):
    path = tmp_path / "a" / "b.txt"
    atomic_write_text(path, "first, longer")
    atomic_write_text(path, "second")
    assert path.read_text() == "second"


def test_a_folder_that_is_a_file_is_one_line(tmp_path):
    (tmp_path / "run").write_text("not a folder")
    with pytest.raises(SplatuError, match=r"could not write summary\.json"):
        atomic_write_text(tmp_path / "run" / "summary.json", "{}")


def test_a_killed_writers_temporary_is_found_and_nothing_else_is(tmp_path):
    """What a writer killed outright leaves is found by name, and only that: the render's `.render-swapping` marker,
    which a leftover search for `.render*` would also delete, says a folder is a render's."""
    leftover = temporary_sibling(tmp_path / "step-1.pt")
    assert leftover.name.startswith(".") and leftover.parent == tmp_path  # hidden, beside the file it becomes
    for path in (leftover, tmp_path / "step-1.pt", tmp_path / ".step-1.pt.bak", tmp_path / ".step-1.pt-swapping"):
        path.write_text("x")
    assert leftover_temporaries(tmp_path, "step-*.pt") == [leftover]


def test_the_data_is_fsynced_before_the_rename_and_the_rename_before_returning(tmp_path, monkeypatch):
    """Without the first fsync a machine crash can persist the rename but not the data (an empty or torn checkpoint
    under the real name, the previous one gone); without the second, the rename may be lost after older checkpoints
    are pruned. Told apart by inode: the temporary file's, then the folder's."""
    events: list[tuple[str, int]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.fstat(fd).st_ino))
        real_fsync(fd)

    def replace(src, dst) -> None:
        events.append(("replace", os.stat(src).st_ino))
        real_replace(src, dst)

    monkeypatch.setattr("splatu.atomic.os.fsync", fsync)
    monkeypatch.setattr("splatu.atomic.os.replace", replace)
    path = tmp_path / "step-0000001.pt"
    atomic_write(path, lambda f: f.write(b"checkpoint"))
    written, folder = path.stat().st_ino, tmp_path.stat().st_ino
    assert events == [("fsync", written), ("replace", written), ("fsync", folder)]
