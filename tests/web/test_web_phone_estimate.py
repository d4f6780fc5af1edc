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

import json
import os
from pathlib import Path

import numpy as np
import pytest

from tests.server.conftest import scene_build  # noqa: F401 (the fixture)
from tests.web.fakecamera import camera_page, orient, write_y4m
from tests.web.phoneframes import (
    COPY_SCALE,
    POSES,
    copy_shift_px,
    open_irradiance_estimated,
    open_irradiance_truth,
    server_estimate,
    view_from_three,
)

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
    """Camera mode with the stub server sending a sky (which ?sky=phone must ignore)."""
    lights = json.loads((build / "manifest.json").read_text())["dome"]["count"]
    return camera_page(browser, build, y4m, np.full((lights, 3), 30.0), query=query, size=SIZE)


def _estimate(page, pose):
    standpoint, orientation = POSES[pose]
    page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
    orient(page, *orientation)
    return page.evaluate("window.daylit.debug.phoneEstimate()")


_RENDERS = {}


def pose_frames(browser, build, pose, skies, tmp, server=True):
    """For a pose ((standpoint, orientation), read from the page once) and skies [(name, local
    time, DNI, DHI)]: per sky the Radiance render of ``build`` from the pose the page draws, the
    camera's frame (a Y4M for the fake camera), its exposure, the pose, Radiance's open
    irradiances, and (``server``) the server's estimate on it."""
    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import (
        ACCURATE_CAMERA_RAYS,
        camera_frame,
        linearise,
        render_build_view,
    )

    grey = tmp / "grey.y4m"
    write_y4m(grey, np.full((RENDER[1], RENDER[0], 3), 120, np.uint8))
    standpoint, orientation = pose
    # ?register=off: the pose the phone tells, not one a registration turned on the grey
    # picture (a flat picture of surfaces of different albedo splits "sun" from "shade" on the
    # albedos alone; from the first estimate after the orientation came, which the page makes
    # at once now that none is made before it, the eye pose's view was turned 31 px)
    with _open(browser, build, grey, "&sky=phone&register=off") as (page, _, errors):
        page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
        orient(page, *orientation)
        drawn = page.evaluate("window.daylit.debug.cameraPose()")
        assert not errors, errors
    view = view_from_three(drawn["matrixWorld"], drawn["fovDeg"], *RENDER)
    out = {}
    rng = np.random.default_rng(4)
    for name, hour, dni, dhi in skies:
        spec = SkySpec(name, 10, 15, hour, dni, dhi)
        # without the ambient cache: it put shaded surfaces 8-36 % too bright
        rendered, _ = render_build_view(build, spec, *RENDER, view=view,
                                        rays=ACCURATE_CAMERA_RAYS)
        codes, exposure = camera_frame(rendered.sun_image, rng)
        y4m = tmp / f"{name}.y4m"
        write_y4m(y4m, codes)
        out[name] = {"rendered": rendered, "y4m": y4m, "exposure": exposure, "pose": drawn,
                     "open": open_irradiance_truth(spec, build)}
        if server:
            out[name]["server"] = server_estimate(build, view, linearise(codes),
                                                  rendered.sun_dir)
    return out


@pytest.fixture(scope="module")
def renders(browser, phone_build, tmp_path_factory):
    """Per pose and sky: :func:`pose_frames` and the server's estimate on each frame."""

    def make(pose):
        if pose not in _RENDERS:
            _RENDERS[pose] = pose_frames(browser, phone_build, POSES[pose], SKIES,
                                         tmp_path_factory.mktemp(f"phone-{pose}"))
        return _RENDERS[pose]

    return make


