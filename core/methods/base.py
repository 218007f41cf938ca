"""What every method declares (in the spirit of Falcor's RenderPass).

A method names the buffers it needs (``needs``), the passes it writes
(``passes``, each with its kind of V), and its parameters as a dataclass whose
field names are the paper's. The planner unions the needs of the chosen
methods and builds each buffer once (``core/buffers.py``); ``run()`` sees
only the buffers its needs declare (``buffers.NEED_BUILDERS``).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, fields
from typing import Dict, FrozenSet, Mapping, Optional

import numpy as np

# buffer names a method can ask for (each built by FrameBuffers: buffers.NEED_BUILDERS)
GBUFFER = "gbuffer"                 # camera G-buffer at pixel centres
LIGHT_VIEW = "light_view"           # depth + object-id map(s) from the light centre
SHADOW_GEOMETRY = "shadow_geometry" # Embree BVH of the shadow-casting triangles
SHADOW_TRIANGLES = "shadow_triangles"  # the shadow-casting triangles themselves (no BVH)
LIGHT_SAMPLE_VIEWS = "light_sample_views"  # depth maps from N points on the light
MESH_PIECES = "mesh_pieces"         # connected mesh pieces: surface labels finer than objects
PRECOMPUTE = "precompute"           # a method's light-space precompute, shared by a frame's two stages

AVERAGE = "average"        # Agrawala et al. equation 2
IRRADIANCE = "irradiance"  # equation 1 with / without V
#: the definitions a method's own pass can follow (its Params' ``visibility``), the default first
VISIBILITIES = (IRRADIANCE, AVERAGE)
#: light samples per pixel of every method that samples the light, and of a
#: light's Light Samples in the add-on: a filtered pass's noise is then about
#: that of Cycles' own shadow pair at 256 samples
DEFAULT_LIGHT_SAMPLES = 256


@dataclass
class MethodResult:
    passes: Dict[str, np.ndarray]               # pass id -> float32[H,W] in [0,1]
    time_s: Dict[str, float] = field(default_factory=dict)   # phase -> seconds
    stats: Dict[str, object] = field(default_factory=dict)
    params: Optional[Dict[str, object]] = None   # external producers report theirs here


class Method:
    """Base class; subclasses set the class attributes and implement ``run``."""

    id: str = ""
    paper: str = ""
    #: pass id -> AVERAGE | IRRADIANCE; the method's own pass (``id``) follows its
    #: Params' ``visibility`` where the Params has one (``visibility``)
    passes: Mapping[str, str] = {}
    needs: FrozenSet[str] = frozenset()
    Params: type = object
    physical: bool = False                  # claims to converge to the reference
    #: shades each receiver of a packed G-buffer on its own (a filtered pass's
    #: sub-pixel receivers as a list); False: it needs an image, and runs on
    #: the supersampled view with only the sub-pixel receivers set
    packed: bool = False
    #: traces a scene kept as instances without flattening it (its buffers
    #: come from Embree's two-level BVH: the G-buffer, light views from the
    #: light's centre, shadow rays); False: it needs world-space triangles
    runs_on_instances: bool = False
    #: finds each receiver's occluders where they are at its shutter time
    #: (``GBuffer.time``, ``core/motion.py``); otherwise where they are at the frame
    shutter_time: bool = False
    #: the Preview's settings of this method, under a light's own knobs (which
    #: win); None: too slow for the Preview, which runs ``pcf`` instead
    preview_params: Optional[Mapping[str, object]] = None

    def run(self, buffers, light, params) -> MethodResult:  # pragma: no cover - abstract
        """``buffers``: the frame's ``FrameBuffers``, or the view of it that
        shows only ``needs`` (``FrameBuffers.view``, what ``render_frame`` passes)."""
        raise NotImplementedError

    def subpixel_overrides(self, params, share: int) -> Dict[str, object]:
        """Params overrides for a filtered pass's sub-pixel receivers when
        ``share`` of them make up one pixel (``filtered_frame``): a method that
        draws light samples per receiver gives each its share of them, so a
        pixel's receivers together take about what one receiver takes at the
        pixel centre. Default: nothing changes (the method's cost does not
        grow with the light samples per receiver)."""
        return {}

    def visibility(self, pass_id: str, params=None) -> str:
        """Which V ``pass_id`` is (AVERAGE or IRRADIANCE) under ``params``."""
        own = getattr(params, "visibility", None) if pass_id == self.id else None
        return own if own is not None else self.passes[pass_id]

    # helpers -------------------------------------------------------------
    def make_params(self, overrides: Mapping[str, object] | None = None):
        """Params dataclass with ``overrides`` applied (unknown names ignored
        so one ``--samples`` can reach every method that samples). Values are
        converted to the field's default type; "false"/"0"/"no"/"off" are False."""
        p = self.Params()
        for f in fields(p):
            if not overrides or f.name not in overrides or overrides[f.name] is None:
                continue
            value, default = overrides[f.name], getattr(p, f.name)
            if isinstance(default, bool) or (default is None and str(f.type) == "Optional[bool]"):
                if isinstance(value, str):
                    low = value.strip().lower()
                    if low not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                        raise ValueError(f"{f.name}: expected a boolean, not {value!r}")
                    value = low in ("1", "true", "yes", "on")
                value = bool(value)
            elif default is not None:
                value = type(default)(value)
            setattr(p, f.name, value)
        if getattr(p, "visibility", None) not in (None,) + VISIBILITIES:
            raise ValueError(f"visibility must be one of {', '.join(VISIBILITIES)}, not {p.visibility!r}")
        return p


def params_dict(params) -> dict:
    out = {}
    for k, v in asdict(params).items():
        if isinstance(v, (np.floating, np.integer)):
            v = v.item()
        out[k] = v
    return out


class PhaseTimer:
    """Accumulates wall time per named phase: ``with timer('sort'): ...``."""

    def __init__(self):
        self.times: Dict[str, float] = {}
        self._t0 = time.perf_counter()

    def __call__(self, name: str):
        timer = self

        class _Ctx:
            def __enter__(self_inner):
                self_inner.t = time.perf_counter()

            def __exit__(self_inner, *exc):
                timer.times[name] = timer.times.get(name, 0.0) + time.perf_counter() - self_inner.t
                return False
        return _Ctx()

    def result(self) -> Dict[str, float]:
        out = dict(self.times)
        out["total"] = sum(self.times.values())
        return out
