"""GET /ws/light: the same vectors for everyone, newest-only, misbehaving clients closed alone."""

import asyncio
import json

import aiohttp
import numpy as np
import pytest
from aiohttp import WSMsgType

from server import protocol
from server.app import HUB, create_app
from tests.server.helpers import (
    ManualSource,
    raw_websocket_that_never_reads,
    settings_for,
    wait_for,
)


@pytest.fixture
def make_client(aiohttp_client, build_dir, tmp_path):
    async def make(source=None, site_source=None, **overrides):
        source = source or ManualSource()
        app = create_app(build_dir, settings_for(tmp_path, **overrides), sky_source=source,
                         site_source=site_source)
        client = await aiohttp_client(app)
        return client, app, source

    return make


def publish(app, value=1.0, flags=0):
    n = 40
    return app[HUB].publish_light(np.full((n, 3), value, np.float32), np.zeros(n, bool),
                                  123.5, flags)


async def connect(client, query=""):
    ws = await client.ws_connect("/ws/light" + query)
    hello = json.loads((await ws.receive(timeout=10)).data)
    return ws, hello


async def next_binary(ws, timeout=10.0):
    while True:
        msg = await ws.receive(timeout=timeout)
        if msg.type == WSMsgType.BINARY:
            return protocol.decode(msg.data)
        assert msg.type == WSMsgType.TEXT, msg


async def test_hello_comes_first_and_describes_the_stream(make_client):
    client, app, _ = await make_client()
    ws, hello = await connect(client)
    assert hello["type"] == "hello" and hello["protocol"] == 1
    assert hello["scene"] == "testsite" and hello["lights"] == 40
    assert hello["manifest"] == "/build/manifest.json"
    assert hello["streams"] == ["light"] and hello["available_streams"] == ["light"]
    assert hello["binary"]["header_bytes"] == 24
    seq = publish(app, 2.5)
    m = await next_binary(ws)
    assert m.sequence == seq and m.count == 40 and np.all(m.rgb == 2.5)
    assert m.capture_time_s == 123.5
    await ws.close()


async def test_a_late_client_gets_the_newest_vector_at_once(make_client):
    client, app, _ = await make_client()
    publish(app, 1.0)
    last = publish(app, 3.0)
    ws, _ = await connect(client)
    m = await next_binary(ws)
    assert m.sequence == last and np.all(m.rgb == 3.0)
    await ws.close()


async def test_two_clients_receive_the_same_sequence_numbers(make_client):
    client, app, _ = await make_client()
    (a, _), (b, _) = await connect(client), await connect(client)
    seen_a, seen_b, sent = [], [], []
    for k in range(6):
        sent.append(publish(app, float(k)))
        ma, mb = await next_binary(a), await next_binary(b)
        seen_a.append((ma.sequence, ma.rgb[0, 0]))
        seen_b.append((mb.sequence, mb.rgb[0, 0]))
    assert [s for s, _ in seen_a] == sent == [s for s, _ in seen_b]
    assert seen_a == seen_b
    await a.close()
    await b.close()


@pytest.mark.parametrize("length", [0, 125, 126, 65535, 65536, 300_000])
async def test_a_frame_built_once_reaches_idle_clients_whole(make_client, length):
    """Each WebSocket length form (7-bit, 16-bit, 64-bit) written straight to idle clients'
    transports, as aiohttp's client reader (not our framing) decodes it."""
    client, app, _ = await make_client()
    hub = app[HUB]
    (a, _), (b, _) = await connect(client, "?protocol=2"), await connect(client)
    first = publish(app, 1.0)  # the sender tasks send the first one and go idle
    assert (await next_binary(a)).sequence == first == (await next_binary(b)).sequence
    payloads = {version: bytes([version]) * length for version in protocol.VERSIONS}
    before = hub.written_direct
    for seq in (first + 1, first + 2):
        await asyncio.sleep(0.05)  # the senders are waiting again
        hub.publish("light", payloads, seq)
        got_a, got_b = await a.receive(timeout=10), await b.receive(timeout=10)
        assert got_a.type == got_b.type == WSMsgType.BINARY
        assert got_a.data == payloads[2] and got_b.data == payloads[1]
    assert hub.written_direct - before == 4  # no sender task was woken for them
    await a.close()
    await b.close()