@pytest.mark.parametrize("pose", list(POSES))
def test_phone_estimate_against_radiance_and_the_server(browser, phone_build, renders, pose):
    got = {}
    for name, sky in renders(pose).items():
        rendered = sky["rendered"]
        with _open(browser, phone_build, sky["y4m"],
                   f"&sky=phone&time={rendered.when_unix_s}") as (page, _, errors):
            est = _estimate(page, pose)
            assert est is not None, (pose, name)
            # the sun the client computed (sunposition.js) is Radiance's (gendaylit's own
            # solar position) within a few tenths of a degree
            angle = np.degrees(np.arccos(np.clip(np.dot(est["sun"], rendered.sun_dir), -1, 1)))
            assert angle < 0.5, (name, angle)
            # the sky's isotropic share is followed across estimates (one every 2 s in use):
            # the last four of eight
            more = [page.evaluate("window.daylit.debug.phoneEstimate()") for _ in range(7)][-4:]
            # the light drawn is the phone's (not the stub server's sky, which ?sky=phone
            # ignores): the relighter applied one of its vectors
            page.wait_for_function("window.daylit.status.lightSeq !== null", timeout=30000)
            status = page.evaluate("""() => ({ source: window.daylit.status.lightSource,
              estimates: window.daylit.status.phoneEstimates,
              hud: document.querySelector('.statusline')?.textContent ?? '' })""")
            assert not errors, errors
        truth = rendered.dni_w_m2 / rendered.dhi_w_m2
        ests = more
        # the composite: open ground and four walls lit by the estimate, relative to the open
        # ground (the level is the picture's, not known), against Radiance's
        mine = open_irradiance_estimated(ests[-1], est["sun"])
        composite = (mine / mine[0]) / (sky["open"] / sky["open"][0]) - 1.0
        # the level: the test knows the camera's exposure (linear units per W/(m^2 sr)), the
        # phone does not; its sun and sky in W/m^2 through it
        level = [float(np.median([LUMA @ np.asarray(e[key]) for e in ests])) / sky["exposure"]
                 for key in ("sunNormal", "skyHorizontal")]
        got[name] = {"phone": float(np.median([e["ratio"] for e in ests])), "truth": truth,
                     "sun_err": (level[0] / rendered.dni_w_m2 - 1.0 if rendered.dni_w_m2 > 0
                                 else level[0]),
                     "sky_err": level[1] / rendered.dhi_w_m2 - 1.0,
                     "server": sky["server"], "type": ests[-1]["skyType"],
                     "share": round(ests[-1]["modelShare"], 2), "used": est["used"],
                     "sunlit": est["sunlit"], "status": status,
                     "composite_rms": float(np.sqrt(np.mean(composite[1:] ** 2))),
                     "walls": np.round(composite[1:], 3).tolist()}
    print(pose, {k: {q: (round(v, 3) if isinstance(v, float) else v) for q, v in g.items()
                     if q != "status"} for k, g in got.items()})
    for name, g in got.items():
        assert g["status"]["source"] == "phone", (name, g["status"])
        assert g["status"]["estimates"] >= 8 and "phone" in g["status"]["hud"], g["status"]
        # the light's shape: walls against the open ground within 30 % RMS (reached 4-22 %)
        assert g["composite_rms"] < 0.3, (name, got)
    clear, middle, overcast = got["clear"], got["intermediate"], got["overcast"]
    # Goal: the ratio within 15 % under the clear sky (reached +2 and +7 %, the server -1 and
    # -0 %; with the Perez clear sky, 2026-12-06, +10 and +6 %, the server +12 and +14 %), and
    # the sun within 25 % under the clear and the intermediate sky (reached +1 to +8 %; the sky
    # -2 to -15 %)
    assert clear["phone"] == pytest.approx(clear["truth"], rel=0.15), got
    assert clear["phone"] == pytest.approx(clear["server"], rel=0.15), got
    assert clear["type"] == 12, got
    for g in (clear, middle):
        assert abs(g["sun_err"]) < 0.25 and abs(g["sky_err"]) < 0.25, got
    # The intermediate sky (Perez clearness 2.28) is partly cloudy, CIE type 7; its ratio
    # reads high (+22 and +24 %: the sky 12-14 % low, the walls lit less than the CIE sky
    # predicts).
    # Before 2026-11-25 the clear sky's shape read it at +102 to +118 % (docs/web.md).
    assert middle["type"] == 7, got
    assert middle["phone"] == pytest.approx(middle["truth"], rel=0.35), got
    # Overcast: the sun below 5 % of the sky (goal and reached: 0).
    assert overcast["phone"] < 0.05, got
    assert overcast["type"] == 2, got


