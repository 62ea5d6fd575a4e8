"""Worker processes: a worker exits when the process that started it dies (experiment runner, demo)."""
from __future__ import annotations

import os
import sys
import threading
import time

__all__ = ["watch_parent"]


def watch_parent(interval_s: float = 1.0, parent: int | None = None) -> threading.Thread | None:
    """In a worker process: exit at once (``os._exit``) when the parent process dies.

    A daemon thread polls ``os.getppid()``; once the parent is gone the worker is re-parented and the
    pid changes. Without this, workers of a killed runner keep training, write checkpoints and then
    block forever on their result pipe. Pass ``parent`` (the pid the parent sent along) so that a
    parent that died while the worker was still starting up is noticed too.
    """
    if sys.platform == "win32":  # pragma: no cover - Windows kills pool workers with the job object
        return None
    parent = os.getppid() if parent is None else parent
    if os.getppid() != parent:
        os._exit(1)

    def run():
        while True:
            time.sleep(interval_s)
            if os.getppid() != parent:
                os._exit(1)

    thread = threading.Thread(target=run, name="watch-parent", daemon=True)
    thread.start()
    return thread
