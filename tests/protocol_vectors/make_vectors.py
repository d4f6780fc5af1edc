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
        "rgb": [[float(v) for v in row] for row in rgb], "saturated": [2],
    })
    rgb10 = (np.arange(30, dtype=np.float32).reshape(10, 3) * 0.25).astype(np.float32)
    sat10 = np.zeros(10, bool)
    sat10[[0, 9]] = True
    data = encode_light(rgb10, sat10, 4294967295, 1767225600.0, Flags.REPLAY)
    out["light_10_bitmask_two_bytes"] = (data, {
        "type": 1, "type_name": "light", "version": 1, "flags": 10, "stale": False,
        "saturated_flag": True, "simulated": False, "replay": True, "sequence": 4294967295,
        "capture_time_s": 1767225600.0, "count": 10,
        "rgb": [[float(v) for v in row] for row in rgb10], "saturated": [0, 9],
    })
    data = encode_light(np.full((3, 3), 2.5, np.float32), np.zeros(3, bool), 0, 0.0)
    out["light_3_plain"] = (data, {
        "type": 1, "type_name": "light", "version": 1, "flags": 0, "stale": False,
        "saturated_flag": False, "simulated": False, "replay": False, "sequence": 0,
        "capture_time_s": 0.0, "count": 3, "rgb": [[2.5, 2.5, 2.5]] * 3, "saturated": [],
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
    good = out["light_3_plain"][0]
    out["error_bad_magic"] = (b"XXXX" + good[4:], {"error": "magic"})
    out["error_version_2"] = (good[:4] + bytes([2]) + good[5:], {"error": "version"})
    out["error_truncated"] = (good[:-3], {"error": "bytes"})
    out["error_short_header"] = (good[:10], {"error": "header"})
    return out


def main() -> None:
    for name, (data, expected) in vectors().items():
        (HERE / f"{name}.bin").write_bytes(data)
        (HERE / f"{name}.json").write_text(json.dumps(expected, indent=1) + "\n", "utf-8")
        print(f"{name}: {len(data)} bytes")


if __name__ == "__main__":
    main()
