"""Writes the occlusion-mask test vectors: ``occlusion_rle_NAME.bin`` (one whole OCCLUSION_MASK
message), ``.json`` (what any message decoder returns, as for every vector in this folder) and
``.mask.json`` (what a mask decoder must return: the mask, or the error it must raise).

``.mask.json``: ``{"width", "height", "people", "set_count", "spans": [[row, x0, x1], ...]}``
with every maximal run of set pixels of a row as ``[row, x0, x1)``, or ``{"error": WORD}`` where
WORD appears in the decoder's error message. ``tests/server/occlusion/test_occlusion_codec.py``
checks that the encoder still produces these bytes and that the decoder reads them; a
JavaScript decoder (web client) should read the same files.

Run from the repository root: ``.venv/bin/python tests/protocol_vectors/occlusion_make_vectors.py``.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from server.occlusion.codec import encode_mask, leb128  # noqa: E402
from server.protocol import MessageType, encode_blob  # noqa: E402

HERE = Path(__file__).resolve().parent
TIME_S = 1750000100.5


def spans(mask: np.ndarray) -> list[list[int]]:
    """Maximal runs of set pixels per row, ``[row, x0, x1)``."""
    out = []
    for row, line in enumerate(np.asarray(mask) != 0):
        padded = np.concatenate([[False], line, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(padded))
        out += [[row, int(a), int(b)] for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return out


def masks() -> dict[str, tuple[np.ndarray, int]]:
    """The masks of the good vectors: (mask, people in front)."""
    empty = np.zeros((3, 4), np.uint8)
    person = np.zeros((4, 8), np.uint8)  # first and last pixel set: a leading zero-length run
    person[0, 0] = 255
    person[1:4, 3:5] = 255
    person[2, 2:6] = 255
    person[3, 7] = 255
    full = np.full((2, 3), 255, np.uint8)
    wide = np.zeros((100, 300), np.uint8)  # runs of 1, 2 and 3 varint bytes
    wide[90:97, 250:260] = 255
    wide[98, 10:150] = 255
    return {
        "empty_4x3": (empty, 0),
        "person_8x4": (person, 2),
        "full_3x2": (full, 1),
        "wide_300x100": (wide, 1),
    }


def vectors() -> dict[str, tuple[bytes, dict, dict]]:
    """name -> (message bytes, message-level expectation, mask-level expectation)."""
    out = {}
    sequence = 100
    for name, (mask, people) in masks().items():
        payload = encode_mask(mask, people)
        out[name] = (payload, {
            "width": mask.shape[1], "height": mask.shape[0], "people": people,
            "set_count": int(np.count_nonzero(mask)), "spans": spans(mask),
        })
    head = struct.pack("<BBHHH", 1, 1, 4, 3, 0)
    out["error_truncated"] = (head + leb128([5]) + b"\x87", {"error": "truncated"})
    out["error_coverage"] = (head + leb128([5, 2]), {"error": "cover"})
    out["error_zero_run"] = (head + leb128([5, 0, 7]), {"error": "zero-length"})
    out["error_version_2"] = (struct.pack("<BBHHH", 2, 1, 4, 3, 0) + leb128([12]),
                              {"error": "version"})
    out["error_encoding_9"] = (struct.pack("<BBHHH", 1, 9, 4, 3, 0) + leb128([12]),
                               {"error": "encoding"})
    out["error_short"] = (head[:5], {"error": "header"})
    result = {}
    for name, (payload, mask_expected) in out.items():
        sequence += 1
        data = encode_blob(MessageType.OCCLUSION_MASK, payload, sequence, TIME_S)
        message = {
            "type": 3, "type_name": "occlusion-mask", "version": 1, "flags": 0,
            "sequence": sequence, "capture_time_s": TIME_S, "count": len(payload),
            "payload_hex": payload.hex(),
        }
        result[f"occlusion_rle_{name}"] = (data, message, mask_expected)
    return result


def main() -> None:
    for name, (data, message, mask_expected) in vectors().items():
        (HERE / f"{name}.bin").write_bytes(data)
        (HERE / f"{name}.json").write_text(json.dumps(message, indent=1) + "\n", "utf-8")
        (HERE / f"{name}.mask.json").write_text(json.dumps(mask_expected) + "\n", "utf-8")
        print(f"{name}: {len(data)} bytes")


if __name__ == "__main__":
    main()
