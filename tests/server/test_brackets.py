"""Bracketed exposures (issue 15 item 2a): the sky of test_sunmeter (this suite's own lens,
sky and limb-darkened disc, not server.fisheye or server.simsky) photographed by this file's
own 8-bit camera at several exposure times (its own gamma or sRGB encoding, noise, rounding,
clipping, optionally JPEG, its own EXIF writer), then read, merged and measured by the server.
Answers: the disc's DNI as drawn, its direction from pvlib, the clear-sky DNI from pvlib."""

import asyncio
import datetime as dt
import json
import struct
import zlib

import cv2
import numpy as np
import pytest

from bake.dome import Dome
from daylit.sun import SunSource
from server.brackets import BracketError, read_bracket
from server.measure import Frame, SkyMeter
from server.photometry import Photometry, inverse_response_table
from server.sources.replay import ReplaySource
from server.sunmeter import SunMeter
from tests.server.test_sunmeter import (
    DNI_TRUE,
    SITE,
    WHEN,
    angle_deg,
    assert_replayed_true_sun,
    clear_sky_dni,
    render,
    true_sun,
)

K = 0.75  # the test camera: linear value per second of exposure per unit radiance
# Exposure times 1/N s, 4.4 stops apart: the longest exposes the sky, the shortest the disc
# (an ND filter's work on a real camera). Exactly these rationals go into EXIF.
DENOMINATORS = [60, 1300, 28000, 600000, 13000000]
CLIPPING = [60, 1300, 28000]  # the shortest still clips the disc 300 times over


@pytest.fixture(scope="module")
def sky():
    return render()


@pytest.fixture(scope="module")
def dome():
    return Dome.for_light_count(160).vertices


def encode(linear: np.ndarray, curve: str, rng) -> np.ndarray:
    """The test camera's 8-bit codes (RGB) of linear values (full scale 1)."""
    noisy = linear + rng.normal(0.0, 0.002, linear.shape) * np.sqrt(np.clip(linear, 0, 1))
    x = np.clip(noisy, 0.0, 1.0)
    if curve == "srgb":
        v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    else:  # "gamma:2.2"
        v = x ** (1 / 2.2)
    return np.round(v * 255.0).astype(np.uint8)


def exif_tiff(exposure: tuple[int, int], when: str, offset: str) -> bytes:
    """A little-endian TIFF block: IFD0 -> Exif IFD with ExposureTime, DateTimeOriginal and
    OffsetTimeOriginal (written here, byte by byte)."""
    date = when.encode() + b"\x00"  # 20 bytes
    off = offset.encode() + b"\x00"  # 7 bytes
    ifd0 = 8
    exif_ifd = ifd0 + 2 + 12 + 4
    data_at = exif_ifd + 2 + 3 * 12 + 4
    tiff = b"II*\x00" + struct.pack("<I", ifd0)
    tiff += struct.pack("<H", 1) + struct.pack("<HHII", 0x8769, 4, 1, exif_ifd)
    tiff += struct.pack("<I", 0)
    tiff += struct.pack("<H", 3)
    tiff += struct.pack("<HHII", 0x829A, 5, 1, data_at)
    tiff += struct.pack("<HHII", 0x9003, 2, len(date), data_at + 8)
    tiff += struct.pack("<HHII", 0x9011, 2, len(off), data_at + 8 + len(date))
    tiff += struct.pack("<I", 0)
    return tiff + struct.pack("<II", *exposure) + date + off


