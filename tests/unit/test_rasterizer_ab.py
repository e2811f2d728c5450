"""benchmarks/rasterizer_ab.py imports an earlier commit's package beside the working tree's, renamed; the
renaming must reach every import statement and nothing else, or the "base" would silently run current code."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.benchmark_scripts import benchmark_script

PACKAGE = Path(__file__).resolve().parents[2] / "splatu"


@pytest.fixture(scope="module")
def ab():
    yield from benchmark_script("rasterizer_ab")


def test_rename_package_rewrites_imports_only(ab) -> None:
    source = ("from splatu.rasterizer import rasterize\nimport splatu.sh\n    from splatu import losses\n"
              "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")
    assert ab.rename_package(source) == (
        "from splatu_base.rasterizer import rasterize\nimport splatu_base.sh\n    from splatu_base import losses\n"
        "from splatux import other\nname = 'splatu.rasterizer'  # splatu\n")


def test_no_import_of_the_current_package_survives_renaming(ab) -> None:
    leftover = re.compile(r"^\s*(from|import)\s+splatu\b", re.MULTILINE)
    for module in PACKAGE.rglob("*.py"):
        renamed = ab.rename_package(module.read_text())
        assert not leftover.search(renamed), module
        assert "import_module(\"splatu" not in renamed and "import_module('splatu" not in renamed, module