# A registration's whole-pixel shift against the geometry's: within 2 px. Once the view has
# turned onto the picture the search's landscape is flat over a pixel or two (a soft-shadowed
# sky): on the clear sky's frames a settled view read +1 px where the geometry gave -0.65
# (2026-12-04). A wrong pose reads 12 px and more. (Pixels of the 192 x 108 copy these were
# measured in; COPY_SCALE of the copy's now: the same angles.)
REGISTRATION_ATOL_PX = 2.0 * COPY_SCALE
WRONG_POSE_PX = 8.0 * COPY_SCALE  # a pose told this far off is off (the tests' precondition)
SETTLED_PX = 1.5 * COPY_SCALE  # the registration's own accuracy

def _tell_a_wrong_pose(page, standpoint, alpha, beta, gamma):
    """Only the test's estimates and registrations from here (the page's own may have turned
    the view already, at its first pose: that turn goes); the phone at the standpoint tells a
    heading 6 degrees off and a tilt 3 degrees off."""
    assert page.evaluate("window.daylit.debug.holdPhoneEstimates(true)")
    page.evaluate("window.daylit.debug.resetAlignment()")
    page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
    orient(page, alpha + 6.0, beta + 3.0, gamma)


def test_phone_estimate_registers_a_wrong_pose(browser, phone_build, renders):
    """A compass 6 degrees off and a tilt 3 degrees off (the phone told a wrong pose): each
    estimate finds the picture's shift that puts the model's sun and shade on the picture's
    (poseregister.js) where the test's geometry puts it for the pose it read with, and turns
    the view by it (camera-view.js turnBy): the drawn model ends within the registration's
    own accuracy (1.5 px of the copy) of where the Radiance frame shows the site. Its sun and
    sky stay within the main test's 25 % (unregistered, the tilt alone took 27 % off the clear
    sky's sky and 44 % off the intermediate's: benchmarks/bench_phone_pose.py)."""
    standpoint, (alpha, beta, gamma) = POSES["eye"]
    for name in ("clear", "intermediate"):
        sky = renders("eye")[name]
        rendered = sky["rendered"]
        true_pose = sky["pose"]  # the one the Radiance frame was rendered from
        with _open(browser, phone_build, sky["y4m"],
                   f"&sky=phone&time={rendered.when_unix_s}") as (page, _, errors):
            _tell_a_wrong_pose(page, standpoint, alpha, beta, gamma)
            ests = [page.evaluate("window.daylit.debug.phoneEstimate()") for _ in range(5)]
            final_pose = page.evaluate("window.daylit.debug.cameraPose()")
            assert not errors, errors
        assert np.hypot(*copy_shift_px(true_pose, ests[0])) > WRONG_POSE_PX  # a precondition
        # Each estimate against the pose it read with.
        for e in ests:
            np.testing.assert_allclose(e["shiftPx"], copy_shift_px(true_pose, e),
                                       atol=REGISTRATION_ATOL_PX,
                                       err_msg=name)
        # Within the registration's own accuracy (its shifts against the geometry: 1.5 px)
        residual = copy_shift_px(true_pose, final_pose)
        assert np.hypot(*residual) < SETTLED_PX, (name, residual)
        later = ests[2:]
        sun, sky_h = (float(np.median([LUMA @ np.asarray(e[key]) for e in later]))
                      / sky["exposure"] for key in ("sunNormal", "skyHorizontal"))
        sun_err, sky_err = sun / rendered.dni_w_m2 - 1.0, sky_h / rendered.dhi_w_m2 - 1.0
        print(name, "shifts", [e["shiftPx"] for e in ests], "residual", np.round(residual, 2),
              "sun", round(sun_err, 3), "sky", round(sky_err, 3))
        assert abs(sun_err) < 0.25 and abs(sky_err) < 0.25, (name, sun_err, sky_err)


