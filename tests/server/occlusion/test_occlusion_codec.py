"""The occlusion mask's wire format: round trips, and the stored test vectors.

Vectors: ``tests/protocol_vectors/occlusion_rle_*`` (see occlusion_make_vectors.py). Each
``.bin`` is a whole OCCLUSION_MASK message (the generic message decoders of
tests/server/test_protocol.py and tests/web/test_protocol_js.py read it as well); its
``.mask.json`` holds the mask a mask decoder must return, or the error it must raise.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from server import protocol
from server.occlusion.codec import (
    HEADER_BYTES,
    MaskCodecError,
    decode_mask,
    encode_mask,
    encode_message,
    leb128,
    parse_leb128,
    runs_of,
)

VECTORS = Path(__file__).resolve().parents[2] / "protocol_vectors"
NAMES = sorted(p.name[: -len(".mask.json")] for p in VECTORS.glob("occlusion_rle_*.mask.json"))


def load_generator():
    spec = importlib.util.spec_from_file_location(
        "occlusion_make_vectors", VECTORS / "occlusion_make_vectors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def mask_from_spans(expected: dict) -> np.ndarray:
    mask = np.zeros((expected["height"], expected["width"]), np.uint8)
    for row, x0, x1 in expected["spans"]:
        mask[row, x0:x1] = 255
    return mask


@pytest.mark.parametrize("shape", [(1, 1), (3, 4), (270, 480), (512, 1024), (7, 65535)])
@pytest.mark.parametrize("fill", [0.0, 0.002, 0.3, 1.0])
def test_masks_round_trip(shape, fill):
    rng = np.random.default_rng(abs(hash((shape, fill))) % 2**32)
    mask = rng.random(shape) < fill
    mask[:, : shape[1] // 3] = False  # long runs as well as short ones
    payload = encode_mask(mask.astype(np.uint8) * 255, people_in_front=3)
    decoded, people = decode_mask(payload)
    assert people == 3
    assert decoded.dtype == np.uint8 and decoded.shape == shape
    assert np.array_equal(decoded > 0, mask)


def test_a_person_costs_bytes_in_proportion_to_their_outline_not_their_area():
    mask = np.zeros((512, 1024), np.uint8)
    mask[100:400, 300:380] = 255  # 300 rows, 24000 pixels
    payload = encode_mask(mask)
    assert len(payload) <= HEADER_BYTES + 6 + 300 * 3  # two runs (3 bytes) per row
    assert len(encode_mask(np.zeros((512, 1024), np.uint8))) == HEADER_BYTES + 3


def test_runs_start_with_a_clear_run_and_add_up():
    mask = np.array([[1, 1, 0, 1]], bool)
    assert runs_of(mask).tolist() == [0, 2, 1, 1]
    assert runs_of(~mask).tolist() == [2, 1, 1]
    assert runs_of(np.zeros((2, 2))).tolist() == [4]


def test_leb128_matches_the_textbook_examples():
    assert leb128([0, 1, 127, 128, 300, 624485]).hex() == "00017f8001ac02e58e26"
    values = np.array([0, 127, 128, 16383, 16384, 2**21, 2**28 - 1, 2**32 - 1])
    assert parse_leb128(leb128(values)).tolist() == values.tolist()


@pytest.mark.parametrize("bad", [np.zeros((0, 4)), np.zeros(5), np.zeros((2, 70000)),
                                 np.zeros((2, 2, 3))])
def test_encoder_refuses_what_the_layout_cannot_carry(bad):
    with pytest.raises(ValueError):
        encode_mask(bad)


def test_generator_reproduces_the_stored_vectors():
    generated = load_generator().vectors()
    assert sorted(generated) == NAMES and len(NAMES) >= 10
    for name, (data, message, mask_expected) in generated.items():
        assert (VECTORS / f"{name}.bin").read_bytes() == data, name
        assert json.loads((VECTORS / f"{name}.json").read_text()) == message, name
        assert json.loads((VECTORS / f"{name}.mask.json").read_text()) == mask_expected, name


@pytest.mark.parametrize("name", NAMES)
def test_mask_decoder_reads_the_vectors(name):
    message = protocol.decode((VECTORS / f"{name}.bin").read_bytes())
    assert message.type == protocol.MessageType.OCCLUSION_MASK
    expected = json.loads((VECTORS / f"{name}.mask.json").read_text())
    if "error" in expected:
        with pytest.raises(MaskCodecError, match=expected["error"]):
            decode_mask(message.payload)
        return
    mask, people = decode_mask(message.payload)
    assert people == expected["people"]
    assert mask.shape == (expected["height"], expected["width"])
    assert int(np.count_nonzero(mask)) == expected["set_count"]
    assert np.array_equal(mask, mask_from_spans(expected))
    # The encoder gives back the very same bytes (one canonical encoding per mask).
    assert encode_mask(mask, people) == message.payload


def test_whole_message_wraps_the_payload_in_the_light_stream_header():
    mask = np.zeros((4, 6), np.uint8)
    mask[1:3, 2:4] = 255
    data = encode_message(mask, sequence=9, capture_time_s=1750000000.5, people_in_front=1)
    message = protocol.decode(data)
    assert (message.type, message.sequence, message.capture_time_s) == (3, 9, 1750000000.5)
    assert message.type_name == "occlusion-mask"
    decoded, people = decode_mask(message.payload)
    assert people == 1 and np.array_equal(decoded, mask)
