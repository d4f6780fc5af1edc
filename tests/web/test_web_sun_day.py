"""Over a clear simulated day, the reconstruction on screen brightens and darkens with the sun
as physics says it should.

Before the sun had its own light, the sky camera clipped it and the hall's brightness did not
follow the sun at all (correlation with its elevation -0.06, issue 15). Here every vector goes
the way a real one does: the simulated sky's 8-bit fisheye frame (server/simsky.py, its sun
clipped), the real measuring code (server/measure.py with server/sunmeter.py: the sky without
the disc, the sun from the clear-sky model), protocol version 2 on the wire, the client's
decoder, relight and sun, and the displayed pixels at a fixed exposure. What they should show
comes from the oracle at the points those pixels see (the baked sky and the ray-cast sun, from
the same measured vectors).
"""

from __future__ import annotations

import base64
import datetime as dt

import numpy as np
import pytest

from tests.web.harness import StubServer

pytestmark = [pytest.mark.browser]

EXPOSURE = 0.004
HOURS = (7.0, 8.5, 10.0, 11.5, 13.0, 14.5, 16.0, 17.5)


def measured_day(manifest):
    """(elevation_deg, LIGHT message) for each hour of 21 March at the site, clear sky."""
    from server import protocol
    from server.measure import SkyMeter
    from server.photometry import Photometry
    from server.simsky import SimulatedSky
    from server.sunmeter import SunMeter

    scene = manifest["scene"]
    site = (scene["latitude_deg"], scene["longitude_deg"], scene["elevation_m"])
    sim = SimulatedSky.for_site(*site, scene["timezone"], cloud_cover=0.0,
                                start="2026-03-21T07:00", size_px=480)
    dome = np.array([light["vertices"] for light in manifest["dome"]["lights"]])
    meter = SkyMeter(dome, Photometry(response="srgb"), camera=sim.camera, sun=SunMeter(*site))
    start = sim.clock.start_s
    out = []
    for seq, hour in enumerate(HOURS, start=1):
        t = start + (hour - 7.0) * 3600.0
        m = meter.measure(sim.render_at(t, capture_time_s=t))
        elevation = sim.sun_at(t)[1]
        message = protocol.encode_light(m.radiance, m.saturated, seq, t, 0, version=2, sun=m.sun)
        out.append((elevation, message, m.sun))
    return out


def expected_brightness(reference, hits, day):
    """Mean albedo / pi x E x exposure (luminance) over the hall's pixels for each vector of
    the day, from the oracle."""
    from bake.sunlight import SunCasters

    points = np.array([h["point"] for h in hits])
    normals = np.array([h["normal"] for h in hits])
    samples = [reference.locate(p, n) for p, n in zip(points, normals, strict=True)]
    basis = np.stack([reference.basis_at(s, "I") for s in samples])  # (m, n, 3)
    casters = SunCasters.from_site_glb(reference.dir / reference.manifest["model"]["path"])
    albedo = np.array([h["albedo"] for h in hits])  # the glTF base colours the client uses
    out = []
    for _, message, sun in day:
        from server import protocol

        r = protocol.decode(message).rgb.astype(np.float64)
        sky = np.einsum("mnc,nc->mc", basis, r)
        direct = casters.irradiance(points, normals, sun.direction,
                                    sun.normal_irradiance_w_m2)["with"]
        radiance = albedo / np.pi * (sky + direct) * EXPOSURE
        out.append(float((radiance @ np.array([0.2126, 0.7152, 0.0722])).mean()))
    return np.array(out)


def test_the_hall_follows_the_sun_over_a_clear_day(new_page, web_build, reference):
    day = measured_day(reference.manifest)
    assert all(sun.source == 2 for _, _, sun in day)  # clipped: the clear-sky estimate
    with StubServer(web_build, {"protocol": 2}) as server:
        page = new_page(640, 360).open(f"{server.url}/?mode=visit&test&exposure={EXPOSURE}")
        server.wait_for_clients()
        page.page.evaluate("window.daylit.debug.setCamera([30, 14, 36], [0, 3, 0])")
        grid = [[x + 0.5, y + 0.5] for y in range(0, 360, 6) for x in range(0, 640, 6)]
        hits = page.page.evaluate("(p) => window.daylit.debug.pick(p)", grid)
        hall = [i for i, h in enumerate(hits)
                if h is not None and h["role"] == "virtual" and "hall" in h["name"]]
        assert len(hall) > 200, len(hall)
        brightness = []
        for seq, (_, message, _) in enumerate(day, start=1):
            server.push(message)
            page.wait(f"window.daylit.status.lightSeq === {seq} && "
                      "window.daylit.status.lightsExact")
            shot = page.page.evaluate("window.daylit.debug.screen()")
            image = np.frombuffer(base64.b64decode(shot["data"]), np.uint8).reshape(
                shot["height"], shot["width"], 4)[..., :3] / 255.0
            linear = np.where(image <= 0.04045, image / 12.92, ((image + 0.055) / 1.055) ** 2.4)
            luminance = linear @ np.array([0.2126, 0.7152, 0.0722])
            pixels = np.array([grid[i] for i in hall]).astype(int)
            brightness.append(float(luminance[pixels[:, 1], pixels[:, 0]].mean()))
        expected = expected_brightness(reference, [hits[i] for i in hall], day)
        elevation = np.array([e for e, _, _ in day])
        correlation = float(np.corrcoef(expected, brightness)[0, 1])
        print(f"hall over {dt.date(2026, 3, 21)}, sun elevation {np.round(elevation).tolist()}: "
              f"displayed {np.round(brightness, 3).tolist()}, oracle "
              f"{np.round(expected, 3).tolist()}; correlation {correlation:.3f}, with the sun's "
              f"elevation {np.corrcoef(elevation, brightness)[0, 1]:.3f}")
        assert correlation > 0.97, (correlation, brightness, expected)
        # the sun's light, not only the sky's: the sunniest hour several times the dawn's
        assert max(brightness) > 2.0 * brightness[-1], brightness
        assert not page.errors, page.errors
