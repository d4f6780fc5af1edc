"""The phone's own estimate of the sun and the sky (issue 16, web/src/phoneestimate.js) in the
real client, against answers it did not produce.

A small baked site (tests/server/conftest.py scene_build: a building and a wall) is rendered by
Radiance (tests/radiance_frames.py: gendaylit skies, rtrace; not daylit's tracer) from the pose
the client's camera mode takes for a standpoint and a device orientation, through the camera
model (noise, sRGB, JPEG), and played to headless Chromium as its camera (fakecamera.py), with
the client's clock at the render's time (``?time=``) and ``?sky=phone``. The browser's sun/sky
ratio is compared with Radiance's truth (DNI over the sky's horizontal irradiance) and with the
server's estimator (server/sceneestimate.py) on the same frame. The phone's camera is not
calibrated: only the ratio (and the sky type it gives) is checked, not the level.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests.server.conftest import scene_build  # noqa: F401 (the fixture)
from tests.web.fakecamera import camera_page, orient, write_y4m
from tests.web.phoneframes import ORIENTATION, STANDPOINT_M, server_estimate, view_from_three

pytest.importorskip("pyradiance")
pytestmark = [pytest.mark.browser, pytest.mark.slow]

SIZE = (640, 360)  # the page; the camera's picture is rendered at half that (same aspect)
RENDER = (320, 180)
LUMA = np.array([0.2126, 0.7152, 0.0722])
# (name, local standard time, DNI, DHI) on 15 October at the test site (Nara)
SKIES = [("clear", "10.5", 800.0, 80.0), ("intermediate", "13.0", 400.0, 200.0),
         ("overcast", "12.0", 0.0, 150.0)]


@pytest.fixture(scope="module")
def phone_build(request) -> Path:
    existing = os.environ.get("DAYLIT_PHONE_BUILD")  # an existing bake of scene_build
    return Path(existing) if existing else request.getfixturevalue("scene_build")


def _open(browser, build, y4m, query):
    manifest_lights = __import__("json").loads((build / "manifest.json").read_text())
    sky = np.full((manifest_lights["dome"]["count"], 3), 30.0)
    return camera_page(browser, build, y4m, sky, query=query, size=SIZE)


def _pose(page):
    page.evaluate("(p) => window.daylit.debug.standAt(p)", STANDPOINT_M)
    orient(page, *ORIENTATION)
    return page.evaluate("""() => { const c = window.daylit.debug;
      const e = c.phoneEstimate(); return e && { matrixWorld: e.matrixWorld, fovDeg: e.fovDeg,
      sun: e.sun, estimate: e }; }""")


@pytest.fixture(scope="module")
def renders(browser, phone_build, tmp_path_factory):
    """Per sky: the pose (read from the page once), the Radiance render, the camera's frame."""
    from benchmarks.bench_fidelity import SkySpec
    from tests.radiance_frames import camera_frame, linearise, render_build_view

    tmp = tmp_path_factory.mktemp("phone")
    grey = tmp / "grey.y4m"
    write_y4m(grey, np.full((RENDER[1], RENDER[0], 3), 120, np.uint8))
    with _open(browser, phone_build, grey, "&sky=phone") as (page, _, errors):
        page.evaluate("(p) => window.daylit.debug.standAt(p)", STANDPOINT_M)
        orient(page, *ORIENTATION)
        pose = page.evaluate("window.daylit.debug.cameraPose()")
        assert not errors, errors
    view = view_from_three(pose["matrixWorld"], pose["fovDeg"], *RENDER)
    out = {}
    rng = np.random.default_rng(4)
    for name, hour, dni, dhi in SKIES:
        spec = SkySpec(name, 10, 15, hour, dni, dhi)
        rendered, _ = render_build_view(phone_build, spec, *RENDER, view=view)
        codes, _ = camera_frame(rendered.sun_image, rng)
        y4m = tmp / f"{name}.y4m"
        write_y4m(y4m, codes)
        out[name] = {"rendered": rendered, "codes": codes, "y4m": y4m,
                     "server": server_estimate(phone_build, view, linearise(codes),
                                               rendered.sun_dir)}
    return view, out


def test_phone_estimate_against_radiance_and_the_server(browser, phone_build, renders):
    view, skies = renders
    got = {}
    for name, sky in skies.items():
        rendered = sky["rendered"]
        with _open(browser, phone_build, sky["y4m"],
                   f"&sky=phone&time={rendered.when_unix_s}") as (page, _, errors):
            est = _pose(page)
            assert est is not None, name
            # the sun the client computed (sunposition.js) is Radiance's (gendaylit's own
            # solar position) within a few tenths of a degree
            angle = np.degrees(np.arccos(np.clip(np.dot(est["sun"], rendered.sun_dir), -1, 1)))
            assert angle < 0.5, (name, angle)
            ratios = [est["estimate"]["ratio"]] + [
                page.evaluate("window.daylit.debug.phoneEstimate().ratio") for _ in range(2)]
            status = page.evaluate("""() => ({ source: window.daylit.status.lightSource,
              n: window.daylit.status.phoneEstimates, seq: window.daylit.status.lightSeq })""")
            page.wait_for_function("window.daylit.status.lightSeq !== null", timeout=30000)
            status["applied"] = page.evaluate("window.daylit.status.lightSource")
            assert not errors, errors
        truth = rendered.dni_w_m2 / rendered.dhi_w_m2
        got[name] = (float(np.median(ratios)), truth, sky["server"], est["estimate"], status)
    report = {k: {"phone": round(v[0], 3), "truth": round(v[1], 3), "server": round(v[2], 3),
                  "type": v[3]["skyType"], "used": v[3]["used"], "sunlit": v[3]["sunlit"]}
              for k, v in got.items()}
    print(report)
    for name, (phone, truth, server, est, status) in got.items():
        assert status["source"] == "phone" and status["applied"] == "phone", (name, status)
    phone, truth, server, est, _ = got["clear"]
    assert phone == pytest.approx(truth, rel=0.15), report
    assert est["skyType"] == 12, report
    phone, truth, server, est, _ = got["overcast"]
    assert phone < 0.05, report
    assert est["skyType"] == 2, report
    phone, truth, server, est, _ = got["intermediate"]
    assert phone == pytest.approx(truth, rel=0.3), report
