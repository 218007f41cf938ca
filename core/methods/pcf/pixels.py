"""The per-pixel filter: ``pcf_kernel`` (each camera pixel's region, tile
test, blocker search and samples: ``_pcf_pixel``), its argument groups, and
``filter_pixels``, which runs it over tiles of pixels on worker threads."""
from __future__ import annotations

from collections import namedtuple

from ...jit import inner, kernel
from ...kernels import borrowed, each_dealt_chunk, face_project, pick_face
from .anchors import _interpolated, _same_surface, step_levels
from .footprint import pixel_footprint
from .light_region import SEARCH_STEPS, light_halfwidth, search_region
from .receiver import NO_PLANE, receiver_plane
from .samples import blocker_depth, sample_shadow
from .tiles import region_decided
from .weight import NO_WEIGHTS, weight_frame

PIXEL_TILE = 32      # camera pixels per side of a tile of ``pcf_kernel`` (``filter_pixels``)
PIXEL_BLOCK = 1024   # entries of a packed G-buffer dealt together to a chunk of ``pcf_kernel``

# argument groups of ``pcf_kernel``
CameraPixels = namedtuple("CameraPixels", "P Nrm hit obj width rays pixel")
"""G-buffer positions, normals, hit flags and object ids (row-major, ``width`` wide), the
camera's per-pixel ray terms (``pixel_ray_terms``) and, for a packed G-buffer
(``GBuffer.pixel``), each entry's camera pixel (int64[N]; empty: entry i is
pixel i)."""
ShadowMap = namedtuple("ShadowMap", "faces depth bbox tiles planes lsize zmin lframe")
"""Packed light-view faces, their depth maps, finite-depth boxes, the
per-tile depth min / max as sparse tables (``tile_tables``) and planes
(``tile_planes``), per face the light's reach
(``light_reach``: float64[F, 3]), nearest depth (float64[F]) and the
light in its view (``weight.light_frames``)."""
Filter = namedtuple("Filter", "ResFactor MinSize MaxSize NumSamples MinSamples Bias0 Bias1 seed use_plane use_tiles "
                              "light_region BlockerSamples PenumbraSamples pixel_step interpolate step_tolerance "
                              "irradiance")
"""The filter's parameters (the paper's names), ``receiver_plane``, ``tiles``
and ``region="light"``'s switch and sample counts, ``pixel_step``, whether
its other pixels are interpolated (``step_fill``), ``step_tolerance`` and
whether region="light"'s samples weigh their light points
(``visibility="irradiance"``)."""


