"""The wire format: encoder output is pinned by the stored vectors, the decoder reads them."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from server import protocol
from server.protocol import ProtocolError, decode, parse_client_message, parse_streams

VECTORS = Path(__file__).resolve().parents[1] / "protocol_vectors"


def load_vectors():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_vectors", VECTORS / "make_vectors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.vectors()


def test_encoder_reproduces_the_stored_vectors():
    for name, (data, expected) in load_vectors().items():
        assert (VECTORS / f"{name}.bin").read_bytes() == data, name
        assert json.loads((VECTORS / f"{name}.json").read_text()) == expected, name


@pytest.mark.parametrize("path", sorted(VECTORS.glob("*.bin")), ids=lambda p: p.stem)
def test_python_decoder_reads_the_vectors(path):
    expected = json.loads(path.with_suffix(".json").read_text())
    data = path.read_bytes()
    if "error" in expected:
        with pytest.raises(ProtocolError, match=expected["error"]):
            decode(data)
        return
    m = decode(data)
    assert (m.type, m.type_name, m.version, m.flags, m.sequence, m.capture_time_s, m.count) == (
        expected["type"], expected["type_name"], expected["version"], expected["flags"],
        expected["sequence"], expected["capture_time_s"], expected["count"])
    if m.type == protocol.MessageType.LIGHT:
        assert m.rgb.tolist() == expected["rgb"]
        assert np.flatnonzero(m.saturated).tolist() == expected["saturated"]
        assert bool(m.flags & protocol.Flags.STALE) == expected["stale"]
        assert bool(m.flags & protocol.Flags.SIMULATED) == expected["simulated"]
        if expected["sun"] is None:
            assert m.version == 1 and m.sun is None
        else:
            sun = expected["sun"]
            assert m.version >= 2
            assert m.sun.direction.tolist() == sun["direction"]
            assert m.sun.normal_irradiance_w_m2.tolist() == sun["normal_irradiance"]
            assert (m.sun.source_name, m.sun.estimated) == (sun["source"], sun["estimated"])
    else:
        assert m.payload.hex() == expected["payload_hex"]


def hand_pinned_bytes():
    """(file, offset, bytes) from the fenced lines of protocol_vectors/README.md."""
    pinned = []
    for line in (VECTORS / "README.md").read_text().splitlines():
        m = re.match(r"^(\w+\.bin) \+(\d+)\s+((?:[0-9a-f]{2} ?)+)\s*\|", line)
        if m:
            pinned.append((m[1], int(m[2]), bytes.fromhex(m[3])))
    return pinned


def test_vectors_match_the_hand_pinned_bytes():
    pinned = hand_pinned_bytes()
    files = {name for name, _, _ in pinned}
    # Every LIGHT, SITE_CAMERA and error vector is pinned, and every version.
    assert files >= {p.name for p in VECTORS.glob("light*.bin")} | {
        "site_camera_jpeg.bin", "occlusion_mask_reserved.bin"} | {
        p.name for p in VECTORS.glob("error_*.bin") if p.stat().st_size >= 16}
    assert {data[4] for name, offset, data in pinned if offset == 0 and len(data) > 4} >= {
        1, 2, 3}
    for name, offset, want in pinned:
        got = (VECTORS / name).read_bytes()[offset:offset + len(want)]
        assert got == want, (name, offset, got.hex(" "), want.hex(" "))


def test_header_layout_is_24_bytes_and_light_size_formula():
    assert protocol.HEADER_BYTES == 24
    data = protocol.encode_light(np.ones((400, 3)), np.zeros(400, bool), 1, 2.0)
    assert len(data) == protocol.light_message_bytes(400, version=1) == 24 + 4800 + 50
    data = protocol.encode_light(np.ones((400, 3)), np.zeros(400, bool), 1, 2.0, version=2)
    assert len(data) == protocol.light_message_bytes(400, version=2) == 52 + 4800 + 50
    data = protocol.encode_light(np.ones((400, 3)), np.zeros(400, bool), 1, 2.0, version=3)
    assert len(data) == protocol.light_message_bytes(400) == 52 + 2400 + 50 == 2502


def test_version_3_carries_the_sky_within_the_stated_error_and_the_sun_exactly():
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    sky = (10.0 ** rng.uniform(-2, 3, (400, 1)) * rng.uniform(0.1, 1.0, (400, 3))).astype(
        np.float32)
    sun = SimpleNamespace(direction=np.array([0.1, 0.9, -0.3], np.float32),
                          normal_irradiance_w_m2=np.array([901.123, 850.456, 799.789],
                                                          np.float32), source=1)
    m3 = decode(protocol.encode_light(sky, np.zeros(400, bool), 5, 9.0, version=3, sun=sun))
    m2 = decode(protocol.encode_light(sky, np.zeros(400, bool), 5, 9.0, version=2, sun=sun))
    assert np.array_equal(m2.rgb, sky)
    # Every channel on its own within 2^-11 (docs/protocol.md), and not merely equal to it.
    rel = np.abs(m3.rgb.astype(np.float64) - sky) / sky
    assert rel.max() <= 2.0**-11 and rel.max() > 0.9 * 2.0**-11
    for field in ("direction", "normal_irradiance_w_m2"):
        assert np.array_equal(getattr(m3.sun, field), getattr(m2.sun, field))
    assert m3.sun.normal_irradiance_w_m2.tolist() == sun.normal_irradiance_w_m2.tolist()
    assert not m3.saturated.any()


def test_version_1_drops_the_flags_it_does_not_know():
    data = protocol.encode_light(np.ones((2, 3)), np.zeros(2, bool), 1, 2.0,
                                 protocol.Flags.SUN_ESTIMATED | protocol.Flags.STALE, version=1)
    assert decode(data).flags == protocol.Flags.STALE
    with pytest.raises(ValueError, match="version"):
        protocol.encode_light(np.ones((2, 3)), np.zeros(2, bool), 1, 2.0, version=4)


def test_fold_sun_puts_the_irradiance_over_its_patch_solid_angle():
    from types import SimpleNamespace

    sky = np.ones((3, 3), np.float32)
    sun = SimpleNamespace(normal_irradiance_w_m2=np.array([900.0, 850.0, 800.0]))
    folded = protocol.fold_sun(sky, sun, 1, np.array([0.5, 0.25, 0.125]))
    assert folded.tolist() == [[1, 1, 1], [3601, 3401, 3201], [1, 1, 1]]
    assert protocol.fold_sun(sky, None, 1, np.ones(3)).tolist() == sky.tolist()


@pytest.mark.parametrize(("text", "version"),
                         [(None, 1), ("", 1), ("1", 1), ("2", 2), ("3", 3)])
def test_protocol_query_parameter(text, version):
    assert protocol.parse_protocol(text) == version


@pytest.mark.parametrize("text", ["7", "two", "0", "4"])
def test_unknown_protocol_versions_are_refused(text):
    with pytest.raises(ProtocolError, match="protocol"):
        protocol.parse_protocol(text)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("hello", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"type": "dance"}', "unknown message type"),
        ('{"type": "subscribe", "streams": "light"}', "list"),
        ('{"type": "subscribe", "streams": ["weather"]}', "unknown stream"),
        ('{"type": "ping", "id": {"a": 1}}', "ping id"),
        ('{"type": "ping", "id": 1, "x": 2}', "unexpected keys"),
        ('{"type": "ping", "id": "' + "x" * 2000 + '"}', "too long"),
    ],
)
def test_client_messages_outside_the_protocol_are_refused(text, reason):
    with pytest.raises(ProtocolError, match=reason):
        parse_client_message(text)


def test_client_messages_in_the_protocol_are_accepted():
    m = parse_client_message('{"type": "subscribe", "streams": ["light", "site-camera"]}')
    assert m.streams == ["light", "site-camera"]
    assert parse_client_message('{"type": "ping", "id": 17}').id == 17
    assert parse_streams(None) == ["light"]
    assert parse_streams("site-camera,light") == ["site-camera", "light"]
    with pytest.raises(ProtocolError):
        parse_streams("light,tv")