def test_the_view_follows_the_picture_under_a_server_sky(browser, phone_build, renders):
    """A server sky lights the hall (no estimate), the phone told a pose 6 degrees off in
    heading and 3 in tilt: the pose registered on the picture alone turns the view until the
    drawn model lies within 1.5 px of the copy (the registration's accuracy) of where the
    Radiance frame shows the site."""
    standpoint, (alpha, beta, gamma) = POSES["eye"]
    sky = renders("eye")["clear"]
    with _open(browser, phone_build, sky["y4m"],
               f"&time={sky['rendered'].when_unix_s}") as (page, _, errors):
        page.wait_for_function("window.daylit.status.lightSource === 'server'", timeout=30000)
        _tell_a_wrong_pose(page, standpoint, alpha, beta, gamma)
        shifts = [page.evaluate("window.daylit.debug.phoneRegister()") for _ in range(4)]
        final_pose = page.evaluate("window.daylit.debug.cameraPose()")
        status = page.evaluate("""() => ({ source: window.daylit.status.lightSource,
          n: window.daylit.status.phoneEstimates })""")
        assert not errors, errors
    assert status == {"source": "server", "n": 0}, status  # registered, not estimated
    assert np.hypot(*copy_shift_px(sky["pose"], shifts[0])) > WRONG_POSE_PX  # a precondition
    for r in shifts:
        np.testing.assert_allclose(r["shiftPx"], copy_shift_px(sky["pose"], r),
                                   atol=REGISTRATION_ATOL_PX)
    residual = copy_shift_px(sky["pose"], final_pose)
    print("server sky: shifts", [r["shiftPx"] for r in shifts], "residual", np.round(residual, 2))
    assert np.hypot(*residual) < SETTLED_PX, residual


def test_camera_mode_takes_the_server_sky_when_there_is_one(browser, phone_build, tmp_path):
    """With a server sky the phone does not estimate; with none (a server without cameras, or
    offline) it does, without ?sky=phone (turned to the eye-height pose, which sees the
    building's shade: a view with none makes no estimate)."""
    y4m = tmp_path / "grey.y4m"
    write_y4m(y4m, np.full((RENDER[1], RENDER[0], 3), 120, np.uint8))
    lights = json.loads((phone_build / "manifest.json").read_text())
    sky = np.full((lights["dome"]["count"], 3), 30.0)
    with camera_page(browser, phone_build, y4m, sky, size=SIZE) as (page, _, errors):
        page.wait_for_function("window.daylit.status.lightSeq !== null", timeout=30000)
        assert page.evaluate("window.daylit.debug.phoneEstimate()") is None
        status = page.evaluate("""() => ({ source: window.daylit.status.lightSource,
          n: window.daylit.status.phoneEstimates })""")
        assert status == {"source": "server", "n": 0}, status
        assert not errors, errors
    noon = "2026-10-15T12:00:00%2B09:00"
    with camera_page(browser, phone_build, y4m, None, query=f"&time={noon}",
                     size=SIZE) as (page, _, errors):
        standpoint, orientation = POSES["eye"]
        page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
        orient(page, *orientation)
        page.wait_for_function("window.daylit.status.lightSource === 'phone'", timeout=30000)
        page.wait_for_function("window.daylit.status.lightSeq !== null", timeout=30000)
        assert page.evaluate("window.daylit.status.phoneEstimates") >= 1
        assert not errors, errors


# The demo's visitor centre seen from 30 m north-west of it and 6 m up (the server's held-out
# site camera's standpoint, docs/benchmarks.md "On a site it was not tuned on"), the phone
# turned 22 degrees east of south toward it and 5 degrees down.
DEMO_POSE = ([30.0, 6.0, -45.0], (202.3, 84.6, 0.0))
DEMO_SKIES = [("overcast", "14.5", 0.0, 150.0), ("clear", "14.5", 800.0, 80.0)]


def _eight_estimates(browser, build, pose, frames, early=0) -> tuple[dict, dict]:
    """{sky name: eight phone estimates} from camera mode on each of ``frames`` (pose_frames)
    with ``?sky=phone`` and the client's clock at the render's time, stood at ``pose``; and
    {sky name: the ``early`` estimates asked for at the standpoint before the device's
    orientation came (as the page's own frame loop may, before a phone's first
    deviceorientation event)}."""
    got, before = {}, {}
    for name, sky in frames.items():
        rendered = sky["rendered"]
        with _open(browser, build, sky["y4m"],
                   f"&sky=phone&time={rendered.when_unix_s}") as (page, _, errors):
            # only the test's estimates (not as many as the machine's frame loop made)
            assert page.evaluate("window.daylit.debug.holdPhoneEstimates(true)")
            standpoint, orientation = pose
            page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
            before[name] = [page.evaluate("window.daylit.debug.phoneEstimate()")
                            for _ in range(early)]
            orient(page, *orientation)
            got[name] = [page.evaluate("window.daylit.debug.phoneEstimate()") for _ in range(8)]
            assert not errors, errors
    return got, before


