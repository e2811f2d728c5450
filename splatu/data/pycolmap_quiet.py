"""pycolmap, imported without the SIGTERM handler its glog installs.

glog's failure handler answers `kill` with a native stack trace and then re-raises; it calls malloc inside the
handler, and a training killed mid-allocation hung there instead of exiting (seen here). Importing pycolmap
through this module puts back whatever SIGTERM did before (default, ignored, or splatu's own handler), so a
kill ends the process (or, during training, saves first) from every entry point, benchmarks included.
"""

from __future__ import annotations

import signal
import threading

_on_main_thread = threading.current_thread() is threading.main_thread()
_before = signal.getsignal(signal.SIGTERM) if _on_main_thread else None

import pycolmap  # noqa: E402  (the handler to undo is installed by this import)

if _before is not None:  # None: set outside Python, nothing to put back; off the main thread: not allowed
    signal.signal(signal.SIGTERM, _before)

__all__ = ["pycolmap"]
