"""The project installs as a wheel, not only as an editable clone: its presets travel with it."""

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_folder_is_listed_for_the_wheel():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "splatu").rglob("__init__.py")}
    assert found | {"splatu.configs"} == listed


@pytest.mark.skipif(not (ROOT / "pyproject.toml").is_file(), reason="needs the source tree")
def test_a_wheel_install_finds_the_presets(tmp_path):
    """`pip install .` (not -e) used to leave the presets behind: `splatu train` then knew no preset at all."""
    source = tmp_path / "source"  # a copy: building in place would leave build/ behind, and stale files in it
    skipped = {".git", ".venv", "outputs", "build", "splatu.egg-info", ".cache", "data"}  # at the top level only

    def ignore(folder: str, names: list[str]) -> list[str]:
        return [n for n in names if n == "__pycache__" or (Path(folder) == ROOT and n in skipped)]

    shutil.copytree(ROOT, source, ignore=ignore)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", str(source), "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "wheel")],
                   check=True, capture_output=True, timeout=300)
    [wheel] = (tmp_path / "wheel").glob("*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(tmp_path / "site"), str(wheel)],
                   check=True, capture_output=True, timeout=300)
    probe = ("import splatu, splatu.train_config as c; "
             "print(splatu.__file__); print(c.preset_path('fast')); print(c.preset_path('quality'))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, env={"PYTHONPATH": str(tmp_path / "site")},
                         capture_output=True, text=True, timeout=120, check=True).stdout.split()
    site = str(tmp_path / "site")
    assert all(line.startswith(site) for line in out), out  # the installed copy, not this clone
    assert out[1].endswith("splatu/configs/fast.yaml") and out[2].endswith("splatu/configs/quality.yaml")
