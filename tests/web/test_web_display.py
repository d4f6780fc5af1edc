"""The displayed picture (issue 17): what the visitor sees, read back from the canvas after the
display transform, against numpy references computed here, for the hull-plane mode and the
relight targets of the RGBA8 fallback. The lightmap mode's displayed pixels are checked the
same way in test_web_sun.py and the kiosk's in test_web_kiosk_sun.py.

The reference's display transform is three.js's NeutralToneMapping as Khronos specifies it
(tests/web/sunsite.py neutral_tone_map) applied to the oracle's linear radiance times the
exposure, then the sRGB OETF.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.web import sh9oracle
from tests.web.harness import StubServer, decode_floats
from tests.web.shaderpage import pixels, shader_page
from tests.web.sunsite import SUN_DNI, SUN_ELEVATION_DEG, neutral_tone_map, srgb_codes, sun_and_sky
from tests.web.test_web_sun import SunPage

pytestmark = [pytest.mark.browser]

# The virtual box's sunlit east face at about 2.0 before tone mapping: well into the tone
# map's compression, where multiplying the tone-mapped colour by the ratio goes wrong.
HULL_EXPOSURE = 0.0125


def hull_expected(build, casters, s, r, hits, albedo):
    """Displayed codes of the virtual box seen through its hull planes (hull-plane mode): the
    face shaded from the sky's nine harmonics (manifest sh9, Ramamoorthi & Hanrahan's
    irradiance written in sh9oracle.py), the unshadowed sun and its ground bounce as the
    hull's d holds it, times the hull plane's ratio (with + S V) / (without + S) from the
    baked hull atlas (compact), its sun bounce and the ray-cast sun. Also the linear radiance
    and the ratio."""
    points = np.array([h["point"] for h in hits])
    normals = np.array([h["normal"] for h in hits])
    lights = build.manifest["dome"]["lights"]
    sh9 = np.array([light["sh9"] for light in lights])  # (n, 9)
    L = sh9.T @ np.asarray(r, np.float64)  # (9, 3)
    sky = np.stack([sh9oracle.irradiance_from_sh9(L[:, c], normals) for c in range(3)], axis=1)
    cos = np.maximum(normals @ s, 0.0)[:, None]
    ground_albedo = np.asarray(build.manifest["ground"]["albedo"])
    bounce = ground_albedo * SUN_DNI * max(s[1], 0.0) * 0.5 * (1.0 - normals[:, 1:2])
    shading = np.maximum(sky, 0.0) + SUN_DNI * cos + bounce
    base = [build.irradiance(p, n, r, source="compact", atlases=("hull",))
            for p, n in zip(points, normals, strict=True)]
    with_ = np.array([b["with"] for b in base])
    without = np.array([b["without"] for b in base])
    sun_bounce = build.sun_bounce(points, normals, s, SUN_DNI, source="compact", atlases=("hull",))
    sun = casters.irradiance(points, normals, s, SUN_DNI)
    ratio = (with_ + sun_bounce["with"] + sun["with"]) / (
        without + sun_bounce["without"] + SUN_DNI * cos)
    radiance = albedo / math.pi * shading * HULL_EXPOSURE
    return srgb_codes(neutral_tone_map(radiance * ratio)), radiance, ratio


def test_hull_mode_displayed_against_the_oracle(new_page, sun_build, sun_reference):
    """The virtual box's east face in hull-plane mode, in the real box's shadow (lit by the
    bluish sky alone) and in the sun, as displayed, within 3 codes of the reference: the
    shadow is the tone map of the sky-lit face, not the tone-mapped sunlit face scaled by
    ratio^(1/2.2) (the client before 2026-11-24: 38-50 codes darker there, checked below so
    that this test can fail)."""
    build, casters = sun_reference
    s, r = sun_and_sky(build)
    edge_y = 3.0 - 3.5 * math.tan(math.radians(SUN_ELEVATION_DEG))  # 1.726
    face = [[1.0, y, z] for y in (0.7, 1.1, 2.3, 2.6) for z in (-0.5, 0.0, 0.5)]
    with StubServer(sun_build) as server:
        page = new_page(800, 600).open(
            f"{server.url}/?mode=visit&test&shading=hull&exposure={HULL_EXPOSURE}")
        page.wait("window.daylit.status.shadingMode === 'hull'")
        sp = SunPage(page, build, s, r)
        sp.look([3.0, 1.9, 2.2], [1.0, 1.7, 0.2])
        _, hits, shown = sp.at(face)
        assert all(h is not None and h["role"] == "shadowing-plane" and h["atlas"] == "hull"
                   for h in hits), hits
        assert not page.errors, page.errors
    albedo = np.full(3, 0.6)  # the virtual box (sunsite.py)
    want, radiance, ratio = hull_expected(build, casters, s, r, hits, albedo)
    lit = np.array([h["point"][1] > edge_y for h in hits])
    assert (ratio[lit] > 0.9).all() and (ratio[~lit] < 0.3).all(), ratio
    # the shadow is lit by the sky: bluer than the sunlit face
    assert (ratio[~lit, 2] > 1.1 * ratio[~lit, 0]).all(), ratio
    # The bug this test must catch: the tone-mapped, sRGB-encoded face times ratio^(1/2.2).
    scaled = srgb_codes(neutral_tone_map(radiance)) * np.minimum(ratio, 1.0) ** (1 / 2.2)
    assert np.abs(scaled[~lit] - want[~lit]).max() > 15.0, (scaled, want)
    for k in range(len(face)):
        print(f"{face[k]} shown {shown[k]} reference {np.round(want[k], 1)} "
              f"(scaled {np.round(scaled[k], 1)})")
    assert np.abs(shown - want).max() <= 3.0, (shown, want)


@pytest.fixture
def rgbe_roundtrip(browser):
    """The shipped RGBE_ENCODE / RGBE_DECODE chunks: values encoded, rounded to 8 bits as an
    RGBA8 target stores them, decoded."""
    def run(values):
        with shader_page(browser) as (page, errors):
            chunks = page.evaluate("""async () => {
                const m = await import('/src/relight.glsl.js');
                return [m.RGBE_ENCODE, m.RGBE_DECODE];
            }""")
            frag = ("#version 300 es\nprecision highp float;\nuniform sampler2D v;\n"
                    "out vec4 outColor;\n" + chunks[0] + chunks[1] + """
