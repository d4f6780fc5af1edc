"""Equirectangular sky maps to light vectors (``daylit.envmap``): known integrals and the
map's orientation, checked on the dome patches."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from bake.dome import Dome
from daylit.envmap import EnvMapError, equirect_light_vector, read_equirect_exr, write_equirect_exr
from daylit.sky import direction_from_azimuth_elevation
from daylit.spherical import PatchLookup, solid_angle


@pytest.fixture(scope="module")
def dome():
    return Dome.for_light_count(400).vertices


def patch_at(dome, azimuth_deg, elevation_deg) -> int:
    direction = direction_from_azimuth_elevation([azimuth_deg], [elevation_deg])
    return int(PatchLookup(dome)(direction)[0])


def test_a_uniform_map_gives_its_radiance_to_every_patch(dome):
    image = np.empty((64, 128, 3))
    image[:] = [1.5, 2.0, 3.0]
    r = equirect_light_vector(image, dome)
    assert np.allclose(r, [1.5, 2.0, 3.0], rtol=1e-12)


def test_orientation_zenith_row_0_east_a_quarter_across(dome):
    h = 90  # 2-degree pixels
    east_half = np.zeros((h, 2 * h, 3))
    east_half[:, :h] = 1.0  # azimuths 0-180: north through east to south
    r = equirect_light_vector(east_half, dome)
    assert r[patch_at(dome, 90.0, 30.0)].tolist() == [1.0] * 3
    assert r[patch_at(dome, 270.0, 30.0)].tolist() == [0.0] * 3
    # Half the upper hemisphere: the patches' radiances times solid angles sum to pi.
    assert (r[:, 0] * solid_angle(dome)).sum() == pytest.approx(np.pi, rel=1e-3)
    cap = np.zeros((h, 2 * h, 3))
    cap[: h // 6] = 1.0  # elevations 60-90
    r = equirect_light_vector(cap, dome)
    assert r[patch_at(dome, 0.0, 89.0)].tolist() == [1.0] * 3
    assert r[patch_at(dome, 0.0, 10.0)].tolist() == [0.0] * 3
    # The cap's solid angle: 2 pi (1 - sin 60).
    expected = 2 * np.pi * (1 - np.sin(np.radians(60.0)))
    assert (r[:, 0] * solid_angle(dome)).sum() == pytest.approx(expected, rel=2e-3)


def test_a_map_reads_back_and_bad_maps_say_what_to_do(tmp_path):
    image = np.random.default_rng(1).random((8, 16, 3))
    write_equirect_exr(tmp_path / "sky.exr", image)
    assert np.allclose(read_equirect_exr(tmp_path / "sky.exr"), image.astype(np.float32))
    with pytest.raises(EnvMapError, match="no such file"):
        read_equirect_exr(tmp_path / "nowhere.exr")
    square = {c: np.ones((8, 8), np.float32) for c in "RGB"}
    with OpenEXR.File(_header(), square) as f:
        f.write(str(tmp_path / "square.exr"))
    with pytest.raises(EnvMapError, match="twice as wide as high.*resample"):
        read_equirect_exr(tmp_path / "square.exr")
    with OpenEXR.File(_header(), {"Y": np.ones((8, 16), np.float32)}) as f:
        f.write(str(tmp_path / "grey.exr"))
    with pytest.raises(EnvMapError, match="needs R, G and B"):
        read_equirect_exr(tmp_path / "grey.exr")
    (tmp_path / "text.exr").write_text("not an image")
    with pytest.raises(EnvMapError, match="not a readable OpenEXR"):
        read_equirect_exr(tmp_path / "text.exr")
    with pytest.raises(EnvMapError, match="negative"):
        equirect_light_vector(-image, Dome.for_light_count(40).vertices)


def _header() -> dict:
    return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
