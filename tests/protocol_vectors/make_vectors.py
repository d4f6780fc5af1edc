"""Writes the protocol test vectors: ``NAME.bin`` (one binary message) + ``NAME.json``.

The JSON holds what a decoder must return (or the error it must raise). Values are chosen to be
exact in float32 so both languages can compare exactly. ``tests/server/test_protocol.py`` checks
that the encoder still produces these bytes, and the Python and JavaScript decoders read them.

Run from the repository root: ``.venv/bin/python tests/protocol_vectors/make_vectors.py``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from server.protocol import Flags, MessageType, encode_blob, encode_light  # noqa: E402

HERE = Path(__file__).resolve().parent


def vectors() -> dict[str, tuple[bytes, dict]]:
    out = {}
    rgb = np.array(
        [[0.5, 1.25, 3.0], [12.5, 0.15625, 0.0], [1024.0, 2048.5, 4096.25], [1e-3, 2.0, 7.75]],
        dtype=np.float32,
    )
    sat = np.array([False, False, True, False])
    data = encode_light(rgb, sat, 7, 1750000000.25, Flags.STALE | Flags.SIMULATED)
    out["light_4_stale_saturated"] = (data, {
        "type": 1, "type_name": "light", "version": 1, "flags": 7, "stale": True,
        "saturated_flag": True, "simulated": True, "replay": False, "sequence": 7,
        "capture_time_s": 1750000000.25, "count": 4,
        "rgb": [[float(v) for v in row] for row in rgb], "saturated": [2], "sun": None,
    })
    rgb10 = (np.arange(30, dtype=np.float32).reshape(10, 3) * 0.25).astype(np.float32)
    sat10 = np.zeros(10, bool)
    sat10[[0, 9]] = True
    data = encode_light(rgb10, sat10, 4294967295, 1767225600.0, Flags.REPLAY)
    out["light_10_bitmask_two_bytes"] = (data, {
        "type": 1, "type_name": "light", "version": 1, "flags": 10, "stale": False,
        "saturated_flag": True, "simulated": False, "replay": True, "sequence": 4294967295,
        "capture_time_s": 1767225600.0, "count": 10,
        "rgb": [[float(v) for v in row] for row in rgb10], "saturated": [0, 9], "sun": None,
    })
    data = encode_light(np.full((3, 3), 2.5, np.float32), np.zeros(3, bool), 0, 0.0)
    out["light_3_plain"] = (data, {
        "type": 1, "type_name": "light", "version": 1, "flags": 0, "stale": False,
        "saturated_flag": False, "simulated": False, "replay": False, "sequence": 0,
        "capture_time_s": 0.0, "count": 3, "rgb": [[2.5, 2.5, 2.5]] * 3, "saturated": [],
        "sun": None,
    })
    jpeg = bytes([0xFF, 0xD8, 0xFF, 0xE0, 0, 16, 74, 70, 73, 70, 0, 1, 0xFF, 0xD9])
    data = encode_blob(MessageType.SITE_CAMERA, jpeg, 42, 1750000001.5)
    out["site_camera_jpeg"] = (data, {
        "type": 2, "type_name": "site-camera", "version": 1, "flags": 0, "sequence": 42,
        "capture_time_s": 1750000001.5, "count": len(jpeg), "payload_hex": jpeg.hex(),
    })
    data = encode_blob(MessageType.OCCLUSION_MASK, bytes(range(8)), 1, 1750000002.0)
    out["occlusion_mask_reserved"] = (data, {
        "type": 3, "type_name": "occlusion-mask", "version": 1, "flags": 0, "sequence": 1,
        "capture_time_s": 1750000002.0, "count": 8, "payload_hex": bytes(range(8)).hex(),
    })
    out.update(version2_vectors())
    out.update(version3_vectors())
    good = out["light_3_plain"][0]
    out["error_bad_magic"] = (b"XXXX" + good[4:], {"error": "magic"})
    out["error_version_4"] = (good[:4] + bytes([4]) + good[5:], {"error": "version"})
    # A version-1 body under a version-2 header: 28 bytes short of the sun.
    out["error_light2_without_sun"] = (good[:4] + bytes([2]) + good[5:], {"error": "bytes"})
    out["error_truncated"] = (good[:-3], {"error": "bytes"})
    out["error_short_header"] = (good[:10], {"error": "header"})
    # A version-2 body (float32 sky) under a version-3 header: 8 bytes a light too long.
    v2 = out["light2_sun_measured"][0]
    out["error_light3_float_body"] = (v2[:4] + bytes([3]) + v2[5:], {"error": "bytes"})
    return out


def version2_vectors() -> dict[str, tuple[bytes, dict]]:
    """LIGHT messages of protocol version 2: the sun first, then the sky without its disc."""
    out = {}
    # 0.6, 0.8 are not exact in float32: a direction of exact values, unit length.
    direction = np.array([0.375, 0.5, -0.78062475], np.float32)  # az ~ 25.7, el ~ 30
    sky = np.array([[10.5, 12.25, 20.0], [8.0, 9.5, 16.75], [0.0, 0.125, 3.5]], np.float32)

    def sun(d, e, source):
        return SimpleNamespace(direction=np.asarray(d, np.float32),
                               normal_irradiance_w_m2=np.asarray(e, np.float32), source=source)

    def expected(data_flags, seq, t, rgb, sat, sun_dict, **flags):
        return {
            "type": 1, "type_name": "light", "version": 2, "flags": data_flags,
            "stale": flags.get("stale", False), "saturated_flag": bool(sat),
            "simulated": flags.get("simulated", False), "replay": flags.get("replay", False),
            "sequence": seq, "capture_time_s": t, "count": len(rgb),
            "rgb": [[float(v) for v in row] for row in rgb], "saturated": sat, "sun": sun_dict,
        }

    e = [850.5, 812.25, 760.0]
    data = encode_light(sky, np.zeros(3, bool), 11, 1790000000.5, Flags.REPLAY, version=2,
                        sun=sun(direction, e, 1))
    out["light2_sun_measured"] = (data, expected(8, 11, 1790000000.5, sky, [], {
        "direction": [float(v) for v in direction], "normal_irradiance": e,
        "source": "measured", "estimated": False}, replay=True))
    e = [512.0, 480.5, 421.75]
    sat = np.array([False, True, False])
    data = encode_light(sky, sat, 12, 1790000001.0, Flags.SIMULATED | Flags.SUN_ESTIMATED,
                        version=2, sun=sun(direction, e, 2))
    out["light2_sun_estimated"] = (data, expected(38, 12, 1790000001.0, sky, [1], {
        "direction": [float(v) for v in direction], "normal_irradiance": e,
        "source": "model", "estimated": True}, simulated=True))
    night = np.full((3, 3), 0.015625, np.float32)
    data = encode_light(night, np.zeros(3, bool), 13, 1790040000.0, Flags.STALE, version=2)
    out["light2_night_no_sun"] = (data, expected(1, 13, 1790040000.0, night, [], {
        "direction": [0.0, 0.0, 0.0], "normal_irradiance": [0.0, 0.0, 0.0],
        "source": "none", "estimated": False}, stale=True))
    return out


def version3_vectors() -> dict[str, tuple[bytes, dict]]:
    """LIGHT messages of protocol version 3: the sun as in version 2, the sky in float16.

    The expected values are written out by hand (tests/protocol_vectors/README.md works the
    codes), not taken from the encoder: ``light3_sun_measured`` holds values float16 carries
    exactly, ``light3_rounding_clipped`` values it rounds (1.999 -> 1.9990234375, 3.1 ->
    3.099609375, 1e-6 -> 17 x 2^-24, a subnormal), a negative one, and one it clips (1e6 ->
    65504, marked saturated).
    """
    out = {}
    direction = np.array([0.375, 0.5, -0.78062475], np.float32)
    sky = np.array([[10.5, 12.25, 20.0], [8.0, 9.5, 16.75], [0.0, 0.125, 3.5]], np.float32)
    sun = SimpleNamespace(direction=direction, normal_irradiance_w_m2=np.array(
        [850.5, 812.25, 760.0], np.float32), source=1)
    data = encode_light(sky, np.zeros(3, bool), 11, 1790000000.5, Flags.REPLAY, version=3,
                        sun=sun)
    out["light3_sun_measured"] = (data, {
        "type": 1, "type_name": "light", "version": 3, "flags": 8, "stale": False,
        "saturated_flag": False, "simulated": False, "replay": True, "sequence": 11,
        "capture_time_s": 1790000000.5, "count": 3,
        "rgb": [[10.5, 12.25, 20.0], [8.0, 9.5, 16.75], [0.0, 0.125, 3.5]], "saturated": [],
        "sun": {"direction": [0.375, 0.5, -0.7806247472763062],
                "normal_irradiance": [850.5, 812.25, 760.0], "source": "measured",
                "estimated": False}})
    rough = np.array([[1.999, -0.5, 0.0], [100.0, 50.0, 3.1], [1e6, 1.0, 1e-6]])
    data = encode_light(rough, np.zeros(3, bool), 14, 1790000002.0, Flags.SIMULATED,
                        version=3)
    out["light3_rounding_clipped"] = (data, {
        "type": 1, "type_name": "light", "version": 3, "flags": 6, "stale": False,
        "saturated_flag": True, "simulated": True, "replay": False, "sequence": 14,
        "capture_time_s": 1790000002.0, "count": 3,
        "rgb": [[1.9990234375, -0.5, 0.0], [100.0, 50.0, 3.099609375],
                [65504.0, 1.0, 17 * 2.0**-24]], "saturated": [2],
        "sun": {"direction": [0.0, 0.0, 0.0], "normal_irradiance": [0.0, 0.0, 0.0],
                "source": "none", "estimated": False}})
    return out


def main() -> None:
    for stale in HERE.glob("error_version_3.*"):  # renamed: version 3 exists now
        stale.unlink()
    for name, (data, expected) in vectors().items():
        (HERE / f"{name}.bin").write_bytes(data)
        (HERE / f"{name}.json").write_text(json.dumps(expected, indent=1) + "\n", "utf-8")
        print(f"{name}: {len(data)} bytes")


if __name__ == "__main__":
    main()
