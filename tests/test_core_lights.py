"""Light kinds answer for themselves: the bounds, cones and clamps
the methods need are ``Light``'s, checked against closed forms and against
the points the samplers draw on each light."""
from __future__ import annotations

import math

import numpy as np
import pytest

from penumbra.core import sampling
from penumbra.core.scene import KIND_AREA, KIND_SPHERE, KIND_SUN, SUN_MAX_SPREAD_ANGLE, Light
from synthetic import area_light, light_matrix, sphere_light, sun_light

U = np.random.default_rng(7).random((400, 2))
P = np.array([0.3, -0.2, 0.0])        # a shaded point below every light


def _tilted(light: Light) -> Light:
    m = light_matrix((0.5, -1.0, 4.0), forward=(0.3, 0.2, -1.0))
    light.world_from_light = m
    return light


def _samples(light: Light) -> np.ndarray:
    lp = sampling.pack_light(light)
    return np.array([sampling.light_sample(lp, *P, u, v)[:3] for u, v in U])


@pytest.mark.parametrize("light", [area_light(2.0, 1.0, "RECTANGLE"), area_light(1.5, shape="DISK"),
                                   area_light(3.0, 0.5, "ELLIPSE"), sphere_light(0.7),
                                   sphere_light(0.3, spot_size=1.0)], ids=lambda lt: f"{lt.kind}-{lt.shape}")
def test_box_and_bounding_radius_hold_every_sample(light):
    light = _tilted(light)
    pts = _samples(light)
    lo, hi = light.box()
    assert (pts >= lo - 1e-12).all() and (pts <= hi + 1e-12).all()
    r = np.linalg.norm(pts - light.position, axis=1)
    assert r.max() <= light.bounding_radius * (1 + 1e-12)
    # and it is not loose (a disk / ellipse is bounded by its rectangle's corners)
    tight = max(light.half_size) if light.is_round else light.bounding_radius
    assert r.max() >= 0.8 * tight


def test_closed_forms():
    a = area_light(2.0, 1.0, "RECTANGLE")
    assert a.bounding_radius == pytest.approx(0.5 * math.sqrt(5.0))
    assert a.half_size == (1.0, 0.5) and not a.is_round and area_light(1.0, shape="ELLIPSE").is_round
    assert sphere_light(0.7).bounding_radius == 0.7 and math.isinf(sun_light(0.1).bounding_radius)
    with pytest.raises(ValueError, match="no box"):
        sun_light(0.1).box()
    s = sun_light(2 * math.atan(0.1))
    assert s.sun_spread == pytest.approx(0.1) and s.sun_half_angle == pytest.approx(math.atan(0.1))
    assert s.sun_cos_max == pytest.approx(1.0 / math.sqrt(1.01))
    assert sun_light(0.0).sun_spread == 0.0
    # the clamp: a sun of 180 degrees or more spreads as one of 179, finitely
    wide = sun_light(math.pi).sun_spread
    assert wide == pytest.approx(math.tan(0.5 * SUN_MAX_SPREAD_ANGLE)) and math.isfinite(wide)
    assert sun_light(math.pi).sun_half_angle == pytest.approx(math.pi / 2)
    spot = sphere_light(0.1, spot_size=math.pi / 2)
    assert spot.is_spot and spot.spot_cos == pytest.approx(math.cos(math.pi / 4))
    assert not sphere_light(0.1).is_spot and sphere_light(0.1).spot_cos == pytest.approx(0.0, abs=1e-15)
    assert (a.kind_code, sphere_light().kind_code, s.kind_code) == (KIND_AREA, KIND_SPHERE, KIND_SUN)
    assert (sampling.KIND_AREA, sampling.KIND_SPHERE, sampling.KIND_SUN) == (KIND_AREA, KIND_SPHERE, KIND_SUN)


def test_axes_are_the_light_frame():
    light = _tilted(area_light(1.0))
    ax, ay, az = light.axes
    R = np.stack([ax, ay, az], 1)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.allclose(-az, light.direction)


def test_sun_samples_stay_in_its_cone():
    s = _tilted(sun_light(0.6))
    d = _samples(s)
    cos = d @ (-s.direction)
    assert cos.min() >= s.sun_cos_max - 1e-12
    assert cos.min() <= s.sun_cos_max + 1e-3            # the cone's rim is reached
