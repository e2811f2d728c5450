"""Eval splits: which frames are held out.

`contiguous` holds out a block of consecutive frames, which creates an unseen angle as in
the paper's 50 consecutive poster frames; `every-n` is nerfstudio's rule; an explicit list
names the eval frames.
"""

from __future__ import annotations

import random
from collections.abc import Sequence

from splatu.errors import SplatuError, require_at_least


def contiguous_split(n_frames: int, block: int, seed: int, option: str = "--eval-block",
                     where: str = "in the split options") -> tuple[list[int], list[int]]:
    """Hold out `block` consecutive frames starting at a seeded random position; `option` is the flag that set
    `block`, named in the error when it does not fit."""
    if not 0 < block < n_frames:
        raise SplatuError(f"{option} {block} is out of range: a scene of {n_frames} frames can hold out 1 to "
                          f"{n_frames - 1} of them", where, f"pass {option} between 1 and {n_frames - 1}")
    start = random.Random(seed).randrange(0, n_frames - block + 1)
    eval_idx = list(range(start, start + block))
    train_idx = [i for i in range(n_frames) if not start <= i < start + block]
    return train_idx, eval_idx


def every_n_split(n_frames: int, n: int) -> tuple[list[int], list[int]]:
    """nerfstudio's rule: every n-th frame (0, n, 2n, ...) is held out."""
    require_at_least(n, 2, "--eval-every")
    eval_idx = list(range(0, n_frames, n))
    train_idx = [i for i in range(n_frames) if i % n != 0]
    return train_idx, eval_idx


def list_split(names: Sequence[str], eval_names: Sequence[str], source: str) -> tuple[list[int], list[int]]:
    """Hold out exactly the frames named in `eval_names` (from a list file)."""
    wanted = set(eval_names)
    unknown = wanted - set(names)
    if unknown:
        raise SplatuError(f"eval list names {len(unknown)} unknown frames (e.g. {sorted(unknown)[0]!r})",
                          f"in {source}", "list file names exactly as in the scene")
    eval_idx = [i for i, n in enumerate(names) if n in wanted]
    train_idx = [i for i, n in enumerate(names) if n not in wanted]
    if not eval_idx or not train_idx:
        raise SplatuError("the eval list leaves an empty split", f"in {source}",
                          "name at least one frame and leave at least one for training")
    return train_idx, eval_idx
