"""Sources through the whole chain: sim, restarts, a camera that stops, bad frames."""

import json
import math

import cv2
import numpy as np
from aiohttp import WSMsgType

from server import protocol
from server.app import PIPELINE, SUPERVISOR, create_app
from server.protocol import Flags
from server.sources import CameraSource, ReplaySource
from tests.server.helpers import FakeCamera, ManualSource, settings_for, sky_frame, wait_for


async def light_messages(ws, count, timeout=20.0):
    out = []
    while len(out) < count:
        msg = await ws.receive(timeout=timeout)
        if msg.type == WSMsgType.BINARY:
            m = protocol.decode(msg.data)
            if m.type == protocol.MessageType.LIGHT:
                out.append(m)
        else:
            assert msg.type == WSMsgType.TEXT, msg
    return out



async def test_simulated_sky_streams_flagged_vectors(aiohttp_client, build_dir, tmp_path):
    app = create_app(build_dir, settings_for(tmp_path))
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light")
    hello = json.loads((await ws.receive(timeout=10)).data)
    assert hello["source"] == "sim" and hello["simulated"] is True
    msgs = await light_messages(ws, 3)
    assert all(m.flags & Flags.SIMULATED for m in msgs)
    assert [m.sequence for m in msgs] == sorted(m.sequence for m in msgs)
    assert all(np.all(m.rgb > 0) for m in msgs)  # a daytime sky (10:30 at the site)
    status = await (await client.get("/api/status")).json()
    assert status["source"] == "sim" and status["fps"] > 0 and status["stale"] is False
    assert status["clients"] == 1 and status["sequence"] >= 3
    assert status["sun_elevation_deg"] > 30  # June morning in Nara
    assert isinstance(status["saturated_lights"], list)
    sky = await client.get("/api/sky.jpg")
    assert sky.status == 200 and sky.content_type == "image/jpeg"
    assert cv2.imdecode(np.frombuffer(await sky.read(), np.uint8), cv2.IMREAD_COLOR) is not None
    await ws.close()


async def test_a_restarted_source_resumes_the_stream(aiohttp_client, build_dir, tmp_path):
    source = ManualSource()
    app = create_app(build_dir, settings_for(tmp_path), sky_source=source)
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    await source.started()
    source.push(sky_frame(0.3))
    before = await light_messages(ws, 1)
    source.crash()  # the driver dies; the supervisor logs it and starts the source again
    await wait_for(lambda: source.runs == 2 and source.deliver is not None)
    assert app[SUPERVISOR].restarts["sky source"] == 1
    source.push(sky_frame(0.8))
    after = await light_messages(ws, 1)
    assert after[0].sequence > before[-1].sequence
    assert after[0].rgb.mean() > before[0].rgb.mean()
    status = await (await client.get("/api/status")).json()
    assert status["restarts"]["sky source"] == 1
    await ws.close()


async def test_a_camera_that_stops_goes_stale_and_recovers(aiohttp_client, build_dir, tmp_path):
    camera = FakeCamera()
    source = CameraSource(0, rate_hz=20.0, reconnect_min_s=0.05, reconnect_max_s=0.1,
                          open_capture=camera.open)
    app = create_app(build_dir, settings_for(tmp_path, sky__stale_after_s=0.4),
                     sky_source=source)
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    fresh = await light_messages(ws, 2)
    while any(m.flags & Flags.STALE for m in fresh):  # a busy machine may start slowly
        fresh = await light_messages(ws, 2)
    camera.alive.clear()  # unplugged
    while not (m := (await light_messages(ws, 1))[0]).flags & Flags.STALE:
        pass
    assert np.allclose(m.rgb, fresh[-1].rgb)  # the last good vector, flagged
    status = await (await client.get("/api/status")).json()
    assert status["stale"] is True and status["connected"] is False
    assert status["reconnects"] >= 1
    camera.alive.set()  # plugged back in
    while (m := (await light_messages(ws, 1))[0]).flags & Flags.STALE:
        pass
    status = await (await client.get("/api/status")).json()
    assert status["stale"] is False and status["connected"] is True
    assert camera.opened >= 2
    await ws.close()


async def test_bad_frames_are_skipped_and_the_stream_goes_on(aiohttp_client, build_dir,
                                                             tmp_path, caplog):
    source = ManualSource()
    app = create_app(build_dir, settings_for(tmp_path), sky_source=source)
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    await source.started()
    source.push(sky_frame(0.5))
    await light_messages(ws, 1)
    bad = sky_frame(0.5)
    bad.image = bad.image[:, :, :2]  # two channels
    source.push(bad)
    await wait_for(lambda: app[PIPELINE].frames_skipped == 1)
    source.push(sky_frame(0.7))
    m = (await light_messages(ws, 1))[0]
    assert np.allclose(m.rgb, m.rgb[0])
    assert "skipping a frame" in caplog.text
    await ws.close()


