"""Sources through the whole chain: sim, restarts, a camera that stops, bad frames."""

import asyncio
import json

import cv2
import numpy as np
from aiohttp import WSMsgType

from server import protocol
from server.app import PIPELINE, SUPERVISOR, create_app
from server.protocol import Flags
from server.sources import CameraSource, ReplaySource
from tests.server.helpers import FakeCamera, ManualSource, settings_for, sky_frame


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


async def wait_for(predicate, timeout=20.0):
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not predicate():
        assert loop.time() < end, "condition not reached"
        await asyncio.sleep(0.02)


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
