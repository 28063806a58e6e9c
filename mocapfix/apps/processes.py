"""Worker processes for a run (`mocapfix fix --jobs N`): how they start, and that they end with
the run that started them.

Each worker is forked from a server process that imported the run's modules once (worker_context),
not spawned fresh: a spawned worker imports torch and mocapfix again, 1.7 CPU seconds each (what
fixing a minute and a half of motion costs), 16 times over on 16 cores. They are never forked
from the run itself, whose threads (torch's, BLAS's) a fork would copy in a state they cannot be
used in.

After a `kill -9` of a run's main process its workers would live on: they hold the caller's
pipes open (a shell or a CI step waiting for the output waits for them) and go on writing outputs
nobody asked for any more. die_with_run, called first in each worker, ends the worker when the
run ends, however it ends. Light on purpose (no torch): a worker calls it before anything else.
"""

from __future__ import annotations

import multiprocessing
import os
import select
import signal
import sys
import threading
import time
from pathlib import Path

PARENT_POLL_S = 0.5  # how often a worker the kernel cannot wake looks whether its run is there
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def worker_context(preload: list[str]) -> multiprocessing.context.BaseContext:
    """Where a run's workers start: forked from a fork server that imported the modules `preload`
    names once; spawned fresh where there is no fork server (Windows). The server is a process of
    its own started by exec with the first worker, single-threaded: it never runs torch, so forking
    it is safe, as forking the run is not. It stays, idle, for the life of the process that
    started it (`mocapfix fix`: the run; a program calling fix_files: about 270 MB with torch
    imported, serving its later runs)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(preload)  # no effect once the server runs: it has them already
    return context


def die_with_run(run: int) -> None:
    """End this worker when the run `run` (its main process) ends, however it ends.
    A worker the run spawned: the kernel sends it SIGKILL when its parent ends (Linux's prctl
    PR_SET_PDEATHSIG; the worker's temporary files are then removed by the next run that claims
    those outputs, io/files.py); elsewhere a thread looks every PARENT_POLL_S whether its parent
    changed. A worker forked by the run's fork server (worker_context): the server outlives the
    run while its workers do (they hold its pipe open), so a thread waits for the run itself to
    end (Linux's pidfd; elsewhere it looks every PARENT_POLL_S). A run already gone, or a parent
    that is neither the run nor a process of the run's, ends it now."""
    parent = os.getppid()
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent or (parent != run and _parent_of(parent) not in (run, None)):
        os._exit(1)
    if parent != run:
        _end_with(run)
    elif not armed:
        _end_with(parent, lambda: os.getppid() == parent)


def _end_with(run: int, alive=None) -> None:
    """A thread that ends this process when process `run` ends: woken by the kernel where Linux
    gives a pidfd for it, else looking every PARENT_POLL_S whether alive() (default: whether a
    process `run` exists)."""
    if alive is None and hasattr(os, "pidfd_open"):
        try:
            ended = os.pidfd_open(run)  # readable once the process has ended
        except ProcessLookupError:
            os._exit(1)
        except OSError:  # a kernel without pidfds (before Linux 5.3)
            pass
        else:

            def wait() -> None:
                select.select([ended], [], [])
                os._exit(1)

            threading.Thread(target=wait, name="mocapfix-run-watch", daemon=True).start()
            return

    def exists() -> bool:
        try:
            os.kill(run, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # there, but not ours to signal
            pass
        return True

    alive = alive or exists

    def watch() -> None:
        while alive():
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="mocapfix-parent-watch", daemon=True).start()


def _parent_of(pid: int) -> int | None:
    """The parent of process `pid` (Linux's /proc), or None where that cannot be read."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None
