"""Worker processes that end with the process that started them, even when it is killed.

A ``ProcessPoolExecutor``'s workers outlive a parent killed by SIGKILL (nothing runs in it to stop
them): re-parented to PID 1, they would go on writing a stage's scratch frames after the stage is
gone, and a rerun would score frames of a run it never started. :func:`worker_pool`'s workers
(spawned: fork would copy torch's thread pools) set Linux's parent-death signal (SIGKILL) as they
start, and a daemon thread in each polls the parent's id as well (elsewhere than Linux, and for a
parent that died before the signal was set), so a worker ends within :data:`POLL_SECONDS` of its
parent at worst.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

POLL_SECONDS = 0.5  # how often a worker's watchdog thread checks that its parent is alive
PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


def _set_parent_death_signal() -> None:
    """Ask Linux to SIGKILL this process when its parent ends (a no-op elsewhere, or without libc)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # no prctl in this libc: the watchdog alone
        pass


def _watch_parent(parent: int) -> None:
    """End this process as soon as ``parent`` is no longer its parent (it died: re-parented)."""
    while os.getppid() == parent:
        time.sleep(POLL_SECONDS)
    os._exit(1)  # no cleanup to run: the parent's stage is gone, its scratch is the next run's


def _start_worker(parent: int, threads: int) -> None:
    """A worker's start: die with ``parent`` (the signal, then the watchdog thread, which also ends a
    worker whose parent died before the signal was set) and use ``threads`` torch threads."""
    _set_parent_death_signal()
    threading.Thread(target=_watch_parent, args=(parent,), name="parent-watchdog", daemon=True).start()
    if threads > 0:
        import torch

        torch.set_num_threads(threads)


def worker_pool(workers: int, threads: int = 0) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes, each with ``threads`` torch threads (0: torch is not
    imported at start), that end when this process ends, SIGKILL included. Create it from the thread
    that waits for it (the parent-death signal fires when the creating thread ends)."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(
        workers, mp_context=context, initializer=_start_worker, initargs=(os.getpid(), threads)
    )
