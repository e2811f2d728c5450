"""Time the Python pre-check of a COLMAP text model (splatu.data.colmap) against pycolmap's own read of it.

    python benchmarks/colmap_precheck.py [--points 1000000] [--images 300] [--runs 3] [--json PATH]

Writes a synthetic valid text model into a temporary folder, shaped like a real one (lund_door's, as COLMAP
writes it): `--points` 3D points with tracks of 2–10 observations in consecutive images (17 significant digits
for positions), `--images` images whose 2D points lines hold those observations plus a quarter as many untracked
features (POINT3D_ID -1, 6 significant digits), two cameras. Times every check `read_reconstruction` runs on
such a model before and after pycolmap reads it (the median of `--runs`), and `pycolmap.Reconstruction(path)`
on the same files for scale, and iterating the files' lines alone with their endings kept (as the pre-check
reads them, to refuse a lone CR) and with Python's universal newlines. Writes
benchmarks/results/colmap_precheck.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from splatu.data import colmap
from splatu.data.pycolmap_quiet import pycolmap
from splatu.provenance import measured_on, source_revision

REPO = Path(__file__).resolve().parents[1]
TRACK_LENGTHS = (2, 10)
"""The shortest and longest track, inclusive; lengths are uniform between them."""
UNTRACKED_SHARE = 0.25
"""Untracked 2D points (POINT3D_ID -1) per image, as a share of its tracked ones."""


def tracks(points: int, images: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Each point's track length, and the image (0-based) of each observation, point after point: a track runs
    through consecutive images from a random one, as a video's or a walk-around's would."""
    lengths = rng.integers(TRACK_LENGTHS[0], TRACK_LENGTHS[1] + 1, size=points)
    starts = np.repeat(rng.integers(0, images, size=points), lengths)
    offsets = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return lengths, (starts + offsets) % images


def images_text(observed: np.ndarray, lengths: np.ndarray, images: int, rng: np.random.Generator) -> tuple[str,
                                                                                                           np.ndarray]:
    """images.txt for the observations (image of each, point after point), and each one's 2D point index."""
    point_ids = np.repeat(np.arange(1, len(lengths) + 1), lengths)
    index = np.empty(len(observed), dtype=np.int64)
    order = np.argsort(observed, kind="stable")
    counts = np.bincount(observed, minlength=images)
    lines = ["# Image list with two lines of data per image:\n", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, "
             "CAMERA_ID, NAME\n", "#   POINTS2D[] as (X, Y, POINT3D_ID)\n", f"# Number of images: {images}\n"]
    first = 0
    for image in range(images):
        mine = order[first:first + counts[image]]
        first += counts[image]
        total = len(mine) + int(len(mine) * UNTRACKED_SHARE)
        slots = np.sort(rng.choice(total, size=len(mine), replace=False))
        index[mine] = slots
        ids = np.full(total, -1, dtype=np.int64)
        ids[slots] = point_ids[mine]
        xy = rng.uniform(0, 1000, size=(total, 2))
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        pose = " ".join(f"{v:.6g}" for v in (*quat, *rng.uniform(-5, 5, size=3)))
        lines.append(f"{image + 1} {pose} {image % 2 + 1} image_{image + 1:05d}.jpg\n")
        lines.append(" ".join(f"{x:.6g} {y:.6g} {i}" for (x, y), i in zip(xy.tolist(), ids.tolist(), strict=True))
                     + "\n")
    return "".join(lines), index


