"""A principal point that does not fit its image: refused for a candidate camera, reported for a training scene.

A K and a size that do not belong together render a shifted, zoomed view without a word. A candidate camera (a
`--cameras` file, `RunQuery.render`) has no image to show which of the two is wrong, so it is refused. A training
scene's images are checked against its w and h as they load, and tiles or crops cut from a larger photo
legitimately put the principal point far off-centre or off the tile, so there it is one warning line and training
goes on.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Literal

from rich.console import Console

PRINCIPAL_POINT_FAR = 0.2
"""How far from the image's centre, as a fraction of that side, a principal point may lie before another reading of
the camera is looked for. Real captures put it within a few per cent of the centre (fox 1.4%, lund_door 0%); an
off-centre crop can move it further, so a point this far off is only flagged when a simple mistake explains it."""
PRINCIPAL_POINT_NEAR = 0.05
"""How close to the centre, as a fraction of each side, the mistake's correction must bring the principal point."""

CANDIDATE_SWAP_OFF = 0.05
"""How far from the centre, as a fraction of a side, a candidate camera's principal point may lie before a swapped
width and height is looked for: beyond any real capture's (fox 1.4%)."""
CANDIDATE_SWAP_NEAR = 0.02
"""How close to the centre of the swapped size, as a fraction of each side, such a point must lie to be read as a
swap: a real capture's K, within 1.4% of its own centre, swapped lands within this of the swapped one."""

PrincipalPointFault = Literal["outside", "swapped", "resized"]
Misplaced = tuple[str, PrincipalPointFault, str]
"""A camera whose principal point looks misplaced: its name (frame 'a.png', camera 3), the fault's kind and text."""


def _made_for(fraction: tuple[float, float]) -> float | None:
    """The size, relative to this image, of the image where one scale of K puts the principal point at the centre
    (within PRINCIPAL_POINT_NEAR), or None: no scale moves a point on the top or left edge, so it has none."""
    made_for = sum(fraction)
    if min(fraction) <= 0 or max(abs(f / made_for - 0.5) for f in fraction) > PRINCIPAL_POINT_NEAR:
        return None
    return made_for


def misplaced_principal_point(cx: float, cy: float, width: int, height: int,
                              candidate: bool = False) -> tuple[PrincipalPointFault, str] | None:
    """What is wrong with principal point (cx, cy) for a width x height image if it is not a tile or crop of a larger
    photo, as (kind, what), or None:
    - outside: on the image's edge or off it, where no whole photo has it (a K made for a larger image, or a tile:
      every tile of a 2x2 grid has it on a corner, and is flagged alike);
    - swapped: far from the centre, but near it with width and height swapped (a portrait K on a landscape size);
    - resized: inside but far from the centre, at the same fraction of both sides, so that one scale of K would
      centre it (a K made for a smaller or larger image, such as a --downscale's).
    A near-square (4:3) image swapped moves it less than a training scene's tiles and crops may lie off-centre
    (a loader compares each image's real size with w and h instead), so there only a point 20% off is read as
    swapped. A `candidate` camera has no image to check and no reason to be off-centre unless its caller says so,
    so any point clearly off-centre (CANDIDATE_SWAP_OFF) and at the swapped size's centre (CANDIDATE_SWAP_NEAR) is
    a swap; a square image has one centre either way round."""
    point = f"principal point ({cx:.6g}, {cy:.6g})"
    fraction = (cx / width, cy / height)
    made_for = _made_for(fraction)
    as_for = "" if made_for is None else f", as for a K made for an image {made_for:.2g} times this size"
    if not (0.0 < cx < width and 0.0 < cy < height):
        place = "outside" if not (0.0 <= cx <= width and 0.0 <= cy <= height) else "on the edge of"
        return "outside", f"{point} lies {place} the {width}x{height} image{as_for}"
    off, side = max((abs(fraction[0] - 0.5), "width"), (abs(fraction[1] - 0.5), "height"))
    off_swapped = max(abs(cx / height - 0.5), abs(cy / width - 0.5))
    if ((off > PRINCIPAL_POINT_FAR and off_swapped <= PRINCIPAL_POINT_NEAR)
            or (candidate and off > CANDIDATE_SWAP_OFF and off_swapped <= CANDIDATE_SWAP_NEAR)):
        return "swapped", (f"{point} is {off:.0%} of the {side} off the centre of the {width}x{height} image, "
                           f"but at the centre of a {height}x{width} one")
    if off <= PRINCIPAL_POINT_FAR:
        return None
    if made_for is not None:
        return "resized", f"{point} is at {fraction[0]:.0%} x {fraction[1]:.0%} of the {width}x{height} image{as_for}"
    return None


def warn_misplaced(misplaced: list[Misplaced], total: int, noun: str, source: Path,
                   fix: Callable[[PrincipalPointFault], str]) -> None:
    """One warning line on stderr for a training scene's cameras in `misplaced` (of `total` `noun`s in `source`),
    naming the first and the fix of its mistake, or nothing: its images are there to train on, and a tile or crop
    of a larger photo is a legitimate camera the file alone cannot tell from a wrong one."""
    if not misplaced:
        return
    name, kind, what = misplaced[0]
    verb = "has" if len(misplaced) == 1 else "have"
    Console(stderr=True).print(
        f"warning: {len(misplaced)} of {total} {noun} in {source} {verb} a principal point far from the image's "
        f"centre ({name}: {what}); the cameras are used as given, which is right for tiles or crops cut "
        f"from a larger photo, but if the camera is wrong, {fix(kind)}", soft_wrap=True, markup=False, highlight=False)
