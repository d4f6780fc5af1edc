"""The sun tests' site and display transform, shared by test_web_sun.py (the visit) and
test_web_kiosk_sun.py (the kiosk's fixed view): a virtual box and a real box (a proxy that
receives shadows) on open ground, the sun due east and low, so that the real box's shadow
falls over the virtual box and runs on past it beside the virtual box's own shadow:

    x:  -12      -9.2          -3.7   -1  0  1     4.5  6  7.5
        open ..  virtual only  overlap  [V]    real     [R]     (shadows fall west, -X)

and a fixed view (the kiosk's) looking down at both shadows from the south-west.
"""

from __future__ import annotations

import numpy as np

SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG = 90.0, 20.0
SUN_DNI = np.array([780.0, 760.0, 700.0])  # W/m^2, a little warm

# The kiosk's view: 160 x 112 pixels from 10 m up, 12 m south of the shadows.
VIEW = {"name": "kiosk", "width": 160, "height": 112, "fov_y_deg": 60.0,
        "position_m": [-4.0, 10.0, 12.0], "look_at_m": [-3.0, 0.0, 0.0]}


def view_table() -> str:
    v = VIEW
    return (f'\n[[view]]\nname = "{v["name"]}"\nwidth = {v["width"]}\nheight = {v["height"]}\n'
            f'fov_y_deg = {v["fov_y_deg"]}\nposition_m = {v["position_m"]}\n'
            f'look_at_m = {v["look_at_m"]}\n')


def bake_sun_site(root):
    """Bake the site (draft) under ``root``; returns the build folder."""
    from bake.pipeline import bake
    from tests.sites import box, make_site, real_box

    scene = make_site(
        root / "scene",
        virtual=[("vbox", box([2.0, 3.0, 2.0], [0.0, 0.0, 0.0]), (0.6, 0.6, 0.6))],
        real=real_box("rbox", (3.0, 3.0, 3.0), (6.0, 0.0, 0.0)),
        views=view_table(),
        ground_m=40.0,
        ground_texel_m=0.25,
    )
    out = root / "build"
    bake(scene, out, quality="draft", progress=False, log=lambda m: None)
    return out


def sun_and_sky(build):
    """The sun (direction toward it, normal irradiance) and a clear sky without its disc."""
    from daylit import sky as skies

    clear = skies.clear_sky(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    r = skies.patch_mean_radiance(clear, build.dome_vertices, include_sun=False)
    s = skies.direction_from_azimuth_elevation(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    return s, r


def neutral_tone_map(c: np.ndarray) -> np.ndarray:
    """Khronos PBR Neutral (the display transform three.js calls NeutralToneMapping), written
    from the Khronos specification: linear (..., 3) -> display-linear (..., 3)."""
    start, desaturation = 0.8 - 0.04, 0.15
    c = np.array(c, dtype=np.float64)
    x = c.min(axis=-1, keepdims=True)
    offset = np.where(x < 0.08, x - 6.25 * x * x, 0.04)
    c = c - offset
    peak = c.max(axis=-1, keepdims=True)
    d = 1.0 - start
    new_peak = 1.0 - d * d / (peak + d - start)
    g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0)
    compressed = (1.0 - g) * c * new_peak / np.maximum(peak, 1e-12) + g * new_peak
    return np.where(peak < start, c, compressed)


def srgb_codes(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding to 8-bit codes (float, unrounded)."""
    x = np.clip(linear, 0.0, 1.0)
    return 255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