void main() {
  vec3 x = texelFetch(v, ivec2(gl_FragCoord.xy), 0).rgb;
  vec4 stored = floor(encodeRGBE(x) * 255.0 + 0.5) / 255.0;
  outColor = vec4(decodeTarget(stored), 1.0);
}""")
            n = len(values)
            data = np.c_[values, np.ones(n)].ravel().tolist()
            out = page.evaluate("([f, n, d]) => window.runFragment(f, n, 1, {v: {type: 'tex', "
                                "value: {width: n, height: 1, data: d}}})", [frag, n, data])
            assert not errors, errors
            return pixels(out, n, 1)[0, :, :3]
    return run


def test_rgbe_keeps_signed_values(rgbe_roundtrip):
    """The RGBA8 fallback's shared exponent keeps each channel's sign: decoded values within
    1/255 of the texel's largest magnitude (half a mantissa step, rounded) of the stored ones,
    across the exponent range (1e-4 to 2e4), negative channels included."""
    rng = np.random.default_rng(17)
    magnitude = 10.0 ** rng.uniform(-4, 4.3, size=(64, 1))
    values = magnitude * rng.uniform(-1, 1, size=(64, 3))
    values[0] = [-0.5, 0.25, 0.125]  # a bounced-light texel: negative red
    values[1] = [-3.0, -2.0, -1.0]
    values[2] = [0.0, 0.0, 0.0]
    got = rgbe_roundtrip(values)
    scale = np.abs(values).max(axis=1, keepdims=True)
    err = np.abs(got - values) / np.maximum(scale, 1e-30)
    print(f"RGBE round trip: worst error {err.max() * 255:.2f} / 255 of the texel's largest")
    assert err.max() <= 1.0 / 255, (values[err.max(axis=1).argmax()], got[err.max(axis=1).argmax()])
    assert (np.sign(got[np.abs(values) > scale / 100]) ==
            np.sign(values[np.abs(values) > scale / 100])).all()


def test_rgbe_targets_match_half_float(new_page, sun_build, sun_reference):
    """The whole client with RGBA8 relight targets (?targets=rgbe, a GPU without half-float
    targets) against half float for the same light: every stack's target within 1/255 of its
    texel's largest magnitude plus half-float rounding, its negative texels (a shadowing
    atlas's I holds d - I, signed) kept negative; the old RGBE clamped them to 0."""
    build, _ = sun_reference
    s, r = sun_and_sky(build)
    reads = {}
    with StubServer(sun_build) as server:
        for name, query in (("half", ""), ("rgbe", "&targets=rgbe")):
            page = new_page(320, 240).open(f"{server.url}/?mode=visit&test&shading=hull{query}")
            page.wait("window.daylit.status.shadingMode === 'hull'")
            SunPage(page, build, s, r)
            formats = page.page.evaluate("window.daylit.debug.formats()")
            assert formats == {"rgbe": name == "rgbe", "linearFrame": name == "half"}, formats
            keys = [k for k in page.page.evaluate("window.daylit.debug.targets()")
                    if k.endswith((".I", ".d"))]
            reads[name] = {k: decode_floats(page.page.evaluate(
                f"window.daylit.debug.read('{k}')"))[..., :3].astype(np.float64) for k in keys}
            assert not page.errors, page.errors
            page.close()
    negatives = 0
    for key, half in reads["half"].items():
        rgbe = reads["rgbe"][key]
        scale = np.abs(half).max(axis=-1, keepdims=True)
        # half float's own rounding: 2^-11 relative, 6e-8 absolute below 6e-5 (subnormals)
        allowed = scale / 255 + np.abs(half) * 2.0 ** -11 + 6e-8
        err = np.abs(rgbe - half) / allowed
        at = np.unravel_index(err.max(axis=-1).argmax(), err.shape[:2])
        print(f"{key}: worst {err.max():.2f} of the allowance at {at}: {half[at]} {rgbe[at]}, "
              f"{int((half < 0).sum())} negative")
        assert err.max() <= 1.0, key
        assert np.abs(half).max() > 0, key  # relit
        strong = half < -scale / 50
        negatives += int(strong.sum())
        assert (rgbe[strong] < 0).all(), key
    assert negatives > 0  # the site's targets have negative texels for this to check


