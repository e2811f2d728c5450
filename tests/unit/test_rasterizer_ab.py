"""benchmarks/rasterizer_ab.py imports an earlier commit's package beside the working tree's, renamed; the
renaming must reach every import statement and nothing else, or the "base" would silently run current code."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.benchmark_scripts import benchmark_script

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ab():
    yield from benchmark_script("rasterizer_ab")


def test_rename_package_rewrites_imports_only(ab) -> None:
    source = ("from splatu.rasterizer import rasterize\nimport splatu.sh\n    from splatu import losses\n"
              "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")
    assert ab.rename_package(source) == (
        "from splatu_base.rasterizer import rasterize\nimport splatu_base.sh\n    from splatu_base import losses\n"
        "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(), reason="needs git and a clone")
def test_the_exported_base_runs_only_its_own_modules(ab, tmp_path: Path) -> None:
    """Import the exported HEAD's rasterizer in a fresh interpreter: every splatu* module it loads must come
    from the export, none from the working tree."""
    ab.export_base(ab.resolve_commit("HEAD"), tmp_path)
    probe = (
        "import sys; sys.path.insert(0, sys.argv[1]); import splatu_base.rasterizer\n"
        "for name, module in sorted(sys.modules.items()):\n"
        "    if name.split('.')[0].startswith('splatu'): print(name, module.__file__)\n"
    )
    loaded = subprocess.run([sys.executable, "-c", probe, str(tmp_path)], capture_output=True, text=True,
                            check=True, cwd=tmp_path).stdout.splitlines()
    assert any(line.startswith("splatu_base.rasterizer.composite ") for line in loaded)
    for line in loaded:
        name, file = line.split(" ", 1)
        assert name.startswith("splatu_base") and Path(file).is_relative_to(tmp_path), line


def test_a_revision_that_names_no_commit_is_one_clear_line(ab) -> None:
    with pytest.raises(SystemExit, match="is not a commit of the repository"):
        ab.resolve_commit("--no-such-revision")
