"""The stored hello (tests/protocol_vectors/hello_kiosk_v3.json, written by hand from
docs/protocol.md): the server's hello function writes exactly it, and every stream it names
is one the server accepts in a subscribe. The JavaScript client reads the same file
(tests/web/test_protocol_js.py) and the real server's hello has its keys
(tests/server/test_occlusion_stream.py)."""

import json
from pathlib import Path

from server import protocol

VECTOR = Path(__file__).resolve().parents[1] / "protocol_vectors" / "hello_kiosk_v3.json"


def load_hello() -> dict:
    return json.loads(VECTOR.read_text())


def test_hello_message_writes_the_stored_hello():
    want = load_hello()
    text = protocol.hello_message(
        scene_id="kiosk-demo", light_count=40, manifest_url="/build/manifest.json",
        source="replay", simulated=False, streams=["light", "site-camera"],
        site_camera={"source": "camera", "size": [1280, 960]}, smoothing_s=2.0,
        server_time_s=1790000000.5,
        extra={"server": "daylit 0.1.0", "asset_query": "v", "views": ["kiosk"]},
        occlusion={"view": "kiosk", "size": [1024, 768]}, version=3)
    assert json.loads(text) == want


def test_every_stream_the_hello_names_is_one_the_server_accepts():
    hello = load_hello()
    names = hello["available_streams"] + hello["streams"]
    assert set(names) <= set(protocol.STREAMS) == {"light", "site-camera", "occlusion"}
    request = json.dumps({"type": "subscribe", "streams": hello["available_streams"]})
    assert protocol.parse_client_message(request).streams == hello["available_streams"]
    assert protocol.parse_streams(",".join(names)) == list(dict.fromkeys(names))
