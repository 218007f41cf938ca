"""Multilayer EXR in/out with the OpenEXR module (DESIGN.md "Contracts").

One layer per light, one single-channel float32 pass per method id: channel
``<layer>.<method>.V``, which Blender splits as layer / pass / channel, so its
Image node shows one socket per method. A filtered frame (``pixel_filter``)
adds the coverage to each layer as pass ``Alpha``, channel ``<layer>.Alpha.A``;
the Z and vector passes (``core/data_passes.py``) go into each layer as
Blender names them: ``<layer>.Depth.Z``, ``<layer>.Vector.X`` ... ``.W``.
Files are written atomically: to a
temporary name in the same folder, then renamed.
"""
from __future__ import annotations

import os
import secrets
from contextlib import contextmanager
from typing import Dict, Mapping

import numpy as np

CHANNEL = "V"
ALPHA_PASS = "Alpha"     # the coverage of a filtered frame; its channel is "A"
DEPTH_PASS, VECTOR_PASS = "Depth", "Vector"
#: the channels of a pass not named after a method (every other: ``CHANNEL``)
PASS_CHANNELS = {ALPHA_PASS: "A", DEPTH_PASS: "Z", VECTOR_PASS: "XYZW"}
TEMP_PREFIX = ".penumbra-"


@contextmanager
def atomic_file(path: str):
    """Yield a temporary file name beside ``path`` (the file exists, empty);
    when the block ends, rename it onto ``path``; on any exception
    (KeyboardInterrupt from a farm's SIGTERM included) remove it.

    The name is drawn before the file is created and the clean-up covers
    the creation itself, so an interrupt at any point leaves either the
    whole new file or none, never a temporary one. The file is created with
    mode 0666 less the process umask (0644 under 022), as ``open()`` would
    create ``path`` itself (``tempfile.mkstemp`` would force 0600).
    """
    d = os.path.dirname(os.path.abspath(path)) or "."
    suffix = os.path.splitext(path)[1]
    tmp = None
    try:
        while True:
            tmp = os.path.join(d, f"{TEMP_PREFIX}{secrets.token_hex(6)}{suffix}")
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:      # another file of that name: not ours
                tmp = None
                continue
            break
        os.close(fd)
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str, data: bytes) -> None:
    with atomic_file(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def write_multilayer(path: str, layers: Mapping[str, Mapping[str, np.ndarray]],
                     attributes: Mapping[str, str] | None = None) -> None:
    """Write ``layers[layer][pass] = float32[H,W]`` (float32[H,W,C] for a
    pass of C channels, ``PASS_CHANNELS``) as one multilayer EXR."""
    import OpenEXR
    channels = {}
    shape = None
    for layer, passes in layers.items():
        for pname, img in passes.items():
            a = np.asarray(img, np.float32)
            names = PASS_CHANNELS.get(pname, CHANNEL)
            if a.shape[2:] != ((len(names),) if len(names) > 1 else ()) or a.ndim < 2:
                raise ValueError(f"pass {layer}.{pname} must be 2-D with {len(names)} channel(s)")
            if shape is None:
                shape = a.shape[:2]
            elif a.shape[:2] != shape:
                raise ValueError("all passes of one EXR must share a size")
            if not np.isfinite(a).all():
                raise ValueError(f"pass {layer}.{pname} holds non-finite values")
            for c, name in enumerate(names):
                channels[f"{layer}.{pname}.{name}"] = np.ascontiguousarray(a if a.ndim == 2 else a[..., c])
    if not channels:
        raise ValueError("nothing to write")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (attributes or {}).items():
        header[f"penumbra/{k}"] = str(v)
    with atomic_file(path) as tmp:
        with OpenEXR.File(header, channels) as f:
            f.write(tmp)


def read_multilayer(path: str) -> Dict[str, Dict[str, np.ndarray]]:
    """Read every part's channels back into ``{layer: {pass: array}}``
    (channel names ``layer.pass.X``; a name with fewer dots keeps what it has;
    a pass of several channels, ``PASS_CHANNELS``, as [H, W, C])."""
    import OpenEXR
    out: Dict[str, Dict[str, np.ndarray]] = {}
    with OpenEXR.File(path, separate_channels=True) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                bits = name.split(".")
                if len(bits) >= 3:
                    layer, pname = ".".join(bits[:-2]), bits[-2]
                elif len(bits) == 2:
                    layer, pname = bits
                else:
                    layer, pname = "", bits[0]
                names = PASS_CHANNELS.get(pname, "")
                if len(names) > 1 and bits[-1] in names:
                    parts = out.setdefault(layer, {}).setdefault(pname, {})
                    parts[names.index(bits[-1])] = np.asarray(ch.pixels)
                else:
                    out.setdefault(layer, {})[pname] = np.asarray(ch.pixels)
    for passes in out.values():
        for pname, v in passes.items():
            if isinstance(v, dict):
                passes[pname] = np.stack([v[k] for k in sorted(v)], -1)
    return out