async def test_small_changes_are_not_sent_but_flag_changes_are(aiohttp_client, build_dir,
                                                                tmp_path):
    source = ManualSource()
    settings = settings_for(tmp_path, stream__change_threshold=0.05,
                            stream__max_interval_s=1000.0, sky__stale_after_s=1000.0)
    app = create_app(build_dir, settings, sky_source=source)
    client = await aiohttp_client(app)
    await source.started()
    pipeline = app[PIPELINE]
    source.push(sky_frame(0.50))
    await wait_for(lambda: pipeline.frames_measured == 1)
    first = pipeline.hub.sequence["light"]
    source.push(sky_frame(0.505))  # well under 5 %
    await wait_for(lambda: pipeline.frames_measured == 2)
    assert pipeline.hub.sequence["light"] == first
    source.push(sky_frame(0.8))
    await wait_for(lambda: pipeline.frames_measured == 3)
    assert pipeline.hub.sequence["light"] == first + 1
    await client.close()


async def test_replay_of_a_folder_loops(aiohttp_client, build_dir, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k:03d}.png"), np.full((64, 64, 3), 60 + 60 * k, np.uint8))
    (folder / "999.png").write_bytes(b"not a png")  # skipped with a log line
    source = ReplaySource(folder, rate_hz=50.0)
    app = create_app(build_dir, settings_for(tmp_path), sky_source=source)
    client = await aiohttp_client(app)
    await wait_for(lambda: source.played >= 7)  # more than one pass
    status = await (await client.get("/api/status")).json()
    assert status["source"] == f"replay:{folder}" and status["replayed_frames"] >= 7
    await client.close()


async def first_light(ws, timeout=20.0):
    hello = json.loads((await ws.receive(timeout=timeout)).data)
    return hello, (await light_messages(ws, 1, timeout))[0]


async def test_the_sun_goes_apart_to_version_2_and_into_its_patch_for_version_1(
        aiohttp_client, build_dir, tmp_path):
    from daylit.spherical import PatchLookup

    app = create_app(build_dir, settings_for(tmp_path, sim__size_px=160,
                                             stream__max_interval_s=0.2))
    client = await aiohttp_client(app)
    bad = await client.get("/ws/light?protocol=7")
    assert bad.status == 400 and "protocol" in await bad.text()
    new = await client.ws_connect("/ws/light?protocol=2")
    old = await client.ws_connect("/ws/light")
    hello2, m2 = await first_light(new)
    hello1, m1 = await first_light(old)
    assert (hello2["protocol"], hello1["protocol"]) == (2, 1)
    # Both connections see every vector: find one sequence in both.
    seen2, seen1 = {m2.sequence: m2}, {m1.sequence: m1}
    while not set(seen2) & set(seen1):
        for ws, seen in ((new, seen2), (old, seen1)):
            m = (await light_messages(ws, 1))[0]
            seen[m.sequence] = m
    seq = min(set(seen2) & set(seen1))
    m2, m1 = seen2[seq], seen1[seq]
    assert m2.version == 2 and m1.version == 1 and m1.sun is None
    sun = m2.sun
    # The simulated camera clips the sun (8 bits): the clear-sky estimate, flagged.
    assert sun.source_name == "model" and sun.estimated
    assert m2.flags & protocol.Flags.SUN_ESTIMATED and not m1.flags & 32
    assert 500.0 < float(sun.normal_irradiance_w_m2[1]) < 1100.0  # a June morning
    pipeline = app[PIPELINE]
    truth = pipeline.latest_frame.truth.sun
    assert float(sun.direction @ truth.direction) > math.cos(math.radians(0.2))
    manifest = json.loads((build_dir / "manifest.json").read_text())
    lights = manifest["dome"]["lights"]
    tris = np.array([light["vertices"] for light in lights])
    patch = int(PatchLookup(tris)(sun.direction[None].astype(float))[0])
    omega = lights[patch]["solid_angle_sr"]
    expected = m2.rgb.astype(np.float64)
    expected[patch] += sun.normal_irradiance_w_m2 / omega
    np.testing.assert_allclose(m1.rgb, expected, rtol=1e-5)
    assert not m2.saturated.any()  # only the sun clipped, and it was taken out
    status = await (await client.get("/api/status")).json()
    s = status["sun"]
    assert s["source"] == "model" and 0.9 <= s["visible_fraction"] <= 1.0
    assert abs(s["elevation_deg"] - status["sun_elevation_deg"]) < 0.5  # a frame apart
    assert len(s["normal_irradiance_W_m2"]) == 3 and s["normal_irradiance_W_m2"][1] > 500
    assert status["clients_protocol_1"] == 1
    await new.close()
    await old.close()
