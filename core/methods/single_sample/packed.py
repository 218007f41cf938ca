"""The kernels' packed parameter vector: its slots and ``pack_params``, which
fills it from the Params and the light.
"""
from __future__ import annotations

import math

import numpy as np

from ..base import IRRADIANCE


# packed parameter layout for the kernels
(P_AUTO, P_MEET, P_RSCALE, P_RBIAS, P_RSHRINK, P_MAXRAD, P_JITTER, P_EDGE, P_PLANE, P_IDTEST,
 P_BIAS, P_SEED, P_KIND, P_RADIUS, P_SUNTAN, P_NORM, P_HARD, P_TOLREL, P_TOLABS,
 P_GSCALE, P_SUM, P_IRR) = range(22)
N_PRM = 22
# relative float32 precision allowance of stored depths (Embree hit distances
# are float32; a few ULPs of the depth and of the largest coordinate)
TOL_REL = 4e-6
TOL_ABS_PER_COORD = 2e-6
# search gauge norms (``prm[P_NORM]``, ``Gauge.norm``)
NORM_EUCLID = 0     # 2-norm: disk-like lights
NORM_MAX = 1        # max-norm: the unit ball is the rectangle
NORM_L1 = 2         # 1-norm: the diamond on the half axes


def pack_params(params, light, hard_only: bool, coord_mag: float) -> np.ndarray:
    """float64[N_PRM]: ``params`` (SingleSampleParams) and ``light`` in the kernels' slots."""
    prm = np.zeros(N_PRM, np.float64)
    prm[P_AUTO] = 1.0 if params.auto_radius else 0.0
    prm[P_MEET] = min(max(float(params.meet), 0.0), 1.0)
    prm[P_RSCALE] = float(params.r_scale)
    prm[P_RBIAS] = float(params.r_bias)
    prm[P_RSHRINK] = float(params.r_shrink)
    prm[P_MAXRAD] = max(float(params.max_radius), 0.0)
    prm[P_JITTER] = min(max(float(params.jitter), 0.0), 1.0)
    prm[P_EDGE] = 1.0 if params.edge_distance else 0.0
    if params.layer not in ("plane", "constant"):
        raise ValueError(f"single_sample: layer must be 'plane' or 'constant', not {params.layer!r}")
    if params.blocker not in ("nearest", "sum"):
        raise ValueError(f"single_sample: blocker must be 'nearest' or 'sum', not {params.blocker!r}")
    prm[P_PLANE] = 1.0 if params.layer == "plane" else 0.0
    prm[P_IDTEST] = 1.0 if params.id_test else 0.0
    prm[P_BIAS] = max(float(params.bias_texels), 0.0)
    add_up = params.blocker == "sum" and params.auto_radius   # the light's real shape
    prm[P_SUM] = 1.0 if add_up else 0.0
    prm[P_IRR] = 1.0 if add_up and params.visibility == IRRADIANCE else 0.0   # ``coverage``'s weights
    prm[P_SEED] = float(int(params.seed) & 0x7FFFFFFF)
    prm[P_KIND] = light.kind_code
    prm[P_RADIUS] = float(light.radius)
    prm[P_SUNTAN] = light.sun_spread
    rect = light.kind == "area" and not light.is_round
    if add_up:                           # the light's whole shape
        prm[P_NORM] = NORM_MAX if rect else NORM_EUCLID
        prm[P_GSCALE] = 1.0
    else:                                # the ramp has the true slope at V = meet
        prm[P_NORM] = NORM_L1 if rect else NORM_EUCLID
        prm[P_GSCALE] = 1.0 if rect else 4.0 / math.pi
    prm[P_HARD] = 1.0 if (hard_only or light.is_zero_size) else 0.0
    prm[P_TOLREL] = TOL_REL
    prm[P_TOLABS] = TOL_ABS_PER_COORD * coord_mag
    return prm