def filter_pixels(cam, smap, flt, out, height, threads=None) -> None:
    """V into ``out`` for every camera pixel (``pcf_kernel``) on Numba's
    thread count, the job's cancel token checked before each chunk
    (``kernels.each_dealt_chunk``): a dense G-buffer (``height`` rows of
    ``cam.width``) in tiles of PIXEL_TILE x PIXEL_TILE pixels, whose regions
    lie close together in the map (a long row of pixels sweeps the whole
    map: samples then miss the cache), dealt over the chunks (sky and ground
    differ widely in cost); a packed one in blocks of PIXEL_BLOCK entries.
    step_fill="interpolate": one pass per level of ``step_levels``."""
    packed = cam.pixel.shape[0] > 0
    tile = 0 if packed else PIXEL_TILE
    n = out.shape[0] if packed else -(-cam.width // PIXEL_TILE) * -(-height // PIXEL_TILE)
    block = PIXEL_BLOCK if packed else 1
    for stage in step_levels(flt.pixel_step, flt.interpolate):
        each_dealt_chunk(lambda idx: pcf_kernel(idx, tile, height, stage, cam, smap, flt, out), n, threads,
                         block=block)


@kernel(nogil=True, error_model="numpy")
def pcf_kernel(idx, tile, height, stage, cam, smap, flt, out):
    """V into out[i] for every camera pixel i (row-major, ``cam.width`` wide)
    in the tiles ``idx`` of ``tile`` x ``tile`` pixels (row-major over the
    ``height``-row image), or, with ``tile`` 0, every entry i in ``idx`` (a
    packed G-buffer: entry i is pixel ``cam.pixel[i]``), where
    ``cam.hit[i]``; other pixels are left as they are. ``stage`` (a dense
    G-buffer, pixel_step > 1, step_fill="interpolate"; ``step_levels``):
    a spacing s; s = pixel_step filters the anchors (row and column
    multiples of s); a smaller s does the pixels of the s-lattice that are
    not on the 2s-lattice (every 2s-lattice pixel is done by then): the
    blend of their 2s-lattice anchors (``_interpolated``) where it can, else
    filtered. 0: every pixel (step_fill="copy": the block's first pixel,
    done before the others of its tile, is shared). A serial ``nogil``
    kernel with ``kernels.borrowed`` arguments (no parfor to compile), run
    on worker threads by ``filter_pixels``; each pixel's V
    depends on its own stream and its anchors only, so the result does not
    depend on the order, the chunks or the thread count. cam: CameraPixels;
    smap: ShadowMap; flt: Filter."""
    cam, smap, flt, out = borrowed((cam, smap, flt, out))
    W = cam.width
    tw = (W + tile - 1) // tile if tile else 1
    step = flt.pixel_step if tile or flt.interpolate else 1
    for k in idx:
        if tile:
            ra, ca = (k // tw) * tile, (k % tw) * tile
            rb, cb = min(ra + tile, height), min(ca + tile, W)
        else:                         # a packed entry: one "row" of one
            ra, rb, ca, cb = 0, 1, k, k + 1
        for r in range(ra, rb):
            for c in range(ca, cb):
                i = r * W + c if tile else c
                if step > 1 and cam.hit[i]:
                    pr, pc = (r, c) if tile else (cam.pixel[i] // W, cam.pixel[i] % W)   # its view pixel
                    if stage == 0:
                        if pr % step or pc % step:
                            j = (r - r % step) * W + (c - c % step)     # the block's first pixel: done before
                            if _same_surface(cam, i, j):
                                out[i] = out[j]
                                continue
                    elif pr % stage or pc % stage:
                        continue                  # a finer level's pixel
                    elif stage < step:
                        up = 2 * stage            # this level's anchors: the coarser lattice, done before
                        if (pr % up == 0 and pc % up == 0) or _interpolated(cam, out, i, pr, pc, up, height,
                                                                           flt.step_tolerance):
                            continue
                _pcf_pixel(i, cam, smap, flt, out)     # inlined by LLVM


@inner(forceinline=True)
def _pcf_pixel(i, cam, smap, flt, out):
    """``pcf_kernel``'s body for pixel i, inlined (a call per pixel is a
    large share of the filter's cost). It and its helpers are inlined by
    LLVM (``forceinline``): Numba types each once, where ``inline="always"``
    would re-type its body at every call site."""
    P, Nrm, hit, width, rays = cam.P, cam.Nrm, cam.hit, cam.width, cam.rays
    faces, depth, bbox, tiles = smap.faces, smap.depth, smap.bbox, smap.tiles
    ResFactor, MinSize, MaxSize, NumSamples = flt.ResFactor, flt.MinSize, flt.MaxSize, flt.NumSamples
    MinSamples, Bias0, Bias1, seed = flt.MinSamples, flt.Bias0, flt.Bias1, flt.seed
    use_plane, use_tiles = flt.use_plane, flt.use_tiles
    if not hit[i]:
        return
    j = cam.pixel[i] if cam.pixel.shape[0] else i    # the camera pixel: footprint and seed
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    f = pick_face(faces, px, py, pz)
    if f < 0:
        out[i] = 1.0
        return
    s, t, z = face_project(faces[f], px, py, pz)
    if ResFactor > 0.0:
        hs, ht = pixel_footprint(rays, faces[f], float(j % width), float(j // width), px, py, pz,
                                 Nrm[i, 0], Nrm[i, 1], Nrm[i, 2], s, t, MaxSize)
    else:
        hs, ht = 0.0, 0.0
    sres = max(hs * ResFactor, MinSize)
    tres = max(ht * ResFactor, MinSize)
    sres = min(sres, MaxSize)
    tres = min(tres, MaxSize)
    if use_plane:
        plane = receiver_plane(faces[f], px, py, pz, Nrm[i, 0], Nrm[i, 1], Nrm[i, 2])
    else:
        plane = NO_PLANE
    lsize = smap.lsize[f]
    wf = NO_WEIGHTS                   # region="light" under visibility="irradiance": ``weight``
    light = flt.light_region and z > 0.0 and (lsize[0] > 0.0 or lsize[1] > 0.0)
    if light:
        # the blocker search region (PCSS): the light's reach at the nearest depth it can hold
        ws, wt = search_region(tiles[f], depth.shape[2], depth.shape[1], s, t, z, lsize, smap.zmin[f],
                               sres, tres, MaxSize, SEARCH_STEPS)
    else:
        ws, wt = sres, tres
    if use_tiles and z >= 0.0:
        known = region_decided(tiles[f], smap.planes[f], faces[f, 16] == 1.0, depth.shape[2],
                               depth.shape[1], s, t, z, ws, wt, plane, Bias0, Bias1)
        if known >= 0.0:
            out[i] = 1.0 - known
            return
    if light:
        zb = blocker_depth(depth[f], bbox[f], s, t, z, ws, wt, flt.BlockerSamples, Bias0, Bias1,
                           seed + 1, j, plane)
        if not (zb > 0.0):
            out[i] = 1.0
            return
        ps, pt = light_halfwidth(lsize, z, zb)
        sres = min(max(ps, sres), MaxSize)
        tres = min(max(pt, tres), MaxSize)
        ku = ps / sres if sres > 0.0 else 0.0      # the light's extent over the region's (its weights)
        kv = pt / tres if tres > 0.0 else 0.0
        NumSamples = flt.PenumbraSamples
        if use_tiles:     # the filter region's own tile test (exact, as the search region's)
            known = region_decided(tiles[f], smap.planes[f], faces[f, 16] == 1.0, depth.shape[2],
                                   depth.shape[1], s, t, z, sres, tres, plane, Bias0, Bias1)
            if known >= 0.0:
                out[i] = 1.0 - known
                return
        if flt.irradiance:
            wf = weight_frame(faces[f], smap.lframe[f], zb, px, py, pz, s, t, sres, tres, ku, kv)
    out[i] = 1.0 - sample_shadow(depth[f], bbox[f], s, t, z, sres, tres, NumSamples,
                                 MinSamples, Bias0, Bias1, seed, j, plane, wf)
