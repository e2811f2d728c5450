"""Where a measurement was taken: a benchmark's JSON names the commit its figures came from."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import pytest

import splatu.provenance
from splatu.provenance import source_revision

REPO = Path(__file__).resolve().parents[2]


def _git(*args: str, cwd: Path) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(), reason="needs git and a checkout")
def test_the_revision_is_this_checkouts_commit_and_unknown_inside_another_project(tmp_path):
    """splatu installed in a venv inside some other project's checkout recorded that project's HEAD."""
    assert source_revision().split()[0] == _git("rev-parse", "--short", "HEAD", cwd=REPO)
    other = tmp_path / "project"
    installed = other / ".venv" / "lib" / "splatu"
    installed.mkdir(parents=True)
    shutil.copy(splatu.provenance.__file__, installed / "provenance.py")
    _git("init", "-q", cwd=other)
    _git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "x", cwd=other)
    spec = importlib.util.spec_from_file_location("installed_provenance", installed / "provenance.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.source_revision() == "unknown"
