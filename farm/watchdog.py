"""A chunk's ``penumbra render`` exits with the Dask worker that started it.

The render runs in a child process of the worker because bpy wants a process
and a main thread of its own, and a crash (or a leak) must not take the worker
down. ``render_chunk`` starts it as ``python -m penumbra.cli render ...`` with
``PENUMBRA_EXIT_WITH_PARENT`` set; ``cli.console_main`` then calls
:func:`exit_with_parent`: a watchdog thread notices when the parent is gone
(the worker was killed; its chunk is rescheduled elsewhere) and sends the
process SIGTERM, which ``console_main`` turns into an interrupt, so a file
being written is removed rather than left half-written.
"""
from __future__ import annotations

import os
import signal
import threading
import time

#: the environment variable that asks ``console_main`` for the watchdog
ENV = "PENUMBRA_EXIT_WITH_PARENT"
WATCH_PERIOD_S = 0.5


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_PERIOD_S)
    os.kill(os.getpid(), signal.SIGTERM)


def exit_with_parent() -> None:
    """Start the watchdog (a daemon thread) for this process's parent."""
    threading.Thread(target=_watch_parent, args=(os.getppid(),), daemon=True,
                     name="penumbra-parent-watchdog").start()