def with_exif(data: bytes, fmt: str, tiff: bytes) -> bytes:
    """A JPEG with an APP1 Exif segment after its SOI, or a PNG with an eXIf chunk after its
    IHDR."""
    if fmt == "jpg":
        body = b"Exif\x00\x00" + tiff
        return data[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + data[2:]
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff
    chunk += struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    at = 8 + 8 + 13 + 4  # signature, IHDR
    return data[:at] + chunk + data[at:]


def write_bracket(folder, sky: np.ndarray, denominators, curve="gamma:2.2", fmt="png",
                  times_in="sidecar", seed=0):
    """The bracket's files, 1/N s each; the times (and the sky's time) in ``bracket.json``
    or in each image's EXIF (``times_in="exif"``)."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    local = (WHEN + dt.timedelta(hours=9)).strftime("%Y:%m:%d %H:%M:%S")
    names = []
    for k, n in enumerate(denominators):
        codes = encode(sky * (K * 1.0 / n), curve, rng)[:, :, ::-1]  # BGR for OpenCV
        params = [cv2.IMWRITE_JPEG_QUALITY, 90] if fmt == "jpg" else []
        ok, buf = cv2.imencode(f".{fmt}", codes, params)
        data = buf.tobytes()
        if times_in == "exif":
            data = with_exif(data, fmt, exif_tiff((1, n), local, "+09:00"))
        name = f"exp{k}.{fmt}"
        (folder / name).write_bytes(data)
        names.append(name)
    if times_in == "sidecar":
        (folder / "bracket.json").write_text(json.dumps({
            "exposure_s": {name: 1.0 / n for name, n in zip(names, denominators, strict=True)},
            "time": WHEN.isoformat()}))
    return folder


def measure(folder, dome, curve="gamma:2.2"):
    merged = read_bracket(folder, inverse_response_table(curve))
    assert merged.sky_time_s == WHEN.timestamp()
    meter = SkyMeter(dome, Photometry(response=curve, exposure=K),
                     sun=SunMeter(*SITE, linke_turbidity=3.0))
    return meter.measure(Frame(merged.image, 0.0, bgr=True, hdr=True,
                               sky_time_s=merged.sky_time_s, clip_level=merged.clip_level))


@pytest.mark.parametrize(("curve", "times_in"), [("gamma:2.2", "sidecar"), ("srgb", "exif")],
                         ids=["gamma-sidecar", "srgb-exif"])
def test_a_bracket_measures_the_sun_unclipped(tmp_path, sky, dome, curve, times_in):
    folder = write_bracket(tmp_path / "b", sky, DENOMINATORS, curve, "png", times_in)
    m = measure(folder, dome, curve)
    sun = m.sun
    assert sun.source == SunSource.MEASURED and sun.direction_measured
    np.testing.assert_allclose(sun.normal_irradiance_w_m2, DNI_TRUE, rtol=0.03)
    assert angle_deg(sun.direction, true_sun()) < 0.5
    assert not m.saturated.any()


def test_a_bracket_that_clips_the_disc_is_the_clear_sky_estimate(tmp_path, sky, dome):
    """JPEG (quality 90) exposures with their times in EXIF: the shortest clips the disc."""
    m = measure(write_bracket(tmp_path / "b", sky, CLIPPING, "srgb", "jpg", "exif"), dome,
                "srgb")
    sun = m.sun
    assert sun.source == SunSource.MODEL and not sun.direction_measured
    assert sun.visible_fraction > 0.9
    luminance = float(sun.normal_irradiance_w_m2 @ [0.2126, 0.7152, 0.0722])
    assert luminance == pytest.approx(clear_sky_dni() * sun.visible_fraction, rel=0.005)
    assert angle_deg(sun.direction, true_sun()) < 0.01
    assert not m.saturated.any()  # the clipped disc was replaced, nothing else clipped


def small_exposures(folder, sizes, sidecar) -> None:
    folder.mkdir(parents=True)
    for k, (w, h) in enumerate(sizes):
        cv2.imwrite(str(folder / f"{k}.png"), np.full((h, w, 3), 40 + 50 * k, np.uint8))
    if sidecar is not None:
        (folder / "bracket.json").write_text(json.dumps(sidecar))


@pytest.mark.parametrize(("sizes", "sidecar", "message"), [
    ([(8, 8)], {"exposure_s": [0.01]}, "a bracket needs at least 2 exposures"),
    ([(8, 8), (8, 6)], {"exposure_s": [0.01, 0.1]}, "differ in size: 0.png is 8x8, 1.png 8x6"),
    ([(8, 8), (8, 8)], {"exposure_s": {"0.png": 0.01}}, "1.png: no exposure time"),
    ([(8, 8), (8, 8)], None, "0.png: no exposure time (no EXIF ExposureTime"),
    ([(8, 8), (8, 8)], {"exposure_s": [0.01, 0]}, "must be a positive number of seconds"),
    ([(8, 8), (8, 8)], {"exposure_s": [0.01, 0.1], "time": "2026-06-21T10:00"},
     "needs its UTC offset"),
    ([(8, 8), (8, 8)], {"exposures": [0.01, 0.1]}, "unknown key(s) exposures"),
], ids=["one-exposure", "sizes", "a-missing-time", "no-times", "zero-time", "naive-time",
        "typo"])
def test_a_bad_bracket_says_what_is_wrong(tmp_path, sizes, sidecar, message):
    small_exposures(tmp_path / "b", sizes, sidecar)
    with pytest.raises(BracketError) as info:
        read_bracket(tmp_path / "b", inverse_response_table("srgb"))
    assert message in str(info.value)
    # The replay skips it with that reason in its status, and plays on.
    source = ReplaySource(tmp_path)
    assert source.read_entry(tmp_path / "b") is None
    status = source.status()
    assert status["skipped_frames"] == 1 and message in status["last_error"]


async def test_a_replayed_bracket_streams_the_measured_sun(aiohttp_client, build_dir, tmp_path,
                                                          sky):
    """The whole chain: a replay folder with a bracket folder (and a broken one, skipped) ->
    the server -> a version-2 client. (The test build's site is Nara, as here.)"""
    from server.app import create_app
    from tests.server.helpers import first_light_v2, settings_for

    folder = tmp_path / "replay"
    write_bracket(folder / "a", sky, DENOMINATORS)
    small_exposures(folder / "b", [(8, 8)], {"exposure_s": [0.01]})
    app = create_app(build_dir, settings_for(tmp_path, sky__source=f"replay:{folder}",
                                             sky__response="gamma:2.2", sky__exposure=K))
    client = await aiohttp_client(app)
    ws, m = await first_light_v2(client)
    assert_replayed_true_sun(m)
    for _ in range(100):
        status = await (await client.get("/api/status")).json()
        if status["skipped_frames"]:
            break
        await asyncio.sleep(0.1)
    assert "a bracket needs at least 2 exposures" in status["last_error"]
    await ws.close()