def test_no_phantom_sun_under_the_demo_s_overcast(browser, web_build, tmp_path):
    """On the demo's own real proxies (a site the phone's estimate was not tuned on) under
    Radiance's overcast sky at 14:30, no estimate keeps a sun of 5 % of the sky or more; under
    the clear sky of the same hour the shadow-edge pairs read the sun and it is kept, within
    10 % of Radiance's. Before the phone's pairs' check (2026-12-05) estimates 2-4 of eight
    kept a sun of 51-52 % of the sky on this frame: the whole-view fit took the CIE sky's
    error on the centre's sunward side for a sun, the overcast contrast test let it through."""
    frames = pose_frames(browser, web_build, DEMO_POSE, DEMO_SKIES, tmp_path, server=False)
    got, _ = _eight_estimates(browser, web_build, DEMO_POSE, frames)
    overcast, clear = got["overcast"], got["clear"]
    print("demo overcast ratios", [round(e["ratio"], 3) for e in overcast],
          "pairs", [(e.get("pairs"), e.get("pairRatio")) for e in overcast])
    sun = [float(LUMA @ np.asarray(e["sunNormal"])) / frames["clear"]["exposure"]
           / frames["clear"]["rendered"].dni_w_m2 - 1.0 for e in clear]
    print("demo clear ratios", [round(e["ratio"], 3) for e in clear], "sun", np.round(sun, 3),
          "pairs", [(e.get("pairs"), e.get("pairRatio")) for e in clear])
    # Goal: under overcast the sun below 5 % of the sky, in every estimate
    assert all(e["ratio"] < 0.05 for e in overcast), overcast
    assert all(e["skyType"] == 2 for e in overcast), overcast
    # the view has enough shadow edges for the check (the pairs' MIN_PAIRS is 8)
    assert all(e["pairs"] >= 8 for e in overcast + clear), got
    # the clear sun: read by the pairs (its check ran and kept it), within 10 %
    assert all(e["pairRatio"] is not None and e["pairRatio"] > 1.0 for e in clear), clear
    assert all(abs(err) < 0.10 for err in sun), sun


# The demo's kiosk view (its standpoint and direction, 16, 3.2, 52 m, looking 17 degrees west
# of north), which sees the ground, the tree and its shadow, one or two pixels high at the
# copy's 108 rows at 14:30, and no other shade.
KIOSK_POSE = ([16.0, 3.2, 52.0], (17.1, 91.9, 0.0))
KIOSK_SKIES = [("clear-9.5", "9.5", 800.0, 80.0), ("clear-14.5", "14.5", 800.0, 80.0),
               ("overcast-9.5", "9.5", 0.0, 150.0)]


