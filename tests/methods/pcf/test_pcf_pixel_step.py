"""pcf's ``pixel_step``: anchors keep the every-pixel V, the pixels between
them share it ("copy") or blend it ("interpolate") on their anchors'
surface only, in levels; on a packed G-buffer's sub-pixel receivers; and
the filter's chunks stop when the job is cancelled."""
import dataclasses

import numba
import numpy as np
import pytest

from penumbra.core import cancel
from penumbra.core.cancel import CancelToken, Cancelled
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.methods.pcf import PCFParams, pixels
from penumbra.core.methods.pcf.anchors import PIXEL_STEP_SLOPE, auto_pixel_step, step_levels
from penumbra.core.pixel_filter import PixelFilter

from helpers import buffers_of, embree_pass, rmse, run_method
from synthetic import area_light, box, half_plane_scene, make_scene, persp_camera, quad


def run_pcf(scene, **over):
    """pcf's result for the scene's first light, with its buffers: the
    average pass (equation 2, as the reference below) unless ``visibility``
    is given."""
    fb = buffers_of(scene)
    over.setdefault("visibility", "average")
    return run_method("pcf", fb, scene.lights[0], **over), fb


def _ground_and_box():
    """A box on a large ground under an area light, seen in perspective:
    silhouettes, two objects and a soft shadow."""
    tris = quad(-10, 10, -10, 10, 0.0) + box(-0.7, 0.45, -0.3, 0.8, 0.0, 1.2)
    return make_scene(tris, [0, 0] + [1] * 12, [area_light(1.5, z=4.0)], res=62,
                      camera=persp_camera((0.5, -4.0, 3.5), (0.0, 0.0, 0.3)), names=("ground", "box"))


def test_pixel_step_copy_shares_a_blocks_first_pixel_on_one_surface_only():
    """pixel_step=2, step_fill="copy" (the Preview's): the first pixel of each 2 x 2 block has
    the full pass's V (the same bits: its own stream); another pixel of the
    block on the same object with a near normal has that V, one on another
    object (or whose block starts on empty sky) its own full-pass V. A step
    that does not divide the tile is an error."""
    scene = _ground_and_box()
    full, fb = run_pcf(scene, pixel_step=1)
    step, _ = run_pcf(scene, pixel_step=2, step_fill="copy")
    a, b = full.passes["pcf"], step.passes["pcf"]
    g = fb.gbuffer
    np.testing.assert_array_equal(b[::2, ::2], a[::2, ::2])
    rows, cols = np.nonzero(g.hit)
    r0, c0 = rows - rows % 2, cols - cols % 2
    shared = g.hit[r0, c0] & (g.object_id[rows, cols] == g.object_id[r0, c0]) & (
        np.sum(g.normal[rows, cols] * g.normal[r0, c0], axis=1) >= 0.95)
    np.testing.assert_array_equal(b[rows[shared], cols[shared]], a[r0[shared], c0[shared]])
    np.testing.assert_array_equal(b[rows[~shared], cols[~shared]], a[rows[~shared], cols[~shared]])
    assert (~shared).sum() > 20 and ((rows % 2 + cols % 2) > 0)[shared].sum() > 1000
    assert ((a > 0.0) & (a < 1.0)).sum() > 200            # a shadow with a penumbra
    with pytest.raises(ValueError, match="pixel_step"):
        run_pcf(scene, pixel_step=3)


