"""Coherence-based sampling of the light (Agrawala et al. 2000, section 5.2).

Per surface point p_i the light's unit square is split into the same nx x ny
strata as the reference (``sampling.strata``), one jittered sample per cell,
drawn with the reference's counter hash (seed, pixel, stratum), so with
coherence off the method shoots exactly the reference's rays.

SoftShad (the paper's pseudocode), per tile of the image, points in a
serpentine scan order:

  Predict: every point of the blocker points list is projected through p_i
  onto the light (area: its plane; sphere: the disk through the centre facing
  p_i; sun: the cone of directions) and mapped back to unit-square
  coordinates (the inverse of ``sampling.light_sample``). A point that lands
  outside the light (or is not between p_i and the light) is removed (5.2.2).
  A cell hit by a projected blocker is predicted blocked. Each cell keeps a
  ``subgrid`` x ``subgrid`` grid and at most one blocker per sub-cell (the
  newest); the list is therefore bounded by subgrid^2 x cells. Cells on the
  light's border and cells whose prediction differs from one of their 8
  neighbours go to cellsToDo; the others to cellsUsePrev. With the sub-grid
  shortcut, a cell whose own jittered sample falls in a sub-cell holding a
  blocker goes straight to cellsDone as blocked. (The per-point part of the
  projection - the light's frame seen from p_i - is computed once per point,
  ``light_frame``, and the kept blockers are compacted in place.)
  Trace: cells are dequeued and traced; a result that differs from the
  prediction moves the cell's 8 neighbours still in cellsUsePrev to cellsToDo
  (8-connected flood fill of the prediction errors).
  Shade: V (eq. 2) = unblocked cells / cells; V_irr (eq. 1 ratio) weights each
  cell by the reference's cos cos / d^2.

A cell whose ray leaves p_i into the surface p_i lies on (cos theta_r <= 0
with the camera-facing normal) is blocked by that surface: it is set without
tracing (and not counted as a traced ray). The depth images cannot answer
for it - p_i's own surface is seen edge-on or from behind from the light - and
a ray tracer's answer is "blocked" there.

Without information - the first point of a tile, a point farther than the
reset tolerance from the previous one (5.2.1) - every cell is traced and the
blocker list restarts. (The paper's "if the BlockerPtsList is empty, we put
all of the light source cells in the cellsToDo list" is read as this: an
empty list *after* a prediction means "nothing blocks", for which 5.2.1 says
only the edge cells are traced.)

The state of one tile lives in a few arrays (``TileState``); ``begin_point``
/ ``absorb`` / ``finish_point`` are shared by the depth-image driver (one
Numba loop per tile) and by the Embree wave driver, which batches the queued
rays of every tile into one Embree call per wave. The set of traced cells
does not depend on the order the queue is drained in, so both give the same
sampling of a tile for the same ray results.
"""
from __future__ import annotations

import math
from collections import namedtuple

from ...jit import inner
from ...sampling import offset_origin, orthonormal_basis, reference_sample

USEPREV, QUEUED, DONE = 0, 1, 2

# misc slots
M_NBLK, M_QH, M_QT, M_GEN, M_HAVEPREV, M_RAYS = 0, 1, 2, 3, 4, 5
# sampler statistics: points traced in full (no prediction), their rays,
# cells queued by Predict (edges + border), cells added by the flood fill,
# prediction errors (traced verdict != prediction), blocker points projected
M_FULL, M_FULLRAYS, M_SEEDED, M_FLOOD, M_ERR, M_BLK = 6, 7, 8, 9, 10, 11
M_SIZE = 16

# argument groups (built by the package's ``__init__``)
Points = namedtuple("Points", "P Nrm pix tol")
"""The shaded points in coherent order: positions, camera-facing normals,
pixel ids and reset tolerances (5.2.1)."""
Sampler = namedtuple("Sampler", "lp seed scale nx ny S coherent shortcut big")
"""The sampling: packed light, seed, scene scale, ``nx x ny`` light cells,
``S x S`` sub-cells per cell, coherence and sub-grid shortcut switches, and
the length of a ray towards a direction (sun)."""
TileState = namedtuple("TileState", "origin tgt wts subi back blk stamp vis cst queue pred prevp misc")
"""One tile's state: ray origin, ray end / weight / sub-cell / back-facing
flag per cell, blocker list and its sub-cell stamps, visibility, cell state
(USEPREV / QUEUED / DONE), queue, prediction, previous point, ``misc`` (M_*)."""