def test_a_thin_shadow_is_not_shade(browser, web_build, tmp_path):
    """Each sample's sun is its patch's share in sun: on the demo's kiosk view at 14:30 the
    tree's shadow is thinner than a patch, so no pixel of the copy is mostly shaded and the phone
    makes no estimate (the sky cannot be told from the sun; the last light stays). Before
    (2026-12-05) the three pixels whose centres fell in the shadow counted as shaded while they
    read mostly sunlit ground: the sky read 112-158 % too bright and the sun 21-30 % too dim.

    At 9:30 the same view sees the building's shade (some 25 usable pixels mostly in shadow):
    every estimate is made and none is wildly wrong, the sun and the sky each within 25 % (the
    issue's phone goal; measured 2026-12-05: sun -1.4 to +2.2 %, sky -8.7 to +12.7 %; with the
    Perez clear sky and the grid, 2026-12-06: sun -1.7 to +2.2 %, sky -9.4 to +11.6 %), and each
    is read where the pose's registration puts the picture within 3 px of the geometry's shift
    (measured 1.9 px at worst: the registration's landscape is flat over so few shaded pixels).
    On main three of eight dropped the sun and read the sky ten times too bright: at the true
    pose the registration took a shift of 15 px that put the model's shaded pixels, of the
    building's darker albedo, on sunlit ground, a split cleaner than the true one but the wrong
    way round (poseregister.js: the model's shade read brighter per albedo than its sun).

    Under the overcast sky at 9:30 the view cannot tell a sun from the sky: no estimate keeps
    a sun of 5 % of the sky or more (the issue's overcast goal; measured: no estimate, the
    sky's shape never settles). On main five of eight kept one of 37-41 %: the clear shape's
    fit asked for the overcast one, whose fit (a sun of 95 % of the sky) asked for the
    intermediate one, whose fit asked for the overcast one again, and the last was kept."""
    frames = pose_frames(browser, web_build, KIOSK_POSE, KIOSK_SKIES, tmp_path, server=False)
    got, before = _eight_estimates(browser, web_build, KIOSK_POSE, frames, early=2)
    err = {}
    for name, ests in got.items():
        rendered, exposure = frames[name]["rendered"], frames[name]["exposure"]
        if rendered.dni_w_m2 == 0.0:
            continue
        err[name] = [None if e is None else (
            round(float(LUMA @ np.asarray(e["sunNormal"])) / exposure / rendered.dni_w_m2 - 1, 3),
            round(float(LUMA @ np.asarray(e["skyHorizontal"])) / exposure / rendered.dhi_w_m2
                  - 1, 3)) for e in ests]
    shifts = [None if e is None else (e["shiftPx"], np.round(
        copy_shift_px(frames["clear-9.5"]["pose"], e), 1).tolist()) for e in got["clear-9.5"]]
    # where each sky's first estimate read the picture from, against the frame's pose (px)
    first_px = {name: None if ests[0] is None else np.round(
        copy_shift_px(frames[name]["pose"], ests[0]), 1).tolist() for name, ests in got.items()}
    print("kiosk view: (sun, sky) error per estimate", err, "9:30 shifts (read, geometry's)",
          shifts, "overcast ratios", [None if e is None else round(e["ratio"], 3)
                                      for e in got["overcast-9.5"]],
          "first estimate's pose off the frame's", first_px, "estimates before the orientation",
          {name: [e is not None for e in ests] for name, ests in before.items()})
    # Before the device's orientation the view is a placeholder (level, facing north): nothing
    # is read there, and the first estimate after it reads at the device's pose (within the
    # registration's settling, a pixel or two, of the frame's). On main the two estimates asked
    # for there were made and turned the view by what the placeholder lacked, turns kept: the
    # first estimate at 9:30 read 16 px sideways and 8 px vertically off the frame's pose (the
    # page's own estimates did the same in the test's first seconds, in 5 of 7 runs 13-16 px;
    # under the intermediate sky at 9:30 such a first estimate read the sun +32 %, the sky -39 %).
    assert all(e is None for ests in before.values() for e in ests), before
    assert np.hypot(*first_px["clear-9.5"]) < REGISTRATION_ATOL_PX, first_px
    assert all(e is None for e in got["clear-14.5"]), err
    assert all(e is not None for e in got["clear-9.5"]), err
    overcast = [e for e in got["overcast-9.5"] if e is not None]
    assert all(e["ratio"] < 0.05 for e in overcast), [e["ratio"] for e in overcast]
    # Under the overcast sky the view stays where the phone put it: the registration's split
    # there is the sky's (walls that see half the sky read darker per albedo than open ground),
    # not the sun's. Before 2026-12-06, midday the view followed it 11-15 degrees away in five
    # estimates (shifts of 9-41 px), until it saw no shade and estimated nothing.
    drift_px = [float(np.hypot(*copy_shift_px(frames["overcast-9.5"]["pose"], e["turned"])))
                for e in overcast]
    print("overcast: the view off the frame's pose after each estimate (px)",
          np.round(drift_px, 1).tolist())
    assert len(overcast) >= 6 and max(drift_px) < REGISTRATION_ATOL_PX, drift_px
    # Goal: no estimate wildly wrong, sun and sky each within 25 %
    assert all(abs(sun) < 0.25 and abs(sky) < 0.25 for sun, sky in err["clear-9.5"]), err
    for read, geometry in shifts:
        np.testing.assert_allclose(read, geometry, atol=3.0 * COPY_SCALE, err_msg=str(shifts))


