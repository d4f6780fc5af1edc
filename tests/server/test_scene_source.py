"""``[sky] source = "scene"`` end to end: a site camera's frame of a small baked site's real
proxies (tests/sites.py: a building and a wall, seen from the north as a kiosk would), rendered
by Radiance under a known clear sky, through the real server to a version-2 client.

The frame is an OpenEXR replay (linear, with its capture time as ``capDate``, so the sun is
where it was for the render); the vector arrives with the sun's source ``scene`` and the
SUN_ESTIMATED flag, and ``/api/status`` shows the estimate against the render's truth.
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

pytest.importorskip("pyradiance")


def write_exr(path, rgb: np.ndarray, when_unix_s: float, utc_offset_h: float = 9.0) -> None:
    """Linear RGB with the capture time as OpenEXR's capDate (local) and utcOffset."""
    import OpenEXR

    channels = {c: np.ascontiguousarray(rgb[:, :, k].astype(np.float32))
                for k, c in enumerate("RGB")}
    local = dt.datetime.fromtimestamp(when_unix_s, dt.UTC) + dt.timedelta(hours=utc_offset_h)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "capDate": local.strftime("%Y:%m:%d %H:%M:%S"),
              "utcOffset": -utc_offset_h * 3600.0}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


@pytest.mark.slow
async def test_scene_source_streams_the_estimated_sun_and_sky(aiohttp_client, scene_build,
                                                              tmp_path):
    from benchmarks.radiance import SkySpec
    from daylit.sun import SunSource
    from server import protocol
    from server.app import create_app
    from tests.radiance_frames import ACCURATE_CAMERA_RAYS, render_build_view
    from tests.server.helpers import first_light_v2, settings_for

    # without Radiance's ambient cache: its brightened shade read as sky (+66 % with the
    # Perez clear sky, whose shape no longer makes up for it)
    rendered, view = render_build_view(scene_build, SkySpec("clear", 10, 15, "11",
                                                                 800.0, 80.0), 320, 180,
                                       procs=1, rays=ACCURATE_CAMERA_RAYS)
    exposure = 0.8 / float(np.percentile(rendered.sun_image, 99.0))
    folder = tmp_path / "site"
    folder.mkdir()
    write_exr(folder / "frame.exr", rendered.sun_image * exposure, rendered.when_unix_s)
    app = create_app(scene_build, settings_for(
        tmp_path, sky__source="scene", site_camera__source=f"replay:{folder}",
        site_camera__rate_hz=5.0, occlusion__enabled=False,
        scene__radiance_per_unit=1.0 / exposure))
    client = await aiohttp_client(app)
    ws, m = await first_light_v2(client)
    assert m.sun.source == SunSource.SCENE
    assert m.flags & protocol.Flags.SUN_ESTIMATED and m.sun.estimated
    sun_w_m2 = float(np.mean(m.sun.normal_irradiance_w_m2))
    assert sun_w_m2 == pytest.approx(rendered.dni_w_m2, rel=0.15)
    status = await (await client.get("/api/status")).json()
    est = status["scene_estimate"]
    assert status["source"].startswith("scene:")
    assert np.mean(est["sky_horizontal_irradiance_W_m2"]) == pytest.approx(rendered.dhi_w_m2,
                                                                            rel=0.15)
    assert np.all(np.asarray(m.rgb) >= 0.0) and np.asarray(m.rgb).max() > 0.0
    # the build's albedos are right: each surface's learned scale near 1 and none used
    surfaces = est["surfaces"]
    assert len(surfaces) >= 2
    assert sum(s["share_of_view"] for s in surfaces) == pytest.approx(1.0, abs=1e-3)
    assert all(not s["used"] and abs(s["learned_scale"] - 1.0) < 0.15 for s in surfaces), surfaces
    await ws.close()


def test_scene_source_without_a_site_camera_is_a_clear_error(scene_build, tmp_path):
    from server.app import create_app
    from server.config import ConfigError
    from tests.server.helpers import settings_for

    with pytest.raises(ConfigError, match="needs a site camera"):
        create_app(scene_build, settings_for(tmp_path, sky__source="scene"))