@inner(forceinline=True)
def tile_row(ts, ti):
    """Tile ``ti``'s TileState from one whose arrays hold every tile (first axis)."""
    return TileState(ts.origin[ti], ts.tgt[ti], ts.wts[ti], ts.subi[ti], ts.back[ti], ts.blk[ti],
                     ts.stamp[ti], ts.vis[ti], ts.cst[ti], ts.queue[ti], ts.pred[ti], ts.prevp[ti],
                     ts.misc[ti])


@inner(forceinline=True)
def inv_concentric(x, y):
    """Inverse of ``sampling.concentric_disk``: unit disk -> [0,1)^2."""
    r = math.sqrt(x * x + y * y)
    if r == 0.0:
        return 0.5, 0.5
    phi = math.atan2(y, x)
    q = math.pi / 4.0
    if phi < -q:
        phi += 2.0 * math.pi
    if phi < q:
        a = r
        b = phi * a / q
    elif phi < 3.0 * q:
        b = r
        a = -(phi - 2.0 * q) * b / q
    elif phi < 5.0 * q:
        a = -r
        b = (phi - 4.0 * q) * a / q
    else:
        b = -r
        a = -(phi - 6.0 * q) * b / q
    return 0.5 * (a + 1.0), 0.5 * (b + 1.0)


@inner(forceinline=True)
def light_frame(lp, px, py, pz):
    """The per-point part of the projection onto a planar light (area: its
    plane; sphere: the disk through the centre facing p), computed once per
    surface point instead of once per blocker point: (ok, n, e1, e2, half
    sizes, (c - p).n, centre, square?) as a flat tuple. Not for a sun."""
    cx, cy, cz = lp[1], lp[2], lp[3]
    kind = lp[0]
    if kind == 0.0:
        nx_, ny_, nz_ = lp[10], lp[11], lp[12]
        e1x, e1y, e1z = lp[4], lp[5], lp[6]
        e2x, e2y, e2z = lp[7], lp[8], lp[9]
        hx, hy = lp[13], lp[14]
        square = lp[15] != 1.0
    else:
        square = False
        wx, wy, wz = cx - px, cy - py, cz - pz
        wl = math.sqrt(wx * wx + wy * wy + wz * wz)
        if wl == 0.0 or lp[16] == 0.0:
            return (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False)
        nx_, ny_, nz_ = wx / wl, wy / wl, wz / wl
        b1, b2 = orthonormal_basis(nx_, ny_, nz_)
        e1x, e1y, e1z = b1[0], b1[1], b1[2]
        e2x, e2y, e2z = b2[0], b2[1], b2[2]
        hx, hy = lp[16], lp[16]
    ok = hx > 0.0 and hy > 0.0
    num = (cx - px) * nx_ + (cy - py) * ny_ + (cz - pz) * nz_
    return (ok, nx_, ny_, nz_, e1x, e1y, e1z, e2x, e2y, e2z, hx, hy, num, cx, cy, cz, square)


@inner(forceinline=True)
def project_planar(fr, px, py, pz, bx, by, bz):
    """Blocker point b seen from p -> (inside, u, v), ``fr`` = light_frame(p)."""
    if not fr[0]:
        return False, 0.0, 0.0
    dx, dy, dz = bx - px, by - py, bz - pz
    den = dx * fr[1] + dy * fr[2] + dz * fr[3]
    if den == 0.0:
        return False, 0.0, 0.0
    s = fr[12] / den
    if not (s >= 1.0):          # the blocker is not between p and the light
        return False, 0.0, 0.0
    qx = px + s * dx - fr[13]
    qy = py + s * dy - fr[14]
    qz = pz + s * dz - fr[15]
    X = (qx * fr[4] + qy * fr[5] + qz * fr[6]) / fr[10]
    Y = (qx * fr[7] + qy * fr[8] + qz * fr[9]) / fr[11]
    if fr[16]:
        if abs(X) > 1.0 or abs(Y) > 1.0:
            return False, 0.0, 0.0
        return True, 0.5 * (X + 1.0), 0.5 * (Y + 1.0)
    if X * X + Y * Y > 1.0:
        return False, 0.0, 0.0
    u, v = inv_concentric(X, Y)
    return True, u, v


