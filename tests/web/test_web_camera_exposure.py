"""Camera mode's exposure from the camera's own picture (issue 17: "in camera and AR modes match
the real camera's image"). Chromium's fake camera plays a picture of three horizontal bands:
sky, a dark ground band, a bright ground band at the bottom. Which band is the ground depends on
where the "phone" looks: held level, the ground below the horizon is mostly the dark band; tilted
up by 20 degrees, only the bottom band is below the horizon. The meter must read the band the
pose puts on the ground, and the exposure must draw the modelled ground at the level the picture
shows it: exposure x (albedo / pi x E) = the picture's ground level, with E = pi L under a
uniform sky of radiance L (a known answer, not the client's sum)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.web.fakecamera import assert_metered_the_ground, camera_page, orient, write_y4m_rows

pytestmark = [pytest.mark.browser]

SIZE = (640, 360)
SKY_RGB = (150, 180, 230)
DARK_GROUND_CODE = 90
BRIGHT_GROUND_CODE = 170
# (first row, colour): sky above the middle row (the level camera's horizon), the dark ground
# band to row 290, the bright one below it (a camera turned up by 20 degrees sees its horizon at
# row 180 + f tan 20 = 293, f = 311.8 px).
BANDS = [(0, SKY_RGB), (180, (DARK_GROUND_CODE,) * 3), (290, (BRIGHT_GROUND_CODE,) * 3)]
SKY_RADIANCE = 40.0  # W/(m^2 sr) in every patch: the open ground gets pi x 40 W/m^2
LUMA = np.array([0.2126, 0.7152, 0.0722])


def settled(page):
    """The exposure at its target now, and what the meter read."""
    exposure = page.evaluate("window.daylit.debug.settleExposure()")
    status = page.evaluate("""() => ({ meter: window.daylit.status.exposureMeter,
      level: window.daylit.status.pictureGroundLevel })""")
    return exposure, status["meter"], status["level"]


def test_camera_mode_exposes_the_hall_as_the_camera_exposed_its_ground(browser, web_build,
                                                                        tmp_path):
    y4m = tmp_path / "bands.y4m"
    write_y4m_rows(y4m, SIZE, BANDS)
    manifest = json.loads((web_build / "manifest.json").read_text())
    lights = manifest["dome"]["lights"]
    assert abs(sum(light["cosine_weighted_sr"] for light in lights) - np.pi) < 0.01 * np.pi
    sky = np.full((len(lights), 3), SKY_RADIANCE)
    albedo = np.array(manifest["ground"]["albedo"], float)
    ground_radiance = LUMA @ (albedo * SKY_RADIANCE)  # albedo / pi x (pi L)
    # The picture's registration off: the bands are not of the site, and it would class them
    # by the client's sun at the hour the suite runs (test_web_camera_mode.SUN_TIME).
    with camera_page(browser, web_build, y4m, sky, "&register=off", size=SIZE) as (
            page, _, errors):
        page.evaluate("(r) => window.daylit.debug.relight(r, 1)", sky.ravel().tolist())

        readings = {}
        for name, beta in [("level", 90), ("up 20", 110), ("sky", 170)]:
            orient(page, 0, beta, 0)
            page.evaluate("window.daylit.debug.screen()")  # the pose drawn, then metered
            readings[name] = settled(page)

        bands = {"level": DARK_GROUND_CODE, "up 20": BRIGHT_GROUND_CODE}
        assert_metered_the_ground(readings, bands, ground_radiance)
        assert not errors, errors