def points_text(lengths: np.ndarray, observed: np.ndarray, index: np.ndarray, rng: np.random.Generator) -> str:
    """points3D.txt: ids from 1, positions, colours, errors and the tracks (1-based image ids)."""
    xyz = rng.normal(scale=10.0, size=(len(lengths), 3)).tolist()
    rgb = rng.integers(0, 256, size=(len(lengths), 3)).tolist()
    error = rng.uniform(0, 2, size=len(lengths)).tolist()
    pairs = [f"{image} {i}" for image, i in zip((observed + 1).tolist(), index.tolist(), strict=True)]
    ends = np.cumsum(lengths).tolist()
    lines = ["# 3D point list with one line of data per point:\n",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"]
    for point, ((x, y, z), (r, g, b), e, end, length) in enumerate(
            zip(xyz, rgb, error, ends, lengths.tolist(), strict=True), start=1):
        lines.append(f"{point} {x:.17g} {y:.17g} {z:.17g} {r} {g} {b} {e:.17g} {' '.join(pairs[end - length:end])}\n")
    return "".join(lines)


def write_model(folder: Path, points: int, images: int, seed: int = 0) -> dict[str, Path]:
    """A valid COLMAP text model in `folder`; its cameras, images and points3D files."""
    rng = np.random.default_rng(seed)
    lengths, observed = tracks(points, images, rng)
    images_txt, index = images_text(observed, lengths, images, rng)
    (folder / "cameras.txt").write_text("# Camera list with one line of data per camera:\n"
                                        "1 SIMPLE_RADIAL 1296 1936 2435.38 648 968 -0.0336422\n"
                                        "2 PINHOLE 1000 750 900.5 901.25 500 375\n")
    (folder / "images.txt").write_text(images_txt)
    (folder / "points3D.txt").write_text(points_text(lengths, observed, index, rng))
    return colmap.model_files(folder)


def precheck(files: dict[str, Path]) -> None:
    """Every check read_reconstruction makes of a text model besides pycolmap's read; the model must pass."""
    assert colmap.text_model_errors(files) == (None, None)


def iterate_lines(files: dict[str, Path], newline: str | None) -> None:
    """Read every line of the model's files as the pre-check opens them: `newline=""` keeps each line's ending (the
    pre-check's, to refuse a lone CR), None is Python's universal newlines; the cost of that choice alone."""
    for path in files.values():
        with path.open(encoding="utf-8", errors="replace", newline=newline) as lines:
            for _ in lines:
                pass


def median_ms(run: Callable[[], object], runs: int) -> tuple[float, list[float]]:
    """The median and each of `runs` wall times of `run`, in milliseconds."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        run()
        times.append(1e3 * (time.perf_counter() - start))
    return statistics.median(times), times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=1_000_000, help="3D points in the model")
    parser.add_argument("--images", type=int, default=300, help="images in the model")
    parser.add_argument("--runs", type=int, default=3, help="timed runs of each; the median is reported")
    parser.add_argument("--json", type=Path, default=REPO / "benchmarks" / "results" / "colmap_precheck.json",
                        help="where to write the results")
    args = parser.parse_args()
    if args.points < 1 or args.images < TRACK_LENGTHS[1] or args.runs < 1:
        parser.error(f"--points and --runs must be at least 1, --images at least {TRACK_LENGTHS[1]}")

    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        files = write_model(Path(folder), args.points, args.images)
        written = time.perf_counter() - start
        megabytes = {name: round(path.stat().st_size / 1e6, 1) for name, path in files.items()}
        ms_precheck, precheck_runs = median_ms(lambda: precheck(files), args.runs)
        ms_pycolmap, pycolmap_runs = median_ms(lambda: pycolmap.Reconstruction(folder), args.runs)
        ms_kept, _ = median_ms(lambda: iterate_lines(files, ""), args.runs)
        ms_universal, _ = median_ms(lambda: iterate_lines(files, None), args.runs)
    total_mb = sum(megabytes.values())
    result = {
        "points": args.points, "images": args.images, "megabytes": megabytes,
        "ms_precheck": round(ms_precheck), "ms_precheck_runs": [round(t) for t in precheck_runs],
        "ms_precheck_per_mb": round(ms_precheck / total_mb, 2),
        "ms_pycolmap_read": round(ms_pycolmap), "ms_pycolmap_read_runs": [round(t) for t in pycolmap_runs],
        "ms_iterate_lines_endings_kept": round(ms_kept), "ms_iterate_lines_universal_newlines": round(ms_universal),
        "seconds_to_write_model": round(written, 1), "revision": source_revision(), "measured_on": measured_on(),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"{'points':>10}{'images':>8}{'MB':>8}{'pre-check ms':>14}{'ms per MB':>11}{'pycolmap ms':>13}")
    print(f"{args.points:>10}{args.images:>8}{total_mb:>8.1f}{ms_precheck:>14.0f}{ms_precheck / total_mb:>11.2f}"
          f"{ms_pycolmap:>13.0f}")
    print(f"iterating the lines alone: {ms_kept:.0f} ms keeping their endings (as the pre-check reads them), "
          f"{ms_universal:.0f} ms with universal newlines")
    print(f"revision {result['revision']}; written to {args.json}")


if __name__ == "__main__":
    main()