def test_the_kiosk_view_s_clear_sky_with_bounce_surfaces_lit_on_their_tilt(browser, web_build,
                                                                           tmp_path):
    """The demo's kiosk view at 9:30 under Radiance's clear sky (gendaylit 800/80, rendered here
    from the phone's pose), six pools (``phonePoolSeed`` 1-6) of three estimates each: the sky's
    median error within 8 %, at least 10 of the 18 within the issue's 10 % and none off by 20 %
    or more, the sun within 10 % in every one.

    The bounce surfaces are lit by the model sky on their own tilt (phonepool.js
    skyBounceTerms; the server's tilted_irradiance): under this sky a wall facing the sun gets
    far more than an isotropic sky's 0.5 of the horizontal irradiance, and one facing away
    less. With each lit by an isotropic sky on its tilt the median error was 11.2 % and 8 of 18
    within 10 % (sky -12.6 to +21.2 %; 2026-12-06, docs/benchmarks.md).

    The copy is 384 x 216 (phoneestimate.js ESTIMATE_SIZE): at 192 x 108 the tree's shadow is
    a pixel or two high, the pool has 15-36 pixels mostly in shade and the sky moved by up to
    27 % from one pool to the next. Measured 2026-12-06 (the same frames; "worst" the largest
    error): the code before, at 192 x 108, median 7.6 %, 13 of 18 within 10 %, worst 18.3 %
    (CI's run, the page's own estimates let in before the hold, 10.0 %, 12 of 18, worst 21.1 %:
    this test's failure there); pools 7-18, 7.6 %, 23 of 36, worst 27 %. Now, at 384 x 216,
    median 3.2 %, 14 of 18, worst 13.4 %; pools 7-18, 5.3 %, 28 of 36, worst 13.3 % (today's
    code at 192 x 108: 11.7 %, 9 of 18; it fails here). What is left is mostly the Perez sky's
    clearness bin: the truth (6.44) is in the clearest bin; fits whose first ratio reads a
    clearness under 6.2 take the bin below and read the sky up to 6 % high, those above it
    read it 5-15 % low."""
    frames = pose_frames(browser, web_build, KIOSK_POSE, [("clear-9.5", "9.5", 800.0, 80.0)],
                         tmp_path, server=False)
    sky = frames["clear-9.5"]
    rendered, exposure = sky["rendered"], sky["exposure"]
    errors_sky, errors_sun = [], []
    with _open(browser, web_build, sky["y4m"],
               f"&sky=phone&time={rendered.when_unix_s}") as (page, _, errors):
        # only the test's estimates, from the start: what the page's own frame loop made
        # before would depend on how many frames the machine drew (each may turn the view, and
        # the pool is the turned pose's)
        assert page.evaluate("window.daylit.debug.holdPhoneEstimates(true)")
        standpoint, orientation = KIOSK_POSE
        page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
        orient(page, *orientation)
        for _ in range(2):  # the registration settles at the pose
            page.evaluate("window.daylit.debug.phoneEstimate()")
        for seed in range(1, 7):
            page.evaluate("(s) => window.daylit.debug.phonePoolSeed(s)", seed)
            for _ in range(3):
                e = page.evaluate("window.daylit.debug.phoneEstimate()")
                assert e is not None, seed
                errors_sun.append(float(LUMA @ np.asarray(e["sunNormal"])) / exposure
                                  / rendered.dni_w_m2 - 1.0)
                errors_sky.append(float(LUMA @ np.asarray(e["skyHorizontal"])) / exposure
                                  / rendered.dhi_w_m2 - 1.0)
        assert not errors, errors
    errors_sky, errors_sun = np.array(errors_sky), np.array(errors_sun)
    print("kiosk 9:30 clear over six pools: sky", np.round(errors_sky, 3), "sun",
          np.round(errors_sun, 3))
    assert np.all(np.abs(errors_sun) < 0.10), errors_sun
    assert np.median(np.abs(errors_sky)) < 0.08, errors_sky
    assert np.sum(np.abs(errors_sky) < 0.10) >= 10, errors_sky
    assert np.all(np.abs(errors_sky) < 0.20), errors_sky
