"""``penumbra render --frames`` takes every chunk string the farms send:
Open Job Description's one-frame chunk ``5-5``, and the forms Flamenco's
``frameChunker`` emits (``47``, ``9,10,20,21``, ``1-4,9,20-22``)."""
import os

import pytest
from hypothesis import given
from hypothesis import strategies as st

from penumbra.cli import _frame_list, main
from penumbra.farm.chunks import chunk_frames, frame_spec
from scenes import sample_path

FAST = ["--resolution", "16x16", "--methods", "pcf", "--no-previews"]


@pytest.mark.parametrize("chunk, frames", [
    ("5-5", [5]),                                  # OpenJD: a chunk of one frame
    ("47", [47]),                                  # Flamenco: one frame
    ("9,10,20,21", [9, 10, 20, 21]),               # Flamenco: runs of two frames
    ("1-4,9,20-22", [1, 2, 3, 4, 9, 20, 21, 22]),  # Flamenco: ranges and single frames
])
def test_render_writes_exactly_the_frames_of_a_chunk_string(tmp_path, capsys, chunk, frames):
    assert main(["render", sample_path("torus_plane"), "--out", str(tmp_path), "--frames", chunk] + FAST) == 0
    want = sorted(f"torus_plane.{f:04d}.{ext}" for f in frames for ext in ("exr", "json"))
    assert sorted(os.listdir(tmp_path)) == want


@pytest.mark.parametrize("chunk", ["5-", "-", "1-4,,9", "9;10", "1..4", "4-1", "1-4:0", " "])
def test_bad_chunk_strings_exit_2_with_one_line(tmp_path, capsys, chunk):
    assert main(["render", sample_path("torus_plane"), "--out", str(tmp_path), "--frames", chunk] + FAST) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("penumbra: error: bad --frames")
    assert os.listdir(tmp_path) == []


@given(st.sets(st.integers(-50, 400), min_size=1, max_size=60), st.integers(1, 12))
def test_farm_chunks_cover_the_frames_and_read_back(frames, size):
    """``penumbra farm``'s chunks: contiguous runs of the sorted frames, at
    most ``size`` each, whose chunk strings ``--frames`` parses back exactly."""
    chunks = chunk_frames(frames, size)
    assert [f for c in chunks for f in c] == sorted(frames)
    assert all(1 <= len(c) <= size for c in chunks) and all(len(c) == size for c in chunks[:-1])
    for c in chunks:
        assert _frame_list(frame_spec(c)) == c


def test_frame_spec_forms():
    assert frame_spec([47]) == "47"
    assert frame_spec([9, 10, 20, 21]) == "9-10,20-21"
    assert frame_spec([1, 2, 3, 4, 9, 20, 21, 22]) == "1-4,9,20-22"
    assert frame_spec([-3, -2, -1, 0]) == "-3-0"
    with pytest.raises(ValueError):
        frame_spec([])
    with pytest.raises(ValueError):
        chunk_frames([1, 2], 0)
