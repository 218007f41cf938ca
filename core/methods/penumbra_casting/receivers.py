"""Receiver points of penumbra casting (Laine & Aila 2005, section 3.1) and
everything the casting needs before any blocker (``prepare``).

The receivers r_j are the camera G-buffer hits, moved off their surface
exactly like the ``embree`` reference's ray origins
(``sampling.offset_points``); each gets its light sample set by a hash of
its pixel (section 3.4) and, for a sphere light, its disk rotation
(``light.min_rotations``); for the irradiance ratio they keep their normals
(``visibility``). The tolerances scale with the scene's extent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ... import sampling
from ..base import IRRADIANCE
from .cast import Receivers
from .light import MODE_SPHERE, LightSamples, LightSetup, all_sample_points, assign_sets, light_setup, min_rotations


@dataclass
class Setup:
    """Everything the casting needs, before any triangle: receivers, light
    samples, groups, polygons. ``sample_points(rows)`` gives the exact light
    sample positions (homogeneous, bit order) the casting tests for those
    receivers, so a test can cast the same rays with Embree."""

    idx: np.ndarray          # pixel ids of the receivers
    Pg: np.ndarray           # G-buffer positions
    pts: np.ndarray          # receiver points r_j (the reference's ray origins)
    set_id: np.ndarray       # light sample set of each receiver
    M: np.ndarray            # sphere light: each receiver's disk rotation (row-major 3x3)
    N: np.ndarray            # normals for the irradiance weights (zero rows: the average)
    light: LightSetup
    seed: int
    tol: float               # slack of the culling tests (scene units)
    eps: float               # plane construction tolerance (scene units)

    def light_samples(self) -> LightSamples:
        L = self.light
        return LightSamples(L.mode, L.SP, L.Q, L.centre, L.lp, self.seed, L.bit2s, L.nx, L.ny)

    def receivers(self) -> Receivers:
        return Receivers(self.pts, self.set_id, self.idx, self.Pg, self.M, self.N)

    def sample_points(self, rows) -> np.ndarray:
        rows = np.ascontiguousarray(rows, np.int64)
        return all_sample_points(self.light_samples(), rows, self.light.S, self.receivers())


def prepare(buffers, light, params) -> Setup:
    """The receivers of ``buffers``' G-buffer and ``light``'s setup for
    ``params`` (``PenumbraCastingParams``)."""
    g = buffers.gbuffer
    idx, Pg, Nrm = g.hit_points()
    pts = sampling.offset_points(Pg, Nrm, float(buffers.scale), True) if len(idx) else np.empty_like(Pg)
    mag = float(np.abs(pts).max()) if len(pts) else 1.0
    mag = max(mag, float(np.abs(light.position).max()), float(buffers.scale), 1e-30)
    tol = 1e-9 * mag
    eps = 1e-12 * mag
    L = light_setup(light, params.samples, params.GroupSize, params.SampleSets,
                    params.shared_samples_with_reference, params.seed, Pg, tol)
    seed = int(params.seed)
    if L.mode == MODE_SPHERE:
        M, _ = min_rotations(Pg, L.centre, L.w0)
    else:
        M = np.zeros((1, 9))
    set_id = assign_sets(g.seed_ids(idx), L.nsets, seed) if L.nsets > 1 else np.zeros(len(idx), np.int64)
    N = Nrm if params.visibility == IRRADIANCE else np.zeros((0, 3))
    return Setup(idx, Pg, pts, set_id, M, N, L, seed, tol, eps)
