"""Worker processes that end when the process that started them ends, however it ends.

A pool worker waits on a pipe for work; if its parent is killed (SIGKILL, out of memory) no
one closes that pipe in an orderly way and the worker, and the ``multiprocessing`` resource
tracker that shares its file descriptors, would stay alive until killed by hand.
:func:`die_with_parent`, run first thing in every worker, prevents that twice over:

- on Linux the kernel sends the worker SIGKILL when its parent dies
  (``prctl(PR_SET_PDEATHSIG)``, through ``ctypes``); the signal is tied to the parent
  *thread* that started the worker, which for the process pool is the thread that submits
  the frames and lives until the pool is shut down;
- everywhere, a daemon thread checks once a second whether the worker's parent is still the
  process that started it (an orphan is re-parented, so ``os.getppid()`` changes) and ends
  the worker if not.

The resource tracker exits by itself once every process holding its pipe has ended.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time

__all__ = ["POLL_INTERVAL_S", "die_with_parent"]

#: seconds between two checks of the parent by the watching thread
POLL_INTERVAL_S = 1.0
#: from <linux/prctl.h>
_PR_SET_PDEATHSIG = 1
#: exit status of a worker that ends because its parent is gone
_ORPHAN_EXIT = 70


def _kernel_signal_on_parent_death(sig: int) -> bool:
    """Ask Linux to send ``sig`` to this process when its parent dies; False if unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    return False


def _watch(parent_pid: int, interval_s: float) -> None:
    while True:
        time.sleep(interval_s)
        if os.getppid() != parent_pid:
            os._exit(_ORPHAN_EXIT)


def die_with_parent(parent_pid: int, interval_s: float = POLL_INTERVAL_S) -> None:
    """Make this process end when process ``parent_pid`` (its parent) ends.

    Parameters
    ----------
    parent_pid : int
        The pid of the parent as the parent saw it when it started this process (compared
        with ``os.getppid()``: a parent that died before this call is noticed at once).
    interval_s : float
        Seconds between checks of the watching thread.
    """
    _kernel_signal_on_parent_death(signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the kernel was told
        os._exit(_ORPHAN_EXIT)
    threading.Thread(
        target=_watch, args=(parent_pid, interval_s), name="holofit-parent-watch", daemon=True
    ).start()