def _anchor_blend(a, g, step, tol, slope):
    """NumPy's account of step_fill="interpolate" over the pixel-centre pass
    ``a`` (every pixel filtered): per pixel, whether its anchors (the
    non-zero bilinear weights at ``step`` spacing) on its surface are at
    least 2 holding at least half the weight and span at most ``tol``, and
    their renormalised blend."""
    H, W = a.shape
    r, c = np.mgrid[0:H, 0:W]
    r0, c0 = r - r % step, c - c % step
    fr, fc = (r - r0) / step, (c - c0) / step
    r1, c1 = np.where(r > r0, r0 + step, r0), np.where(c > c0, c0 + step, c0)
    ok = g.hit & ((r % step + c % step) > 0) & (r1 < H) & (c1 < W)
    r1, c1 = np.minimum(r1, H - 1), np.minimum(c1, W - 1)
    lo, hi, blend = np.full(a.shape, np.inf), np.full(a.shape, -np.inf), np.zeros(a.shape)
    wsum, count = np.zeros(a.shape), np.zeros(a.shape, int)
    for rr, cc, wgt in ((r0, c0, (1 - fr) * (1 - fc)), (r0, c1, (1 - fr) * fc),
                        (r1, c0, fr * (1 - fc)), (r1, c1, fr * fc)):
        d = g.position - g.position[rr, cc]
        off = np.abs(np.sum(d * g.normal[rr, cc], axis=-1))
        same = (g.hit[rr, cc] & (g.object_id == g.object_id[rr, cc])
                & (np.sum(g.normal * g.normal[rr, cc], axis=-1) >= 0.95)
                & (off <= slope * np.linalg.norm(d, axis=-1)))
        used = (wgt > 0) & same
        v = a[rr, cc].astype(np.float64)
        lo = np.where(used, np.minimum(lo, v), lo)
        hi = np.where(used, np.maximum(hi, v), hi)
        blend += np.where(used, wgt * v, 0.0)
        wsum += np.where(used, wgt, 0.0)
        count += used
    ok &= (count >= 2) & (wsum >= 0.5)
    blend = blend / np.where(ok, wsum, 1.0)
    ok &= (hi - lo <= tol) & ((hi == lo) | ((lo > 0.0) & (hi < 1.0)))
    return ok, blend, ok & (wsum < 1.0 - 1e-9)


def _levels_blend(a, g, step, tol, slope):
    """NumPy's account of the levels (``step_levels``): the anchors (row
    and column multiples of ``step``) keep ``a``; then for s = step / 2,
    ..., 1 the pixels of the s-lattice off the 2s-lattice take the blend of
    their 2s-lattice anchors in the image so far where ``_anchor_blend``
    allows, else their own ``a``. Returns (the image, interpolated mask,
    mask of those blended from part of their anchors: beside a silhouette)."""
    H, W = a.shape
    r, c = np.mgrid[0:H, 0:W]
    img = a.astype(np.float64).copy()
    interp = np.zeros(a.shape, bool)
    part = np.zeros(a.shape, bool)
    s = step // 2
    while s >= 1:
        level = (r % s == 0) & (c % s == 0) & ~((r % (2 * s) == 0) & (c % (2 * s) == 0))
        ok, blend, some = _anchor_blend(img, g, 2 * s, tol, slope)
        take = level & ok
        img[take] = blend[take]
        interp |= take
        part |= level & some
        s //= 2
    return img, interp, part


def test_pixel_step_interpolates_between_anchors_on_their_surface_only():
    """The render's default: step_fill="interpolate", pixel_step 0:
    2, and 4 from 1280 pixels across (``auto_pixel_step``), in levels
    (``step_levels``: 4, 2, 1). Anchors (row and column multiples of 4)
    keep the every-pixel pass's V bit for bit; a pixel of a finer level
    whose anchors on the coarser one lie on its surface (object, normal,
    tangent plane; at least 2 holding half the weight, renormalised) and
    span at most step_tolerance is their bilinear blend; every other pixel
    (an object's silhouette, a shadow edge sharper than the tolerance) has
    its own every-pixel V. pixel_step=2 is the one level of the same rule.
    The interpolated pass is no further from embree's than the every-pixel
    one."""
    scene = _ground_and_box()
    full, fb = run_pcf(scene, pixel_step=1)
    step, _ = run_pcf(scene, pixel_step=4)
    two, _ = run_pcf(scene)
    assert PCFParams().pixel_step == 0 and PCFParams().step_fill == "interpolate"
    assert auto_pixel_step(62, 62) == 2 and auto_pixel_step(1279, 719) == 2
    assert auto_pixel_step(1280, 720) == 4 and auto_pixel_step(1920, 1080) == 4
    assert step_levels(4, True) == [4, 2, 1] and step_levels(4, False) == [0] and step_levels(1, True) == [0]
    a, b = full.passes["pcf"], step.passes["pcf"]
    g = fb.gbuffer
    np.testing.assert_array_equal(b[::4, ::4], a[::4, ::4])
    tol = PCFParams().step_tolerance
    for got, st in ((b, 4), (two.passes["pcf"], 2)):
        want, interp, _ = _levels_blend(a, g, st, tol, PIXEL_STEP_SLOPE)
        np.testing.assert_allclose(got[interp], want[interp], atol=1e-6)
        np.testing.assert_array_equal(got[~interp], a[~interp])
    want, interp, part = _levels_blend(a, g, 4, tol, PIXEL_STEP_SLOPE)
    rr, cc = np.mgrid[0:62, 0:62]
    coarse = (rr % 2 == 0) & (cc % 2 == 0) & ~((rr % 4 == 0) & (cc % 4 == 0))
    assert interp.sum() > 1500 and (interp & coarse).sum() > 200       # both levels blend
    assert part.sum() > 10                 # beside the box's silhouette: the anchors on the pixel's side
    assert ((~interp) & g.hit & (((rr % 4) + (cc % 4)) > 0)).sum() > 20
    # a shadow edge the tolerance keeps: pixels between anchors whose V differs by more than it
    edge = g.hit & ~interp & (a > 0.0) & (a < 1.0)
    assert edge.sum() > 10
    ref = embree_pass(fb, scene.lights[0], samples=1024)
    m = g.hit
    assert rmse(b[m], ref[m]) <= rmse(a[m], ref[m]) + 0.002
    with pytest.raises(ValueError, match="step_fill"):
        run_pcf(scene, step_fill="nearest")