@inner(forceinline=True)
def project_sun(lp, px, py, pz, bx, by, bz):
    """Sun: the direction p -> b inside the cone -> (inside, u, v)."""
    dx, dy, dz = bx - px, by - py, bz - pz
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d == 0.0:
        return False, 0.0, 0.0
    dx /= d
    dy /= d
    dz /= d
    cos_t = dx * lp[10] + dy * lp[11] + dz * lp[12]
    omc = 1.0 - cos_t
    span = 1.0 - lp[17]
    if span <= 0.0:
        return False, 0.0, 0.0
    r2 = omc / span
    if r2 > 1.0 or cos_t <= 0.0:
        return False, 0.0, 0.0
    sin_t = math.sqrt(max(0.0, omc * (2.0 - omc)))
    sx = dx * lp[4] + dy * lp[5] + dz * lp[6]
    sy = dx * lp[7] + dy * lp[8] + dz * lp[9]
    if sin_t > 0.0:
        rr = math.sqrt(r2)
        X, Y = sx / sin_t * rr, sy / sin_t * rr
    else:
        X, Y = 0.0, 0.0
    u, v = inv_concentric(X, Y)
    return True, u, v


@inner
def project_to_light(lp, px, py, pz, bx, by, bz):
    """Blocker point b seen from p -> (inside, u, v) on the light's unit square."""
    if lp[0] == 2.0:
        return project_sun(lp, px, py, pz, bx, by, bz)
    return project_planar(light_frame(lp, px, py, pz), px, py, pz, bx, by, bz)


@inner(forceinline=True)
def _cell_of(u, v, nx, ny, S):
    fu = u * nx
    fv = v * ny
    cu = min(max(int(math.floor(fu)), 0), nx - 1)
    cv = min(max(int(math.floor(fv)), 0), ny - 1)
    su = min(max(int(math.floor((fu - cu) * S)), 0), S - 1)
    sv = min(max(int(math.floor((fv - cv) * S)), 0), S - 1)
    return cv * nx + cu, sv * S + su


