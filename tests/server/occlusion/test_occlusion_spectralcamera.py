"""The synthetic sequences' light model (spectralcamera.py) against published physics."""

from __future__ import annotations

import numpy as np
import pytest

from server.occlusion import spectralcamera as sc
from server.occlusion.synthetic import default_site


def test_planck_peaks_where_wiens_displacement_law_says():
    lam = np.arange(300.0, 1000.0, 0.01)
    for t_k in (4000.0, 5778.0, 8000.0):
        peak_nm = lam[np.argmax(sc.planck(lam, t_k))]
        assert peak_nm == pytest.approx(2.897771955e6 / t_k, abs=0.02)  # b = 2897.77 um K


def test_rayleigh_depth_and_air_mass_are_the_published_ones():
    # Sea-level Rayleigh optical depth at 550 nm: 0.0973 (Bucholtz 1995, Table 5); the model
    # reads it off a clear sky with no aerosol at the zenith as the beam's loss.
    sky = sc.SkyState("rayleigh only", aerosol_depth_550=0.0)
    direct, _ = sky.irradiance(90.0)
    i550 = int(np.argmin(np.abs(sc.WAVELENGTHS_NM - 550.0)))
    top = sc.planck(sc.WAVELENGTHS_NM, sc.SUN_TEMPERATURE_K)
    tau = -np.log(direct[i550] / top[i550]) / sc.air_mass(90.0)
    assert tau == pytest.approx(0.0973, rel=0.03)
    # Kasten & Young (1989): 1.0 at the zenith, 1.99 at 30 degrees, 5.6 at 10 degrees.
    assert sc.air_mass(90.0) == pytest.approx(1.0, abs=1e-3)
    assert sc.air_mass(30.0) == pytest.approx(1.995, abs=0.01)
    assert sc.air_mass(10.0) == pytest.approx(5.60, abs=0.05)


def test_the_reflectance_basis_is_a_partition_of_unity():
    assert np.allclose(sc.REFLECTANCE_BASIS.sum(axis=0), 1.0)
    assert (sc.REFLECTANCE_BASIS >= 0).all()
    assert np.allclose(sc.reflectance_spectrum([0.3, 0.3, 0.3]), 0.3)  # grey is flat
    # A grey surface under any light shows the light's own colour, scaled.
    _, diffuse = sc.SKY_STATES["clear"].irradiance(32.0)
    grey = sc.camera_matrix(diffuse) @ np.full(3, 0.3)
    assert np.allclose(grey, 0.3 * sc.response(diffuse))


def test_skylight_is_bluer_than_the_sun_and_a_thin_cloud_greys_it():
    def blue_over_red(spectrum):
        r, _, b = sc.response(spectrum)
        return b / r

    for name in ("clear", "hazy"):
        direct, diffuse = sc.SKY_STATES[name].irradiance(32.0)
        assert blue_over_red(diffuse) > 1.5 * blue_over_red(direct), name
    clear = sc.SKY_STATES["clear"].irradiance(32.0)
    cloud = sc.SKY_STATES["thin cloud"].irradiance(32.0)
    assert blue_over_red(cloud[1]) < blue_over_red(clear[1])
    # A clear sky's diffuse share of the light on the ground, sun at 32 degrees, G channel:
    # 0.1-0.3 as measured on clear days; a thin cloud's more than half.
    for (direct, diffuse), lo, hi in ((clear, 0.1, 0.3), (cloud, 0.5, 0.9)):
        share = sc.response(diffuse)[1] / sc.response(direct + diffuse)[1]
        assert lo < share < hi


def test_the_sequences_shadows_are_the_skylight_alone():
    """A shadowed grey ground pixel over its sunlit value: the skylight alone over sun plus
    sky, as dark as a clear sky's diffuse share and bluer; a full 3x3 change, not per channel."""
    site = default_site(160, 90)
    lit, shadow, _ = site.light(0.0)
    direct, diffuse = sc.SKY_STATES["clear"].irradiance(site.sun_elevation_deg)
    grey = np.full(3, 0.3)
    raw = (sc.camera_matrix(diffuse) @ grey) / (sc.camera_matrix(direct + diffuse) @ grey)
    ratio = (shadow @ grey) / (lit @ grey)
    # The camera's colour correction (the inverse of its channels' overlap) spreads the
    # channels apart: R darker and B lighter than the raw ratio, G within 10 %.
    assert ratio[1] == pytest.approx(raw[1], rel=0.1)
    assert ratio[0] < raw[0] and ratio[2] > raw[2]
    assert 0.1 < ratio[1] < 0.3
    assert ratio[2] > ratio[1] > ratio[0]  # bluer in shadow
    # Off-diagonal terms: a shadow is not a per-channel factor for every surface.
    m = np.linalg.solve(lit.astype(float), shadow.astype(float))
    assert np.abs(m - np.diag(np.diag(m))).max() > 0.01
