"""Pixel area: ``[camera] samples_per_pixel`` box-filters each pixel (bubblefit.model.geometry.pixel_offsets).

The check is exact by construction: a 4x4 stratified render of W x H pixels samples the
same points as a 4W x 4H render (disc scaled by 4) samples at its pixel centres, so the
former must equal the 4x4 block average of the latter, at the bubble's edge (where
point sampling aliases) as everywhere else.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.model.geometry import pixel_offsets
from bubblefit.model.scene import Scene, render_scene


def _scene(w, h, disc, spp):
    return Scene.from_dict({
        "camera": {"width": w, "height": h, "disc": list(disc), "samples_per_pixel": spp},
        "bubble": {"thickness_nm": 420.0, "roughness": 0.05},
        "lighting": {"point_lights": [{"direction": [0.3, 0.5, 1.0], "radiance": [2.0, 2.0, 2.0]}],
                     "background": "black"},
        # every effect pinned: ``auto`` may decide per pixel, and differently at another size
        "effects": {"model": "physical", "spectral": {"method": "uniform", "samples": 16}, "filtering": "mirror",
                    "interference": "airy", "bounces": 2, "diffuse": True, "front_reflection": True,
                    "rear_reflection": True},
    })


def test_offsets_are_stratified_box_samples():
    o = pixel_offsets(16)
    assert o.shape == (16, 2)
    np.testing.assert_allclose(o.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.unique(o[:, 0]), [-0.375, -0.125, 0.125, 0.375])
    np.testing.assert_allclose(pixel_offsets(1), [[0.0, 0.0]])
    with pytest.raises(ValueError):
        pixel_offsets(8)


def test_supersampled_edge_equals_box_average_of_larger_render():
    w = h = 12
    small = render_scene(_scene(w, h, (6.3, 5.8, 4.7), 16))
    big = render_scene(_scene(4 * w, 4 * h, (4 * 6.3, 4 * 5.8, 4 * 4.7), 1))
    boxed = big.reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(small, boxed, rtol=2e-4, atol=2e-6)
    point = render_scene(_scene(w, h, (6.3, 5.8, 4.7), 1))
    # Not vacuous: at the rim point sampling differs from the box average.
    assert np.abs(point - boxed).max() > 20 * np.abs(small - boxed).max()


def test_samples_per_pixel_must_be_square():
    with pytest.raises(InputError, match="square"):
        _scene(8, 8, (4, 4, 3), 8)