async def test_a_client_that_never_reads_does_not_delay_another(make_client):
    client, app, _ = await make_client()
    hub = app[HUB]
    stalled = await raw_websocket_that_never_reads(client.port)
    for _ in range(100):  # wait until the server has registered it
        if len(hub.clients) == 1:
            break
        await asyncio.sleep(0.02)
    reader, _ = await connect(client)
    big = protocol.encode_light(np.ones((20000, 3)), np.zeros(20000, bool), 0, 0.0)  # 240 kB
    received = []
    for seq in range(1, 61):  # 14 MB in all: far more than the stalled socket's buffers
        hub.publish("light", big[:8] + seq.to_bytes(4, "little") + big[12:], seq)
        received.append((await next_binary(reader)).sequence)
    assert received == list(range(1, 61))  # the reader got every one, in step
    stalled_client = next(c for c in hub.clients if c.ws is not reader and
                          c.remote and c.messages_sent < 60)
    assert stalled_client.messages_sent < 40  # its connection filled up long ago...
    assert len(hub.clients) == 2  # ...and it is still connected, costing only one buffer
    stalled.close()
    await reader.close()


@pytest.mark.parametrize(
    ("send", "code", "reason"),
    [
        ("text:not json at all", 1008, "not JSON"),
        ('text:{"type": "shout"}', 1008, "unknown message type"),
        ("bytes:\x01\x02", 1003, "binary"),
        ("text:" + "x" * 5000, 1009, ""),
    ],
)
async def test_a_bad_message_closes_only_its_sender(make_client, send, code, reason):
    client, app, _ = await make_client()
    bad, _ = await connect(client)
    good, _ = await connect(client)
    kind, _, payload = send.partition(":")
    if kind == "text":
        await bad.send_str(payload)
    else:
        await bad.send_bytes(payload.encode("latin-1"))
    msg = await bad.receive(timeout=10)
    while msg.type in (WSMsgType.BINARY, WSMsgType.TEXT):
        msg = await bad.receive(timeout=10)
    assert msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSED, WSMsgType.CLOSING)
    assert bad.close_code == code
    if reason:
        assert reason in (msg.extra or "")
    seq = publish(app, 4.0)
    assert (await next_binary(good)).sequence == seq
    # The server lets the bad client go once its close handshake ends (not before the good
    # one's next message, necessarily).
    await wait_for(lambda: len(app[HUB].clients) == 1, 10)
    await good.close()


async def test_flooding_client_is_closed_for_too_many_messages(make_client):
    client, _, _ = await make_client(server__client_max_messages_per_s=2.0)
    ws, _ = await connect(client)
    for k in range(30):
        await ws.send_str(json.dumps({"type": "ping", "id": k}))
    codes = []
    async for msg in ws:
        codes.append(msg.type)
    assert ws.close_code == 1008


async def test_ping_is_answered_and_subscribe_is_accepted(make_client):
    client, app, _ = await make_client()
    ws, _ = await connect(client)
    await ws.send_str(json.dumps({"type": "ping", "id": "abc"}))
    pong = json.loads((await ws.receive(timeout=10)).data)
    assert pong["type"] == "pong" and pong["id"] == "abc" and pong["server_time_s"] > 0
    await ws.send_str(json.dumps({"type": "subscribe", "streams": ["light"]}))
    seq = publish(app)
    assert (await next_binary(ws)).sequence == seq
    await ws.close()


async def test_two_hundred_clients_all_receive_frames(make_client):
    client, app, _ = await make_client()
    connector = aiohttp.TCPConnector(limit=0)
    async with aiohttp.ClientSession(connector=connector) as session:
        url = client.make_url("/ws/light")
        sockets = await asyncio.gather(*(session.ws_connect(url) for _ in range(200)))
        hellos = await asyncio.gather(*(ws.receive(timeout=30) for ws in sockets))
        assert all(json.loads(h.data)["type"] == "hello" for h in hellos)
        assert len(app[HUB].clients) == 200
        seq = publish(app, 7.0)
        got = await asyncio.gather(*(next_binary(ws, 30) for ws in sockets))
        assert {m.sequence for m in got} == {seq}
        assert all(np.all(m.rgb == 7.0) for m in got)
        await asyncio.gather(*(ws.close() for ws in sockets))


async def test_clients_beyond_max_clients_are_refused_with_1013(make_client):
    client, app, _ = await make_client(server__max_clients=2)
    a, _ = await connect(client)
    b, _ = await connect(client)
    c = await client.ws_connect("/ws/light")
    msg = await c.receive(timeout=10)
    assert msg.type == WSMsgType.CLOSE and c.close_code == 1013
    assert app[HUB].refused == 1
    await a.close()
    await b.close()


