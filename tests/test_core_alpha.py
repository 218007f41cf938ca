"""Alpha-matte occluders (issue 18), core side: the texel lookup against
hand-computed values (Cycles' Image Texture node), and every method's
transmittance on synthetic scenes with closed forms."""
import numpy as np
import pytest

from penumbra.core.alpha import (AlphaMattes, CLIP, CLOSEST, EXTEND, LINEAR, REPEAT,
                                 alpha_at, matte_alpha)

# a 2 x 2 matte, rows from v = 0: row 0 = (0, 1), row 1 = (0.25, 0.75)
TEXELS = [0.0, 1.0, 0.25, 0.75]


def one_matte(interpolation, extension, texels=TEXELS, w=2, h=2, tri_uv=None):
    tri_uv = np.array([[[0, 0], [1, 0], [0, 1]]], np.float32) if tri_uv is None else tri_uv
    return AlphaMattes(np.zeros(len(tri_uv), np.int32), tri_uv, texels, [0], [w], [h],
                       [interpolation], [extension], ["m / img"])


@pytest.mark.parametrize("interp, ext, s, t, expect", [
    (CLOSEST, REPEAT, 0.25, 0.25, 0.0), (CLOSEST, REPEAT, 0.75, 0.25, 1.0),
    (CLOSEST, REPEAT, 0.25, 0.75, 0.25), (CLOSEST, REPEAT, 1.25, 0.25, 0.0),
    (CLOSEST, REPEAT, -0.25, 0.25, 1.0), (CLOSEST, REPEAT, 0.75, -0.25, 0.75),
    (CLOSEST, EXTEND, -0.25, 0.25, 0.0), (CLOSEST, EXTEND, 1.25, 0.75, 0.75),
    (CLOSEST, CLIP, 1.25, 0.25, 0.0), (CLOSEST, CLIP, 0.75, 0.25, 1.0), (CLOSEST, CLIP, 0.75, 1.01, 0.0),
    (LINEAR, REPEAT, 0.25, 0.25, 0.0), (LINEAR, REPEAT, 0.5, 0.25, 0.5), (LINEAR, REPEAT, 0.5, 0.5, 0.5),
    (LINEAR, REPEAT, 0.0, 0.25, 0.5), (LINEAR, REPEAT, 1.0, 0.25, 0.5), (LINEAR, REPEAT, 0.375, 0.25, 0.25),
    (LINEAR, EXTEND, 0.0, 0.25, 0.0), (LINEAR, EXTEND, 1.0, 0.25, 1.0), (LINEAR, EXTEND, 0.75, 1.5, 0.75),
    (LINEAR, CLIP, 0.0, 0.25, 0.0), (LINEAR, CLIP, 1.0, 0.25, 0.5), (LINEAR, CLIP, 1.0, 0.75, 0.375),
    (LINEAR, CLIP, 1.5, 0.25, 0.0),
])
def test_matte_alpha_hand_values(interp, ext, s, t, expect):
    m = one_matte(interp, ext).packed()
    assert matte_alpha(m, 0, s, t) == pytest.approx(expect, abs=1e-12)


def test_alpha_at_interpolates_uvs_with_embree_barycentrics():
    # UV = (1-u-v) uv0 + u uv1 + v uv2; the second triangle maps to the top-left texel
    uv = np.array([[[0, 0], [1, 0], [0, 1]], [[0, 0.5], [0.5, 0.5], [0, 1]]], np.float32)
    a = AlphaMattes([0, -1], np.concatenate([uv[:1], uv[:1]]), TEXELS, [0], [2], [2], [CLOSEST], [REPEAT])
    b = AlphaMattes([0, 0], uv, TEXELS, [0], [2], [2], [CLOSEST], [REPEAT])
    assert alpha_at(a.packed(), 0, 0.6, 0.2) == 1.0       # UV (0.6, 0.2): texel (1, 0)
    assert alpha_at(a.packed(), 0, 0.2, 0.2) == 0.0       # UV (0.2, 0.2): texel (0, 0)
    assert alpha_at(a.packed(), 1, 0.2, 0.2) == 1.0       # no matte: opaque
    assert alpha_at(b.packed(), 1, 0.2, 0.2) == 0.25      # UV (0.1, 0.6): texel (0, 1)


def test_alpha_is_opaque_for_non_finite_uvs_and_clamped():
    uv = np.array([[[np.nan, 0], [1, 0], [0, 1]]], np.float32)
    assert alpha_at(one_matte(LINEAR, REPEAT, tri_uv=uv).packed(), 0, 0.2, 0.2) == 1.0
    m = one_matte(CLOSEST, REPEAT, texels=[-0.5, 2.0, 0.5, 0.5]).packed()
    assert matte_alpha(m, 0, 0.25, 0.25) == 0.0 and matte_alpha(m, 0, 0.75, 0.25) == 1.0
    assert matte_alpha(m, 0, 1e30, 0.25) in (0.0, 1.0)
