"""Pixel filters as the renderers define them, and the filtered pass built
from them: which pixels need sub-pixel samples, which samples, their resolve.

``PixelFilter`` (``parse``: ``none | scene | KIND:W[:G]``):

    kind        "none"  box | gaussian | blackman-harris | eevee; none: pixel centres
    width       1.5     Cycles' filter_width, EEVEE's filter_size (pixels)
    grid        4       G: sub-pixel samples per axis where a footprint is refined (1..16)
    threshold   0.07    V's second difference that refines a pixel (< 0: all, full grid)
    sharp       0.2     V's second difference beyond which a pixel reads the full grid
    shade_grid  2       samples per axis of the lattice a mildly kinked pixel reads
    geo_v       0.02    V's difference across a geometry edge that refines it (>= 0)
    edge_tail   0.01    the filter's share an edge beyond ``reach`` may carry

Filters. Cycles (``intern/cycles/scene/film.cpp``, ``filter_table``) weights
a camera sample at offset (x, y) from the pixel centre by f(x) f(y):

    box              f = 1                               |v| <= 1/2 (sync forces w = 1)
    gaussian         f = exp(-8 v^2 / w^2), sigma = w/4  |v| <= 1.5 w (table spans 3w)
    blackman-harris  f = 0.35875 - 0.48829 cos a + 0.14128 cos 2a - 0.01168 cos 3a,
                     a = 2 pi (v / 2w + 1/2)             |v| <= w (table spans 2w)

EEVEE (``eevee_film.cc``, ``film_filter_weight``) weights by the distance r
to the pixel centre: exp(-r^2 / (2 (0.284 R)^2)) for r <= R = filter_size
(a Gaussian fitted to Blackman-Harris); no filter at one render sample.

Resolve (``resolve``). A pixel's filtered value is the quadrature of the
filter over its footprint, which reaches into its neighbours, on the
G x G sub-pixel samples (sample (I, J) of the supersampled view sits at
((J + 0.5) / G, (I + 0.5) / G) pixels):

    average pass     V = sum w V_k / sum w                (world samples: V = 1)
    irradiance pass  V = sum w E0_k V_k / sum w E0_k      (world samples: E0 = 0)
    coverage (alpha)   = sum w hit_k / sum w

so unshadowed render x irradiance pass = shadowed render. The samples are a
packed list (``footprint_flat``): no supersampled image is made.

Refinement (``refine_mask``). The centre sample of a symmetric normalised
filter integrates a locally linear V exactly, so a pixel keeps its
pixel-centre value unless a neighbour within ``reach`` (the smallest n >= 1
whose 1-D filter tail beyond n px is at most edge_tail) differs from it in
hit, or in object id, depth or normal with a pass differing by more than
geo_v across the two, or V's second difference V[p+d] + V[p-d] - 2 V[p]
over opposite neighbours exceeds threshold (a jump between two centres
shows as one of its height). Geometry edges and second differences beyond
sharp (hard shadow edges) read the footprint's full grid; pixels flagged
only by V's mild kinks (a soft penumbra's ends, a method's noise) read a
shade_grid x shade_grid lattice of their own pixel, symmetric about its
centre so a linear V is still integrated exactly (``shade_lattice``).

Departures from Cycles: samples outside the image are left out and the
weights renormalise over those inside (Cycles traces beyond the frame: the
border ring differs); the refinement samples only where V or the geometry
needs it (Cycles' every pixel on the full grid: threshold < 0).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .jit import kernel
from .kernels import each_range

KINDS = ("box", "gaussian", "blackman-harris", "eevee")
NONE = "none"
SCENE = "scene"
EEVEE_SIGMA = 0.284            # eevee_film: Gaussian sigma per unit of filter radius
DEFAULT_GRID = 4               # sub-pixel samples per axis where a pixel is refined
MAX_GRID = 16
DEFAULT_SHADE_GRID = 2         # sub-pixel samples per axis where only V is mildly not locally linear
DEFAULT_SHARP = 0.2            # V's second difference beyond which a shadow edge gets the full grid
DEFAULT_GEO_V = 0.02           # V's difference across a discontinuity of the geometry that refines it
DEFAULT_THRESHOLD = 0.07       # V's second difference between pixel centres that marks a shadow edge
EDGE_TAIL = 0.01               # PixelFilter.reach: an edge it misses moves a pixel by <= 1 % of the jump
TAIL_STEPS = 4096
DEPTH_JUMP = 0.05              # relative depth difference that marks a silhouette
NORMAL_COS = 0.9               # normals closer than this (cosine) mark a crease


class PixelFilterError(ValueError):
    """A bad ``--pixel-filter`` spec (one line for the command line)."""


@dataclass(frozen=True)
class PixelFilter:
    """One of ``KINDS`` with its width in pixels (Cycles' ``filter_width``,
    EEVEE's ``filter_size``), or ``none`` (the pixel-centre pass)."""

    kind: str = NONE
    width: float = 1.5
    grid: int = DEFAULT_GRID
    threshold: float = DEFAULT_THRESHOLD   # refine_mask's V threshold; < 0: refine every pixel
    edge_tail: float = EDGE_TAIL  # ``reach``: the filter's share an edge it misses may carry
    shade_grid: int = DEFAULT_SHADE_GRID   # sub-samples per axis where only V's mild kinks need them
                                           # (a divisor of ``grid``; otherwise, or = grid: the full grid)
    sharp: float = DEFAULT_SHARP  # V's test beyond which a shadow edge gets the full grid
    geo_v: float = DEFAULT_GEO_V  # a geometry edge is refined where V differs across it by more than this

    @property
    def shade_lattice(self) -> np.ndarray:
        """bool[grid]: the sub-rows (and sub-columns) of each pixel that the
        pixels refined for V alone read: ``shade_grid`` of the ``grid``,
        placed symmetrically about the pixel centre (each pixel's samples'
        centroid is its centre, so a linear V is integrated exactly; every
        ``grid / shade_grid``-th sub-row would not be); all of them when
        ``shade_grid`` does not divide ``grid`` or equals it."""
        g, v = int(self.grid), int(self.shade_grid)
        keep = np.ones(g, np.bool_)
        if 0 < v < g and g % v == 0:
            keep[:] = False
            for k in range((v + 1) // 2):
                j = int(g * (k + 0.5) / v)
                keep[j] = keep[g - 1 - j] = True
        return keep

    @property
    def is_none(self) -> bool:
        return self.kind == NONE

    @property
    def radius(self) -> float:
        """Half-width of the footprint in pixels (where the weight ends)."""
        return {"box": 0.5 * self.width, "gaussian": 1.5 * self.width,
                "blackman-harris": self.width, "eevee": self.width}.get(self.kind, 0.0)

    def weight(self, dx, dy) -> np.ndarray:
        """The (unnormalised) weight of a sample at offset (dx, dy) pixels."""
        dx = np.asarray(dx, np.float64)
        dy = np.asarray(dy, np.float64)
        if self.kind == "eevee":
            r2 = dx * dx + dy * dy
            R = self.width
            return np.where(r2 <= R * R, np.exp(-0.5 * r2 / (EEVEE_SIGMA * R) ** 2), 0.0)
        return self.profile(dx) * self.profile(dy)

    def profile(self, v) -> np.ndarray:
        """Cycles' 1-D filter function of this kind, zero outside the footprint."""
        v = np.asarray(v, np.float64)
        w, r = self.width, self.radius
        inside = np.abs(v) <= r * (1 + 1e-12)
        if self.kind == "box":
            f = np.ones_like(v)
        elif self.kind == "gaussian":
            f = np.exp(-2.0 * (v * 6.0 / (3.0 * w)) ** 2)
        elif self.kind == "blackman-harris":
            a = 2.0 * math.pi * (v / (2.0 * w) + 0.5)
            f = 0.35875 - 0.48829 * np.cos(a) + 0.14128 * np.cos(2 * a) - 0.01168 * np.cos(3 * a)
        else:
            raise PixelFilterError(f"no 1-D profile for pixel filter {self.kind!r}")
        return np.where(inside, f, 0.0)

    def taps(self):
        """(first sub-sample offset m0, weights float64[k, k]): pixel (r, c)
        reads sub-sample (grid r + m0 + a, grid c + m0 + b) with weight
        ``weights[a, b]``. Empty weights: the filter is narrower than the
        sub-sample spacing and the pixel centre stands for it."""
        s, R = int(self.grid), self.radius
        m_lo = int(math.ceil((0.5 - R) * s - 0.5 - 1e-9))
        m_hi = int(math.floor((0.5 + R) * s - 0.5 + 1e-9))
        if m_hi < m_lo:
            return 0, np.zeros((0, 0), np.float64)
        d = (np.arange(m_lo, m_hi + 1) + 0.5) / s - 0.5
        k = self.weight(d[None, :], d[:, None])
        if not (k > 0).any():
            return 0, np.zeros((0, 0), np.float64)
        return m_lo, np.ascontiguousarray(k, np.float64)

    @property
    def reach(self) -> int:
        """Neighbouring pixels (per axis) ``refine_mask`` compares a pixel
        with: an edge nearer than ``reach`` pixels to its centre lies between
        it and one of them; the smallest n >= 1 whose 1-D tail (the
        filter's share beyond n px, ``tail``) is at most ``edge_tail``, so
        an edge it misses moves the pixel's filtered value by at most that
        share of the jump (``edge_tail`` 0: the whole footprint)."""
        n = 1
        while n < self.radius and self.tail(n) > self.edge_tail:
            n += 1
        return n

    def tail(self, offset: float) -> float:
        """The share of the filter's 1-D profile (EEVEE: its Gaussian)
        beyond ``offset`` pixels on one side (midpoint rule)."""
        r = self.radius
        if offset >= r:
            return 0.0
        v = (np.arange(TAIL_STEPS) + 0.5) * (r / TAIL_STEPS)
        if self.kind == "eevee":
            f = np.exp(-0.5 * (v / (EEVEE_SIGMA * self.width)) ** 2)
        else:
            f = self.profile(v)
        return float(f[v > offset].sum() / (2.0 * f.sum()))

    def to_json(self) -> dict:
        if self.is_none:
            return {"type": NONE}
        return {"type": self.kind, "width_px": float(self.width), "radius_px": float(self.radius),
                "grid": int(self.grid), "threshold": float(self.threshold)}

    def spec(self) -> str:
        return NONE if self.is_none else f"{self.kind}:{self.width:g}:{self.grid}"

    def describe(self) -> str:
        """One line for ``penumbra plan`` and ``render``'s table."""
        if self.is_none:
            return "none (one receiver at each pixel centre)"
        return (f"{self.kind} {self.width:g} px ({self.grid} x {self.grid} sub-pixel receivers where a "
                f"pixel's footprint holds an edge or a shadow edge; each pass gets an Alpha, the coverage)")


def parse(spec: str, scene_filter: Optional[PixelFilter] = None) -> PixelFilter:
    """``none | scene | box:W | gaussian:W | blackman-harris:W`` (and
    ``eevee:W``), each but ``none`` optionally followed by ``:G`` (sub-pixel
    samples per axis, default ``DEFAULT_GRID``) -> PixelFilter; ``scene`` is
    ``scene_filter`` (the scene's own, ``from_render_settings``), or an
    error when it is not known."""
    s = (spec or "").strip().lower()
    if s == NONE:
        return PixelFilter()
    kind, _, rest = s.partition(":")
    if kind == SCENE:
        if scene_filter is None:
            raise PixelFilterError("--pixel-filter scene: the scene's filter is not known here")
        return dataclasses.replace(scene_filter, grid=_grid(rest, spec)) if rest else scene_filter
    bits = rest.split(":") if rest else []
    if kind not in KINDS or not 1 <= len(bits) <= 2:
        raise PixelFilterError(f"bad pixel filter {spec!r}: expected none, scene, box:W, gaussian:W "
                               f"or blackman-harris:W")
    try:
        w = float(bits[0])
    except ValueError:
        raise PixelFilterError(f"bad pixel filter width in {spec!r}: expected a number of pixels")
    if not (math.isfinite(w) and 0.0 < w <= 64.0):
        raise PixelFilterError(f"bad pixel filter width in {spec!r}: expected 0 < W <= 64 pixels")
    return PixelFilter(kind, w, _grid(bits[1], spec) if len(bits) == 2 else DEFAULT_GRID)


def _grid(text: str, spec: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= MAX_GRID:
        raise PixelFilterError(f"bad sub-pixel grid in {spec!r}: expected 1..{MAX_GRID} samples per axis")
    return int(text)


def from_render_settings(engine: str, cycles_type: Optional[str], cycles_width: float,
                         filter_size: float, eevee_samples: int = 0) -> PixelFilter:
    """The filter a render uses: Cycles' type and width (BOX ignores the
    width: Blender passes 1), EEVEE's ``render.filter_size``; any other
    engine: Cycles' settings. EEVEE filters nothing at one render sample
    (``eevee_samples``, ``scene.eevee.taa_render_samples``: eevee_film.cc sets
    the filter radius to 0 when the sample count is 1), nor at size 0."""
    if engine and engine.upper().startswith("BLENDER_EEVEE"):
        if filter_size <= 0 or int(eevee_samples) == 1:
            return PixelFilter()
        return PixelFilter("eevee", float(filter_size))
    t = (cycles_type or "BLACKMAN_HARRIS").upper()
    if t == "BOX":
        return PixelFilter("box", 1.0)
    kind = {"GAUSSIAN": "gaussian", "BLACKMAN_HARRIS": "blackman-harris"}.get(t, "blackman-harris")
    return PixelFilter(kind, float(cycles_width))


# --------------------------------------------------------------------------
# which pixels need sub-pixel samples

def refine_mask(hit, obj, depth, normal, values, reach, threshold, depth_jump, normal_cos, out,
                sharp, full, geo_v, threads=None):
    """out[r, c] = True where pixel (r, c)'s neighbours within ``reach``
    differ from it in hit, or in object id, depth (relative ``depth_jump``)
    or normal (cosine below ``normal_cos``) with one of ``values[k]`` (the
    pixel-centre passes) differing by more than ``geo_v`` between the two
    (a discontinuity V does not see changes no filtered pass), or where one
    of ``values[k]`` is not locally linear: a second difference
    V[p + d] + V[p - d] - 2 V[p] over a pair of opposite neighbours beyond
    ``threshold`` (a linear ramp across the footprint is integrated exactly
    by the centre sample of a symmetric normalised filter, so only V's
    deviation from linear needs sub-pixel samples; a jump between two
    centres shows as a second difference of its height). ``full[r, c]``:
    the pixel needs the full sub-pixel grid: an edge of the geometry, or
    V's test beyond ``sharp`` (a hard shadow edge); the others only V's mild
    kinks and noise."""
    each_range(lambda r0, r1: _refine_rows(r0, r1, hit, obj, depth, normal, values, int(reach), float(threshold),
                                           float(depth_jump), float(normal_cos), out,
                                           float(sharp), full, float(geo_v)), hit.shape[0], threads, grain=8)


@kernel(nogil=True)
def _refine_rows(r0, r1, hit, obj, depth, normal, values, reach, threshold, depth_jump, normal_cos, out,
                 sharp, full, geo_v):
    """``refine_mask`` for rows r0 .. r1 - 1 (a serial ``nogil`` kernel on
    worker threads, ``kernels.each_range``: a parfor's lowering costs more
    compile time than the loop takes)."""
    H, W = hit.shape
    for r in range(r0, r1):
        for c in range(W):
            geo = False
            vflag = False
            for dr in range(-reach, reach + 1):
                rr = r + dr
                if geo or rr < 0 or rr >= H:
                    continue
                for dc in range(-reach, reach + 1):
                    cc = c + dc
                    if geo or cc < 0 or cc >= W or (dr == 0 and dc == 0):
                        continue
                    if hit[r, c] != hit[rr, cc]:
                        geo = True
                    elif hit[r, c]:
                        edge = False
                        if obj[r, c] != obj[rr, cc]:
                            edge = True
                        elif abs(depth[r, c] - depth[rr, cc]) > depth_jump * min(depth[r, c], depth[rr, cc]):
                            edge = True
                        elif (normal[r, c, 0] * normal[rr, cc, 0] + normal[r, c, 1] * normal[rr, cc, 1]
                              + normal[r, c, 2] * normal[rr, cc, 2]) < normal_cos:
                            edge = True
                        if edge:
                            for k in range(values.shape[0]):
                                if abs(values[k, r, c] - values[k, rr, cc]) > geo_v:
                                    geo = True
                                    break
                    if geo:
                        continue
                    ro, co = r - dr, c - dc               # the opposite neighbour
                    if ro < 0 or ro >= H or co < 0 or co >= W:
                        continue
                    for k in range(values.shape[0]):
                        d = abs(values[k, rr, cc] + values[k, ro, co] - 2.0 * values[k, r, c])
                        if d > threshold:
                            vflag = True
                            geo = d > sharp
                            break
            out[r, c] = geo or vflag
            full[r, c] = geo


@kernel(nogil=True)
def _footprint_rows(refine, full, grid, m0, k, lattice, out):
    """``footprint_samples``' kernel: ``out`` (bool[SH * SW], row-major, all
    False) gets True at the sub-samples some refined pixel reads: a
    ``full`` one its whole footprint (sub-rows grid r + m0 ... + k - 1, the
    same for columns), another the sub-samples with ``lattice[I % grid]``
    and ``lattice[J % grid]`` of its own pixel."""
    H, W = refine.shape
    SH, SW = grid * H, grid * W
    reads = np.zeros((H, SW), np.bool_)        # pixel row r's footprints read sub-column J on every sub-row
    sparse = np.zeros((H, SW), np.bool_)       # ... on the lattice's sub-rows of the pixel
    rows_used = np.zeros(H, np.bool_)
    rows_sparse = np.zeros(H, np.bool_)
    for r in range(H):
        for c in range(W):
            if refine[r, c]:
                if full[r, c]:
                    rows_used[r] = True
                    for b in range(k):
                        J = grid * c + m0 + b
                        if 0 <= J < SW:
                            reads[r, J] = True
                else:
                    rows_sparse[r] = True
                    for b in range(grid):
                        J = grid * c + b
                        if 0 <= J < SW and lattice[J % grid]:
                            sparse[r, J] = True
    for I in range(SH):
        base = I * SW
        r0, r1 = max(0, -((k - 1 - (I - m0)) // grid)), min(H - 1, (I - m0) // grid)
        for r in range(r0, r1 + 1):
            if rows_used[r]:
                for J in range(SW):
                    out[base + J] |= reads[r, J]
        if lattice[I % grid]:
            r = I // grid
            if rows_sparse[r]:
                for J in range(SW):
                    out[base + J] |= sparse[r, J]


def footprint_flat(refine: np.ndarray, grid: int, m0: int, k: int, full: Optional[np.ndarray] = None,
                   lattice: Optional[np.ndarray] = None) -> np.ndarray:
    """int64[N]: the sub-samples the refined pixels read, as sorted flat
    indices I * SW + J of the supersampled view: a ``full`` pixel (None:
    all are) its footprint (taps ``m0``, size ``k``), another only the
    sub-samples of its own pixel whose sub-row and sub-column the bool[grid]
    ``lattice`` keeps (``PixelFilter.shade_lattice``; None: all); its
    footprint then reads those and what its refined neighbours list (the
    resolve renormalises over them). No supersampled image is made, only one
    flag per sub-sample."""
    refine = np.ascontiguousarray(refine, np.bool_)
    full = refine if full is None else np.ascontiguousarray(full, np.bool_)
    lattice = np.ones(grid, np.bool_) if lattice is None else np.ascontiguousarray(lattice, np.bool_)
    H, W = refine.shape
    flags = np.zeros(grid * H * grid * W, np.bool_)
    _footprint_rows(refine, full, int(grid), int(m0), int(k), lattice, flags)
    return np.flatnonzero(flags)


def footprint_samples(refine: np.ndarray, grid: int, m0: int, k: int, full: Optional[np.ndarray] = None,
                      lattice: Optional[np.ndarray] = None):
    """(rows int64[N], cols int64[N]): ``footprint_flat``'s sub-samples as
    supersampled pixels (rows[n], cols[n]), row-major."""
    flat = footprint_flat(refine, grid, m0, k, full, lattice)
    SW = int(grid) * refine.shape[1]
    return flat // SW, flat % SW


@kernel
def resolve(refine, centre, rows, cols, sub, weight_sub, taps, grid, m0, out):
    """Filtered pixels: where ``refine``, sum taps w_k weight_sub_k sub_k /
    sum taps w_k weight_sub_k over the listed sub-samples of the footprint
    (sample n at supersampled pixel (rows[n], cols[n]); 1 where that sum is
    0); elsewhere the pixel-centre value ``centre``. Each sample is added
    to the refined pixels whose footprint holds it (a scatter: the list is
    packed, no supersampled image is needed)."""
    H, W = centre.shape
    k = taps.shape[0]
    num = np.zeros((H, W))
    den = np.zeros((H, W))
    for n in range(rows.shape[0]):
        ws = weight_sub[n]
        if ws == 0.0:
            continue
        I, J = rows[n] - m0, cols[n] - m0
        r0, r1 = max(0, -((k - 1 - I) // grid)), min(H - 1, I // grid)
        c0, c1 = max(0, -((k - 1 - J) // grid)), min(W - 1, J // grid)
        for r in range(r0, r1 + 1):
            a = I - grid * r
            for c in range(c0, c1 + 1):
                if refine[r, c]:
                    w = taps[a, J - grid * c] * ws
                    num[r, c] += w * sub[n]
                    den[r, c] += w
    for r in range(H):
        for c in range(W):
            if not refine[r, c]:
                out[r, c] = centre[r, c]
            else:
                out[r, c] = num[r, c] / den[r, c] if den[r, c] > 0.0 else 1.0


def resolve_samples(flt: PixelFilter, refine: np.ndarray, centre: np.ndarray, rows: np.ndarray,
                    cols: np.ndarray, sub: np.ndarray, weight_sub: Optional[np.ndarray] = None) -> np.ndarray:
    """float32[H, W]: ``resolve`` with this filter's taps over the listed
    sub-samples (``sub[n]`` at supersampled pixel (rows[n], cols[n]));
    ``weight_sub`` (None: 1) is E0 for an irradiance pass, the hit mask
    for coverage."""
    m0, taps = flt.taps()
    centre = np.ascontiguousarray(centre, np.float64)
    if taps.size == 0:
        return centre.astype(np.float32)
    sub = np.ascontiguousarray(np.reshape(sub, -1), np.float64)
    ws = np.ones_like(sub) if weight_sub is None else np.ascontiguousarray(np.reshape(weight_sub, -1), np.float64)
    out = np.empty(centre.shape, np.float64)
    resolve(np.ascontiguousarray(refine), centre, np.ascontiguousarray(rows, np.int64),
            np.ascontiguousarray(cols, np.int64), sub, ws, taps, int(flt.grid), int(m0), out)
    return out.astype(np.float32)


def resolve_pass(flt: PixelFilter, refine: np.ndarray, centre: np.ndarray, sub: np.ndarray,
                 weight_sub: Optional[np.ndarray] = None) -> np.ndarray:
    """``resolve_samples`` over every sub-sample of the supersampled image ``sub``."""
    rows, cols = np.indices(np.shape(sub)).reshape(2, -1)
    return resolve_samples(flt, refine, centre, rows, cols, sub, weight_sub)


def coverage(flt: PixelFilter, refine: np.ndarray, hit: np.ndarray, rows: np.ndarray, cols: np.ndarray,
             sub_hit: np.ndarray) -> np.ndarray:
    """Alpha: the filter-weighted fraction of the footprint that sees a surface
    (``sub_hit[n]``: sub-sample (rows[n], cols[n]) sees one)."""
    return resolve_samples(flt, refine, hit.astype(np.float64), rows, cols, sub_hit.astype(np.float64))
