"""Worker processes that end with the run that started them (`mocapfix fix --jobs N`).

After a `kill -9` of a run's main process its workers would live on: they hold the caller's
pipes open (a shell or a CI step waiting for the output waits for them) and go on writing outputs
nobody asked for any more. die_with_parent, called first in each worker, ends the worker when its
parent ends, however it ends. Light on purpose (no torch): a worker calls it before anything else.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

PARENT_POLL_S = 0.5  # how often a worker without PR_SET_PDEATHSIG looks for its parent
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int) -> None:
    """End this process when the process `parent` (the run's main process, its parent) ends.
    Linux: the kernel sends it SIGKILL (prctl PR_SET_PDEATHSIG; the worker's temporary files are
    then removed by the next run that claims those outputs, io/files.py); elsewhere a thread looks
    every PARENT_POLL_S whether the parent changed. A parent already gone before the signal was
    asked for ends it now."""
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:
        os._exit(1)
    if armed:
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="mocapfix-parent-watch", daemon=True).start()
