"""Cancelling inside a long method (Esc answered within a second): the
job's cancel token (``core/cancel.py``) is checked between the chunks of
``kernels.each_in_threads`` (ray-casting bands, Embree chunks, penumbra
casting, pcf's chunks of pixels). No timing: the token cancels
itself after its first check, and fewer chunks run than exist."""
from __future__ import annotations

import pytest

from penumbra.core import cancel, raycast
from penumbra.core.cancel import CancelToken, Cancelled
from penumbra.core.kernels import each_in_threads
from helpers import CancelAfter
from synthetic import area_light, half_plane_scene


@pytest.mark.parametrize("workers", [1, 2])
def test_each_in_threads_stops_after_the_first_chunk(workers):
    ran = []
    token = CancelAfter(1)
    with cancel.watching(token), pytest.raises(Cancelled):
        each_in_threads(ran.append, range(50), workers)
    assert 1 <= len(ran) <= workers < 50
    assert token.cancelled


def test_each_in_threads_runs_everything_without_a_token():
    ran = []
    each_in_threads(ran.append, range(20), 2)
    assert sorted(ran) == list(range(20))
    assert cancel.current() is None


def test_a_token_is_per_thread_and_restored():
    token = CancelToken()
    with cancel.watching(token):
        assert cancel.current() is token
        token.cancel()
        with pytest.raises(Cancelled):
            cancel.check()
    assert cancel.current() is None
    cancel.check()                         # nothing to cancel outside the block


def test_gbuffer_bands_stop_after_the_first(monkeypatch):
    monkeypatch.setattr(raycast, "BAND_RAYS", 32)     # one band per row
    scene = half_plane_scene(area_light(1.0), res=24)
    token = CancelAfter(1)
    with cancel.watching(token), pytest.raises(Cancelled):
        raycast.camera_gbuffer(scene, 24, 24, threads=1)
    assert token.checks == 2 < 24                     # the second band's check raised
