"""``python -m penumbra.farm.render_child render ...``: one chunk's
``penumbra render`` in a child process of a Dask worker.

The render runs in a process of its own because bpy wants a process and a
main thread of its own, and a crash (or a leak) must not take the worker down.
The child exits with its worker: a watchdog thread notices when its parent
is gone (the worker was killed; its chunk is rescheduled elsewhere) and sends
itself SIGTERM, which ``penumbra``'s console entry turns into an interrupt,
so a file being written is removed rather than left half-written.
"""
from __future__ import annotations

import os
import signal
import threading
import time

from .. import cli

WATCH_PERIOD_S = 0.5


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_PERIOD_S)
    os.kill(os.getpid(), signal.SIGTERM)


def main() -> None:
    threading.Thread(target=_watch_parent, args=(os.getppid(),), daemon=True,
                     name="penumbra-parent-watchdog").start()
    cli.console_main()


if __name__ == "__main__":
    main()
