"""Reading the JSON files splatu and nerfstudio write, with a one-line error when one is unreadable."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from splatu.errors import SplatuError


def read_json(path: Path, fix: str = "fix or regenerate the file") -> dict[str, Any]:
    """A JSON object from a file, or a one-line error naming it: a truncated or hand-edited file is a user's
    problem to fix, never a traceback. `fix`: what to do, where a user may have passed another kind of file."""
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SplatuError(f"cannot parse JSON ({err})", f"in {path}", fix) from None
    if not isinstance(content, dict):
        raise SplatuError("expected a JSON object at the top level", f"in {path}", fix)
    return content


def is_finite_number(value: Any) -> bool:
    """A JSON number that is one: not a bool (an int to Python), not NaN or ±Infinity (which json reads)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