@inner
def begin_point(smp, pts, i, noff, ts):
    """Samples for point i (rays start at the offset origin moved a further
    ``noff`` along the normal), then Predict (or a full trace without
    information). Fills ``origin``, ``tgt`` (ray end per cell), ``wts``,
    ``vis`` (prediction), ``cst`` and the queue of ``ts``.
    smp: Sampler; pts: Points; ts: TileState."""
    lp, seed, scale, nx, ny, S = smp.lp, smp.seed, smp.scale, smp.nx, smp.ny, smp.S
    coherent, shortcut, big = smp.coherent, smp.shortcut, smp.big
    P, Nrm, pix, tol = pts.P, pts.Nrm, pts.pix, pts.tol[i]
    origin, tgt, wts, subi, back, blk = ts.origin, ts.tgt, ts.wts, ts.subi, ts.back, ts.blk
    stamp, vis, cst, queue, pred, prevp, misc = ts.stamp, ts.vis, ts.cst, ts.queue, ts.pred, ts.prevp, ts.misc
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
    ox, oy, oz = offset_origin(px, py, pz, n0, n1, n2, scale)
    ox += noff * n0
    oy += noff * n1
    oz += noff * n2
    origin[0] = ox
    origin[1] = oy
    origin[2] = oz
    C = nx * ny
    for s in range(C):
        u, v, x, y, z, is_dir, dx, dy, dz, dist, wt = reference_sample(
            lp, seed, pix[i], s, nx, ny, px, py, pz, ox, oy, oz, n0, n1, n2)
        if is_dir:
            tgt[s, 0] = ox + dx * big
            tgt[s, 1] = oy + dy * big
            tgt[s, 2] = oz + dz * big
        else:
            tgt[s, 0] = x
            tgt[s, 1] = y
            tgt[s, 2] = z
        cos_r = dx * n0 + dy * n1 + dz * n2
        back[s] = 1 if cos_r <= 0.0 else 0
        if cos_r < 0.0:
            cos_r = 0.0
        wts[s] = wt * cos_r
        _c, sub = _cell_of(u, v, nx, ny, S)
        subi[s] = sub
    misc[M_QH] = 0
    misc[M_QT] = 0
    use_pred = False
    if coherent and misc[M_HAVEPREV] == 1:
        d2 = (px - prevp[0]) ** 2 + (py - prevp[1]) ** 2 + (pz - prevp[2]) ** 2
        use_pred = d2 <= tol * tol
    if not use_pred:
        misc[M_NBLK] = 0
        qt = 0
        for s in range(C):
            if back[s] == 1:
                vis[s] = 1
                cst[s] = DONE
            else:
                vis[s] = 0
                cst[s] = QUEUED
                queue[qt] = s
                qt += 1
        misc[M_QT] = qt
        misc[M_FULL] += 1
        misc[M_FULLRAYS] += qt
        return
    # Predict: project and prune the blocker list (newest first), one per sub-cell
    misc[M_BLK] += misc[M_NBLK]
    gen = misc[M_GEN] + 1
    misc[M_GEN] = gen
    for s in range(C):
        pred[s] = 0
        cst[s] = USEPREV
    S2 = S * S
    sun = lp[0] == 2.0
    fr = light_frame(lp, px, py, pz)
    n = misc[M_NBLK]
    w = n                          # kept points are compacted in place towards the end
    for j in range(n - 1, -1, -1):
        bx, by, bz = blk[j, 0], blk[j, 1], blk[j, 2]
        if sun:
            ok, u, v = project_sun(lp, px, py, pz, bx, by, bz)
        else:
            ok, u, v = project_planar(fr, px, py, pz, bx, by, bz)
        if not ok:
            continue
        c, sub = _cell_of(u, v, nx, ny, S)
        slot = c * S2 + sub
        if stamp[slot] == gen:
            continue
        stamp[slot] = gen
        w -= 1                     # w >= j: never overwrites an unread point
        blk[w, 0] = bx
        blk[w, 1] = by
        blk[w, 2] = bz
        pred[c] = 1
        if shortcut and sub == subi[c]:
            cst[c] = DONE
    m = n - w
    if w > 0:
        for j in range(m):         # oldest-first at the front again
            blk[j, 0] = blk[w + j, 0]
            blk[j, 1] = blk[w + j, 1]
            blk[j, 2] = blk[w + j, 2]
    misc[M_NBLK] = m
    for s in range(C):
        if back[s] == 1:
            pred[s] = 1
            cst[s] = DONE
    qt = 0
    for s in range(C):
        vis[s] = pred[s]
        if cst[s] == DONE:
            continue
        cu = s % nx
        cv = s // nx
        todo = cu == 0 or cv == 0 or cu == nx - 1 or cv == ny - 1
        if not todo:
            p0 = pred[s]
            for dv in range(-1, 2):
                for du in range(-1, 2):
                    if pred[(cv + dv) * nx + cu + du] != p0:
                        todo = True
        if todo:
            cst[s] = QUEUED
            queue[qt] = s
            qt += 1
    misc[M_QT] = qt
    misc[M_SEEDED] += qt


@inner(forceinline=True)
def absorb(c, blocked, bx, by, bz, nx, ny, coherent, blk, vis, cst, queue, misc):
    """The result of the ray to cell c (Update + the flood fill)."""
    cst[c] = DONE
    misc[M_RAYS] += 1
    b = 1 if blocked else 0
    if coherent and blocked:
        n = misc[M_NBLK]
        if n < blk.shape[0]:
            blk[n, 0] = bx
            blk[n, 1] = by
            blk[n, 2] = bz
            misc[M_NBLK] = n + 1
    if b != vis[c]:
        misc[M_ERR] += 1
        vis[c] = b
        cu = c % nx
        cv = c // nx
        qt = misc[M_QT]
        for dv in range(-1, 2):
            for du in range(-1, 2):
                uu = cu + du
                vv = cv + dv
                if uu >= 0 and vv >= 0 and uu < nx and vv < ny:
                    k = vv * nx + uu
                    if cst[k] == USEPREV:
                        cst[k] = QUEUED
                        queue[qt] = k
                        qt += 1
        misc[M_FLOOD] += qt - misc[M_QT]
        misc[M_QT] = qt


@inner
def finish_point(P, i, nx, ny, wts, vis, prevp, misc):
    """Shade: (V_avg, V_irr) from the visibility image."""
    C = nx * ny
    lit = 0
    wl = 0.0
    wt = 0.0
    for s in range(C):
        wt += wts[s]
        if vis[s] == 0:
            lit += 1
            wl += wts[s]
    prevp[0] = P[i, 0]
    prevp[1] = P[i, 1]
    prevp[2] = P[i, 2]
    misc[M_HAVEPREV] = 1
    return lit / C, (wl / wt if wt > 0.0 else 0.0)


def blocker_capacity(C: int, S: int) -> int:
    return C * S * S + C
