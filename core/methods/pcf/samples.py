"""Figure 4's ``SampleShadow``: a region's jittered ns x nt grid of depth
map samples (``_grid``, ``_region_samples``), the fraction in shadow
(``sample_shadow``; or their light points' weight) and the mean depth of
the blockers among them (``blocker_depth``); Williams' hard test
(``hard_shadow_kernel``), which a region of size zero reduces to."""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from ...jit import inner, kernel
from ...kernels import face_project, pick_face
from ...sampling import stream_start, stream_word
from .receiver import DEPTH_REL_EPS, _receiver_form, plane_depth
from .weight import NO_WEIGHTS, sample_weight


@inner(forceinline=True)
def _grid(sres, tres, NumSamples, MinSamples):
    """Figure 4's ns x nt cells for a region of half sizes ``sres``, ``tres``
    (texels): one per texel up to ``NumSamples`` in all, at least
    ``MinSamples`` per axis."""
    if sres * tres * 4.0 < NumSamples:
        ns = int(sres * 2.0 + 0.5)
        ns = min(max(ns, MinSamples), NumSamples)
        nt = int(tres * 2.0 + 0.5)
        nt = min(max(nt, MinSamples), NumSamples)
    else:
        nt = int(math.sqrt(tres * NumSamples / sres) + 0.5)
        nt = min(max(nt, MinSamples), NumSamples)
        ns = int(NumSamples / nt + 0.5)
        ns = min(max(ns, MinSamples), NumSamples)
    return ns, nt


@inner(error_model="numpy")
def _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel, Bias0, Bias1, plane, wf):
    """The region's ns x nt grid, each cell sampled once with jitter over the
    whole cell (section 2's method (c)) from pixel ``pixel``'s stream: (the
    samples the receiver is behind by more than a bias drawn in [Bias0,
    Bias1], the sum of their map depths, and where ``wf`` (``weight``'s
    frame; ``NO_WEIGHTS``: none) weighs them, the weight of the samples not
    behind and of all). One 32-bit random word per sample
    gives the two jitters (11 bits each: 1/2048 of a cell) and the bias (10
    bits); the receiver's tangent-plane depth is compared by a
    multiplication (``_receiver_form``). Samples past the map's border read
    the border texel (the map's window is fitted to the receivers, not the
    light's field of view); outside the map's box of finite depths nothing
    is behind (3.3). One loop for ``sample_shadow`` and ``blocker_depth``."""
    ds = 2.0 * sres / ns
    dt = 2.0 * tres / nt
    s0 = s - sres
    t0 = t - tres
    h, w = depth_f.shape
    u0 = min(max(math.floor(s0), 0.0), w - 1.0) + 0.5
    u1 = min(max(math.floor(s + sres), 0.0), w - 1.0) + 0.5
    v0 = min(max(math.floor(t0), 0.0), h - 1.0) + 0.5
    v1 = min(max(math.floor(t + tres), 0.0), h - 1.0) + 0.5
    mode, a, b, c, k = _receiver_form(plane, z, u0, u1, v0, v1)
    fu = ds * (1.0 / 2048.0)
    fv = dt * (1.0 / 2048.0)
    fb = (Bias1 - Bias0) * (1.0 / 1024.0)
    bu0, bu1, bv0, bv1 = bbox_f[0], bbox_f[1], bbox_f[2], bbox_f[3]
    st = stream_start(seed, pixel)
    weigh = wf[0] != 0.0
    n = 0
    acc = 0.0
    wlit = 0.0
    wall = 0.0
    for i in range(ns):
        su = s0 + i * ds
        for j in range(nt):
            st, wd = stream_word(st)
            xs = su + np.float64(wd & np.uint32(2047)) * fu
            ys = t0 + j * dt + np.float64((wd >> np.uint32(11)) & np.uint32(2047)) * fv
            iu = int(math.floor(xs))
            iv = int(math.floor(ys))
            iu = min(max(iu, 0), w - 1)
            iv = min(max(iv, 0), h - 1)
            behind = False
            if iu >= bu0 and iu <= bu1 and iv >= bv0 and iv <= bv1:
                d = np.float64(depth_f[iv, iu])
                thr = d * DEPTH_REL_EPS + (Bias0 + np.float64(wd >> np.uint32(22)) * fb)
                if mode == 2:
                    behind = k > thr * (a * (iu + 0.5) + b * (iv + 0.5) + c)
                elif mode == 1:
                    behind = a * (iu + 0.5) + b * (iv + 0.5) + c > thr
                elif mode == 0:
                    behind = z > thr
                else:
                    behind = plane_depth(plane, iu + 0.5, iv + 0.5, z) > thr
                n += 1 if behind else 0           # no branch: in a penumbra it is a coin toss
                acc += d if behind else 0.0
            if weigh:
                wt = sample_weight(wf, xs, ys)
                wall += wt
                wlit += 0.0 if behind else wt
    return n, acc, wlit, wall


@inner
def sample_shadow(depth_f, bbox_f, s, t, z, sres, tres, NumSamples, MinSamples,
                  Bias0, Bias1, seed, pixel, plane, wf):
    """Reeves et al. figure 4 ``SampleShadow``: fraction of the region in
    shadow. ``s, t`` and ``sres, tres`` are already in texels (scaled).
    ``plane`` (from ``receiver_plane``) gives the receiver's depth at each
    sample's texel centre; ``plane[0] == 0`` keeps the paper's constant z.
    ``wf`` (``weight.weight_frame``; ``NO_WEIGHTS``: the paper's count): each
    sample weighs its light point's emission, the fraction is the weight of
    the samples in shadow over the weight of all (the count where no sample
    weighs anything)."""
    if z < 0.0:
        return 0.0
    lu = math.floor(s - sres)
    hu = math.ceil(s + sres)
    lv = math.floor(t - tres)
    hv = math.ceil(t + tres)
    if lu > bbox_f[1] or hu < bbox_f[0] or lv > bbox_f[3] or hv < bbox_f[2]:
        return 0.0
    ns, nt = _grid(sres, tres, NumSamples, MinSamples)
    inshadow, _, wlit, wall = _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel,
                                              Bias0, Bias1, plane, wf)
    if wall > 0.0:
        return 1.0 - wlit / wall
    return inshadow / (ns * nt)


@inner
def blocker_depth(depth_f, bbox_f, s, t, z, sres, tres, BlockerSamples, Bias0, Bias1, seed, pixel, plane):
    """region="light"'s blocker search (Fernando 2005): the mean map depth of
    the samples (figure 4's grid of about ``BlockerSamples`` jittered cells
    on the region) that the receiver is behind (``sample_shadow``'s test);
    0.0 when there is none."""
    ns, nt = _grid(sres, tres, BlockerSamples, np.int64(1))
    n, acc, _, _ = _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel, Bias0, Bias1, plane,
                                   NO_WEIGHTS)
    return acc / n if n else 0.0


@kernel(parallel=True)
def hard_shadow_kernel(P, faces, depth, bias, out):
    """Williams' hard test at each point: 0 where depth > map + bias, else 1;
    points outside every face are lit. Reference for the zero-region case."""
    for i in prange(P.shape[0]):
        f = pick_face(faces, P[i, 0], P[i, 1], P[i, 2])
        out[i] = 1.0
        if f < 0:
            continue
        s, t, z = face_project(faces[f], P[i, 0], P[i, 1], P[i, 2])
        if z < 0.0:
            continue
        iu = int(math.floor(s))
        iv = int(math.floor(t))
        if z > depth[f, iv, iu] + bias:
            out[i] = 0.0