async def test_origins_other_than_the_page_and_the_allowed_list_are_refused(make_client):
    client, _, _ = await make_client(server__allowed_origins=["https://museum.example"])
    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
        await client.ws_connect("/ws/light", headers={"Origin": "https://evil.example"})
    assert info.value.status == 403
    same = f"http://{client.host}:{client.port}"
    for origin in (same, "https://museum.example"):
        ws = await client.ws_connect("/ws/light", headers={"Origin": origin})
        assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"
        await ws.close()


async def test_site_camera_frames_go_only_to_subscribers(make_client):
    site = ManualSource("site")
    client, app, _ = await make_client(site_source=site)
    kiosk, hello = await connect(client, "?streams=light,site-camera")
    assert hello["available_streams"] == ["light", "site-camera"]
    assert hello["streams"] == ["light", "site-camera"]
    phone, _ = await connect(client)
    await site.started()
    image = np.zeros((48, 64, 3), np.uint8)
    image[:, :32] = 255
    from server.measure import Frame

    site.push(Frame(image, 55.0, bgr=True))
    m = await next_binary(kiosk)
    assert m.type == protocol.MessageType.SITE_CAMERA and m.capture_time_s == 55.0
    assert m.payload[:2] == b"\xff\xd8"  # a JPEG
    seq = publish(app, 1.0)
    assert (await next_binary(phone)).sequence == seq  # the phone got no camera frame first
    with pytest.raises(aiohttp.WSServerHandshakeError):
        await client.ws_connect("/ws/light?streams=light,weather")
    await kiosk.close()
    await phone.close()


async def test_each_client_gets_the_protocol_version_it_asked_for(make_client):
    from types import SimpleNamespace

    site = ManualSource("site")
    client, app, _ = await make_client(site_source=site)
    new, hello2 = await connect(client, "?protocol=2&streams=light,site-camera")
    old, hello1 = await connect(client, "?streams=light,site-camera")
    explicit_old, hello1b = await connect(client, "?protocol=1")
    assert (hello2["protocol"], hello1["protocol"], hello1b["protocol"]) == (2, 1, 1)
    assert "sun_estimated" in hello2["binary"]["flags"]
    assert "sun_estimated" not in hello1["binary"]["flags"] and "sun" not in hello1
    n = 40
    sky = np.full((n, 3), 2.0, np.float32)
    folded = sky.copy()
    folded[7] += 1000.0
    sun = SimpleNamespace(direction=np.array([0.0, 0.6, -0.8]),
                          normal_irradiance_w_m2=np.array([800.0, 780.0, 700.0]), source=2)
    seq = app[HUB].publish_light(sky, np.zeros(n, bool), 9.5,
                                 protocol.Flags.SUN_ESTIMATED | protocol.Flags.SIMULATED,
                                 sun=sun, folded_rgb=folded)
    m2, m1, m1b = await next_binary(new), await next_binary(old), await next_binary(explicit_old)
    assert m2.sequence == m1.sequence == m1b.sequence == seq
    assert m2.version == 2 and m2.sun.source_name == "model" and m2.sun.estimated
    np.testing.assert_allclose(m2.sun.normal_irradiance_w_m2, [800, 780, 700])
    np.testing.assert_allclose(m2.sun.direction, [0.0, 0.6, -0.8], atol=1e-7)
    assert np.all(m2.rgb == 2.0)
    assert m1.version == 1 and m1.sun is None and m1.rgb[7, 0] == 1002.0
    assert m1.flags == protocol.Flags.SIMULATED  # SUN_ESTIMATED is not a version-1 flag
    await site.started()
    from server.measure import Frame

    site.push(Frame(np.zeros((48, 64, 3), np.uint8), 56.0, bgr=True))
    f2, f1 = await next_binary(new), await next_binary(old)
    assert (f2.type, f2.version, f1.type, f1.version) == (2, 2, 2, 1)
    assert f2.payload == f1.payload
    for bad in ("7", "two"):
        with pytest.raises(aiohttp.WSServerHandshakeError) as err:
            await client.ws_connect(f"/ws/light?protocol={bad}")
        assert err.value.status == 400
    for ws in (new, old, explicit_old):
        await ws.close()
