"""Grayscale 8-bit PNG previews with zlib only (no imaging library needed)."""
from __future__ import annotations

import struct
import zlib

import numpy as np

from .exr import atomic_write_bytes


def encode_gray(img: np.ndarray) -> bytes:
    a = np.clip(np.nan_to_num(np.asarray(img, np.float64)), 0.0, 1.0)
    q = (a * 255.0 + 0.5).astype(np.uint8)
    h, w = q.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), q], axis=1).tobytes()  # filter 0 per row

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


def write_gray(path: str, img: np.ndarray) -> None:
    atomic_write_bytes(path, encode_gray(img))
