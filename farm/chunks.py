"""Frame chunks and their chunk strings.

A chunk is a run of at most ``size`` consecutive entries of the sorted frame
list, as Flamenco's ``frameChunker`` and OpenJD's CONTIGUOUS chunks cut it;
its chunk string is what ``penumbra render --frames`` reads back.
"""
from __future__ import annotations

from typing import List, Sequence


def chunk_frames(frames: Sequence[int], size: int) -> List[List[int]]:
    """Sorted unique ``frames`` cut into chunks of at most ``size`` frames."""
    if size < 1:
        raise ValueError("chunk size must be at least 1")
    ordered = sorted(set(int(f) for f in frames))
    return [ordered[i:i + size] for i in range(0, len(ordered), size)]


def frame_spec(frames: Sequence[int]) -> str:
    """The shortest ``--frames`` string for ``frames``: runs of consecutive
    frames as ``A-B``, single frames as ``N`` (``[1,2,3,4,9]`` -> ``1-4,9``)."""
    ordered = sorted(set(int(f) for f in frames))
    if not ordered:
        raise ValueError("no frames")
    parts = []
    start = prev = ordered[0]
    for f in ordered[1:] + [None]:
        if f is not None and f == prev + 1:
            prev = f
            continue
        parts.append(str(start) if start == prev else f"{start}-{prev}")
        if f is not None:
            start = prev = f
    return ",".join(parts)
