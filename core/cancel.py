"""Cancelling a running frame between chunks of work (Esc in the add-on
stops a frame within one chunk's time).

A :class:`CancelToken` belongs to one job. The thread that runs the job
makes it current (``with watching(token):``); the loops that split long
work into chunks (``kernels.each_in_threads``: ray-casting bands, Embree
chunks, penumbra casting; ``pcf``'s rows of pixels) call :func:`check`
between chunks, which raises :class:`Cancelled` once the token is
cancelled. Nothing here knows about Blender: the add-on's worker thread
cancels the token from the UI thread (``bridge.pipeline.BackgroundFrameJob``).
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Optional


class Cancelled(Exception):
    """The job was cancelled; what it computed so far is thrown away."""


class CancelToken:
    """A cancel flag one job's threads share (``threading.Event`` inside)."""

    def __init__(self):
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        """Raise :class:`Cancelled` once :meth:`cancel` was called."""
        if self._event.is_set():
            raise Cancelled()


_local = threading.local()


def current() -> Optional[CancelToken]:
    """The token of the job this thread runs (None: nothing can cancel it)."""
    return getattr(_local, "token", None)


@contextmanager
def watching(token: Optional[CancelToken]):
    """Make ``token`` this thread's current token for the block."""
    prev = current()
    _local.token = token
    try:
        yield token
    finally:
        _local.token = prev


def check() -> None:
    """Raise :class:`Cancelled` if this thread's job was cancelled."""
    token = current()
    if token is not None:
        token.check()
