"""The pieces of benchmarks/sun_bounce_designs.py (the designs that would cut the sun-bounce
images, docs/benchmarks.md) against answers they do not produce: OpenCV's bilinear resize,
an image that is itself a low-resolution one drawn bilinearly, and the dome's own vertices."""

from __future__ import annotations

import cv2
import numpy as np

from bake.dome import Dome
from benchmarks.sun_bounce_designs import (
    bilinear_operator,
    blended,
    coarse_dome_blend,
    low_resolution,
)


def test_bilinear_operator_is_opencvs_resize():
    rng = np.random.default_rng(3)
    for (H, W), (h, w) in (((140, 164), (35, 41)), ((192, 200), (64, 67))):
        low = rng.random((h, w)).astype(np.float32)
        ours = (bilinear_operator(H, W, h, w) @ low.ravel()).reshape(H, W)
        theirs = cv2.resize(low, (W, H), interpolation=cv2.INTER_LINEAR)
        assert np.abs(ours - theirs).max() < 1e-5


def test_low_resolution_recovers_a_low_resolution_image_and_ignores_gutters():
    rng = np.random.default_rng(4)
    H, W, factor = 60, 80, 2
    low = rng.random((H // factor, W // factor, 2, 3)).astype(np.float32)
    columns = cv2.resize(low.reshape(H // factor, W // factor, 6), (W, H),
                         interpolation=cv2.INTER_LINEAR).reshape(H, W, 2, 3)
    valid = np.ones((H, W), bool)
    valid[:, 38:42] = False  # a gutter: whatever is there must not matter
    columns[~valid] = 1e3
    got = low_resolution(columns, valid, factor)
    # (within the fit's small smoothness term, SMOOTHNESS, which pulls at the gutter's edge)
    assert np.abs(got - columns)[valid].max() < 5e-3
    # A texel pattern finer than the low resolution cannot be kept: the fit is not the input.
    checker = np.indices((H, W)).sum(axis=0) % 2
    fine = np.repeat(np.repeat(checker[:, :, None, None], 2, 2), 3, 3).astype(np.float32)
    assert np.abs(low_resolution(fine, np.ones((H, W), bool), factor) - fine).mean() > 0.3


def test_coarse_dome_blend_is_barycentric_and_exact_for_a_smooth_bounce():
    dome = Dome.build("octahedral", 10)
    manifest = {"dome": dome.to_manifest()}
    lights = [i for i, c in enumerate(dome.centroids) if 0.2 < c[1] < 0.9]
    around, blend = coarse_dome_blend(manifest, lights, 2)
    for p in lights:
        nodes, w = blend[p]
        assert len(nodes) == 3 and abs(w.sum() - 1) < 1e-12 and (w >= 0).all()
    # Fewer images than lights, each made of the lights around its node.
    assert len(around) < len(lights) / 2 and all(around)
    # A bounce that is the same per unit irradiance from every direction (column p =
    # solid angle p times a constant image) is blended back exactly.
    omega = dome.solid_angles_sr
    image = np.random.default_rng(5).random((4, 5, 1, 3)).astype(np.float32)
    columns = np.zeros((4, 5, dome.count, 3), np.float32)
    columns[:, :, lights] = image * omega[lights][None, None, :, None]
    got = blended(columns, lights, omega, around, blend)
    assert np.allclose(got, columns[:, :, lights], rtol=1e-5)
    # One that is not (a different image per light) is not.
    columns[:, :, lights] *= np.arange(1, len(lights) + 1, dtype=np.float32)[None, None, :, None]
    assert not np.allclose(blended(columns, lights, omega, around, blend),
                           columns[:, :, lights], rtol=1e-2)