def _box_over_ground(res):
    """A box over a lit ground under an area light, seen from above at an
    angle: silhouettes, a crease and a soft shadow."""
    tris = quad(-3, 3, -3, 3, 0.0) + box(-0.5, 0.5, -0.5, 0.5, 0.4, 0.9)
    return make_scene(tris, [0, 0] + [1] * 12, [area_light(1.5, z=3.0)], res=res,
                      camera=persp_camera((2.0, -2.5, 3.0), (0.0, 0.0, 0.3)))


def test_pixel_step_on_sub_pixel_receivers():
    """pcf's ``pixel_step`` on the packed sub-pixel receivers: the Preview's
    ``step_fill="copy"`` does not touch them (with every pixel refined,
    threshold < 0, the filtered pass comes from them alone and is the same
    bits as with pixel_step 1: a packed list's neighbouring entry is not its
    pixel's block); the render's "interpolate" blends between sub-pixel
    anchors on one surface, and adds at most the pixel filter's 0.005 RMSE
    to the error of the pass that runs every receiver, both against that
    pass converged (1024 region samples)."""
    sc = _box_over_ground(24)
    flt = dataclasses.replace(PixelFilter("blackman-harris", 1.5), threshold=-1.0)
    one = render_filtered(sc, ["pcf"], pixel_filter=flt, method_overrides={"pcf": {"pixel_step": 1}})
    copy = render_filtered(sc, ["pcf"], pixel_filter=flt, method_overrides={"pcf": {"step_fill": "copy"}})
    blend = render_filtered(sc, ["pcf"], pixel_filter=flt)
    converged = render_filtered(sc, ["pcf"], pixel_filter=flt, method_overrides={
        "pcf": {"pixel_step": 1, "BlockerSamples": 256, "PenumbraSamples": 1024}})
    a, b, c, t = (r.lights[0].passes["pcf"] for r in (one, copy, blend, converged))
    assert ((a > 0.05) & (a < 0.95)).sum() > 20              # a penumbra to get wrong
    np.testing.assert_array_equal(a, b)
    cov = blend.coverage > 0
    assert not np.array_equal(a, c)
    assert rmse(c, t, cov) <= rmse(a, t, cov) + 0.005


def test_filter_stops_between_chunks(monkeypatch):
    """The job's cancel token is checked between the filter's chunks
    (``kernels.each_dealt_chunk``): a token cancelled during the first
    chunks stops the frame before the rest run."""
    calls = []
    kernel = pixels.pcf_kernel
    token = CancelToken()

    def counting(*args):
        calls.append(len(args[0]))
        kernel(*args)
        if armed:
            token.cancel()                            # cancel after the first chunk

    monkeypatch.setattr(pixels, "pcf_kernel", counting)
    monkeypatch.setattr(pixels, "PIXEL_TILE", 4)         # 36 tiles of 4 x 4 pixels
    scene = half_plane_scene(area_light(1.0), res=24)
    armed = False
    render_frame(scene, ["pcf"])                      # compiles (the warm-up runs pcf too)
    calls.clear()
    render_frame(scene, ["pcf"])                      # every chunk runs
    chunks = len(calls)
    threads = numba.get_num_threads()
    # kernels.each_dealt_chunk: 8 per thread, once per level of pixel_step (its anchors, then each finer lattice)
    levels = len(step_levels(auto_pixel_step(24, 24), True))
    assert levels == 2 and chunks == levels * min(36, 8 * threads) and sum(calls) == levels * 36
    calls.clear()
    armed = True
    with cancel.watching(token), pytest.raises(Cancelled):
        render_frame(half_plane_scene(area_light(1.0), res=24), ["pcf"])
    assert 1 <= len(calls) <= threads < chunks        # those already running when it cancelled