def meter_level(ground_irradiance, albedo):
    """The documented meter (docs/web.md, Exposure), written here from Krawczyk, Myszkowski &
    Seidel 2005 Eq. 11: the open ground's display level for its irradiance (RGB W/m^2)."""
    luma = np.array([0.2126, 0.7152, 0.0722])
    radiance = float(luma @ (albedo * ground_irradiance)) / math.pi

    def key(lv):
        return 1.03 - 2.0 / (2.0 + math.log10(lv + 1.0))
    return 0.18 * max(key(110.0 * radiance), 0.0) / key(3000.0), radiance


def skies(build):
    """Clear noon (sun 60 degrees up), an overcast noon (CIE overcast, 60 W/m^2 sr at the
    zenith: ~150 W/m^2 on the ground) and dusk (the clear sky with the sun 1 degree up, dimmed
    to a fiftieth: ~2 W/m^2, about 200 lux): sky vectors and suns."""
    from daylit import sky as model

    def clear(azimuth_deg, elevation_deg, scale):
        c = model.clear_sky(azimuth_deg, elevation_deg)
        r = model.patch_mean_radiance(c, build.dome_vertices, include_sun=False) * scale
        s = model.direction_from_azimuth_elevation(azimuth_deg, elevation_deg)
        dni = c.sun.normal_irradiance * scale
        return r, {"direction": s.tolist(), "normalIrradiance": dni.tolist()}

    overcast = model.patch_mean_radiance(model.overcast_sky(60.0), build.dome_vertices)
    return {"clear noon": clear(180.0, 60.0, 1.0), "overcast noon": (overcast, None),
            "dusk": clear(270.0, 1.0, 0.02)}


def test_exposure_follows_the_measured_light(new_page, sun_build, sun_reference):
    """Automatic exposure (no ?exposure) for three lights: an open ground pixel displayed as
    the documented meter says (within 3 codes: the level from the open ground's irradiance,
    computed here, through the display transform), and the picture's mean in the order clear
    noon > overcast noon > dusk, dusk clearly darker (the client before 2026-11-24 showed all
    three with the ground at the same level)."""
    build, _ = sun_reference
    albedo = np.asarray(build.manifest["ground"]["albedo"])
    lights = build.manifest["dome"]["lights"]
    cosine_sr = np.array([light["cosine_weighted_sr"] for light in lights])
    probe = [[-12.0, 0.0, 5.0]]  # open ground, far from both boxes
    means, codes, wants = {}, {}, {}
    with StubServer(sun_build) as server:
        page = new_page(480, 360).open(f"{server.url}/?mode=visit&test")
        for name, (r, sun) in skies(build).items():
            page.page.evaluate("([r, s]) => window.daylit.debug.relight(r, 9, s)",
                               [np.asarray(r, np.float64).ravel().tolist(), sun])
            page.page.evaluate("([p, t]) => window.daylit.debug.setCamera(p, t)",
                               [[-3.0, 18.0, 6.0], [-3.0, 0.0, 0.0]])
            page.page.evaluate("window.daylit.debug.settleExposure()")
            sp = SunPage.__new__(SunPage)
            sp.page = page
            _, hits, shown = sp.at(probe)
            means[name] = float(sp.screen().mean())
            codes[name] = shown[0]
            open_sky = cosine_sr @ np.asarray(r, np.float64)  # the open ground's sky irradiance
            sun_e = 0.0 if sun is None else (np.asarray(sun["normalIrradiance"])
                                             * max(sun["direction"][1], 0.0))
            level, radiance = meter_level(open_sky + sun_e, albedo)
            # the pixel's own irradiance: the open ground's (far from the boxes, in full sun)
            wants[name] = srgb_codes(neutral_tone_map(level / radiance * albedo / math.pi
                                                      * (open_sky + sun_e)))
            print(f"{name}: ground {radiance * 110:.1f} cd/m^2, level {level:.3f}, pixel "
                  f"{shown[0]} reference {np.round(wants[name], 1)}, "
                  f"picture mean {means[name]:.1f}")
            assert hits[0] is not None and hits[0]["role"] in ("ground", "shadowing-plane"), hits
        assert not page.errors, page.errors
    for name in means:
        assert np.abs(codes[name] - wants[name]).max() <= 3.0, (name, codes[name], wants[name])
    assert means["clear noon"] > means["overcast noon"] > means["dusk"], means
    assert means["dusk"] < means["clear noon"] - 20.0, means
    assert means["overcast noon"] > 0.8 * means["clear noon"], means  # dimmer, not black
