"""Occlusion masks on the light stream (issue 6, the server's side).

A replay site camera plays synthetic frames of the draft demo build's kiosk view (two people:
one in front of the virtual building, one behind it); kiosk clients get each SITE_CAMERA frame
followed by its OCCLUSION_MASK with the same capture time.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal

import cv2
import numpy as np
import pytest
from aiohttp import WSMsgType

from server import protocol
from server.app import HUB, OCCLUSION, SITE_CAMERA, create_app, relearn_occlusion
from server.config import ConfigError
from server.measure import Frame
from server.occlusion import decode_mask
from server.protocol import Flags, MessageType
from tests.server.helpers import (
    KioskSequence,
    ManualSource,
    interrupt_and_wait,
    raw_websocket_that_never_reads,
    settings_for,
    wait_for,
)
from tests.server.test_hello_vector import load_hello

# The site is empty for 2 s; the first 10 frames the worker gets are learned. The replay plays
# at 10 frames/s whatever the worker manages (newest frame only): 20 empty frames leave room
# for a machine that handles only every other frame while it learns.
EMPTY_FRAMES = 20


@pytest.fixture(scope="module")
def kiosk(demo_draft_build) -> KioskSequence:
    return KioskSequence(demo_draft_build, frames=40, empty_frames=EMPTY_FRAMES)


@pytest.fixture(scope="module")
def kiosk_replay(kiosk, tmp_path_factory):
    """The sequence as PNG files, with one corrupt file among them (the replay skips it)."""
    folder = kiosk.write(tmp_path_factory.mktemp("kiosk") / "frames")
    (folder / "frame_020.png").write_bytes(b"\x89PNG\r\n\x1a\n but the rest is not an image")
    return folder


async def receive_binary(ws, timeout=30.0):
    while True:
        msg = await ws.receive(timeout=timeout)
        if msg.type == WSMsgType.BINARY:
            return protocol.decode(msg.data)
        assert msg.type == WSMsgType.TEXT, msg


async def frames_with_masks(ws, count, timeout=60.0):
    """``count`` (site-camera message, occlusion message) pairs; each mask must come right
    after its frame, with the same capture time."""
    pairs = []
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while len(pairs) < count:
        assert loop.time() < end, f"only {len(pairs)} frames with masks"
        frame = await receive_binary(ws)
        if frame.type == MessageType.LIGHT:
            continue
        assert frame.type == MessageType.SITE_CAMERA
        mask = await receive_binary(ws)  # next on the wire: its mask
        assert mask.type == MessageType.OCCLUSION_MASK
        assert mask.capture_time_s == frame.capture_time_s
        pairs.append((frame, mask))
    return pairs



@pytest.mark.slow
async def test_kiosk_gets_each_frame_with_the_mask_of_the_people_in_front(
        aiohttp_client, demo_draft_build, kiosk, kiosk_replay, tmp_path, caplog):
    settings = settings_for(tmp_path, site_camera__source=f"replay:{kiosk_replay}",
                            site_camera__rate_hz=10.0)
    app = create_app(demo_draft_build, settings, sky_source=ManualSource())
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light?streams=light,site-camera,occlusion")
    hello = json.loads((await ws.receive(timeout=30)).data)
    assert hello["available_streams"] == ["light", "site-camera", "occlusion"]
    assert hello["streams"] == ["light", "occlusion", "site-camera"]
    assert hello["occlusion"]["view"] == "kiosk"
    assert hello["binary"]["flags"]["learning"] == Flags.LEARNING == 16
    phone = await client.ws_connect("/ws/light")  # light only: no camera frames, no masks
    assert json.loads((await phone.receive(timeout=30)).data)["streams"] == ["light"]
    # The web kiosk's connection gets the stored hello's keys and stream names (one name for
    # the occlusion stream: the JavaScript client is checked against the same file).
    web_kiosk = await client.ws_connect("/ws/light?protocol=3&streams=light,site-camera")
    got = json.loads((await web_kiosk.receive(timeout=30)).data)
    want = load_hello()
    assert set(got) == set(want)
    for key in ("protocol", "streams", "available_streams", "binary", "sky_encoding", "sun",
                "units", "manifest", "asset_query"):
        assert got[key] == want[key], key
    await web_kiosk.close()

    near_cover, far_cover = [], []  # per frame: share of the person's pixels masked
    learned, empty_people = [], []
    seen = set()
    with caplog.at_level(logging.INFO):
        pairs = await frames_with_masks(ws, 2 * len(kiosk.truths))
    sequences = [m.sequence for _, m in pairs]
    assert sequences == sorted(sequences)
    for frame, message in pairs:
        assert frame.payload[:2] == b"\xff\xd8"  # a JPEG
        mask, people = decode_mask(message.payload)
        assert mask.shape == (kiosk.camera.height, kiosk.camera.width)
        i = kiosk.index_of(frame.payload)
        seen.add(i)
        assert i != 20  # the corrupt file was skipped
        if message.flags & Flags.LEARNING:
            learned.append(i)
            assert not mask.any() and people == 0
            continue
        assert message.flags & Flags.REPLAY
        if i < EMPTY_FRAMES:  # the empty site (the replay loops): nobody, nothing masked
            empty_people.append((i, people, np.count_nonzero(mask)))
            continue
        if i < EMPTY_FRAMES + 2:
            continue  # the people are not (wholly) in yet
        # Each mask against the ground truth of its own frame: how many frames the machine
        # managed (and which) changes the list's length, not what each entry should be.
        near, far = kiosk.people_pixels(i)
        if np.count_nonzero(near) >= 40:  # else not (much) over the building in this frame
            near_cover.append(np.count_nonzero(mask[near]) / np.count_nonzero(near))
        if np.count_nonzero(far) >= 40:
            far_cover.append(np.count_nonzero(mask[far]) / np.count_nonzero(far))
        assert people >= 1
    # The first 10 frames the worker got were learned, all of the empty site: the pipeline is
    # built before the replay starts, so no frame is dropped while it loads the build.
    assert len(learned) == 10 and max(learned) < EMPTY_FRAMES, learned
    assert len(seen) >= 25  # the replay went through
    assert len(near_cover) >= 8 and len(far_cover) >= 8, (near_cover, far_cover)
    assert all(p == 0 and n == 0 for _, p, n in empty_people), empty_people
    # The person in front hides the virtual building, the building hides the one behind.
    near_cover, far_cover = np.array(near_cover), np.array(far_cover)
    assert np.count_nonzero(near_cover < 0.9) <= 1, near_cover
    assert np.median(near_cover) > 0.95, near_cover
    assert np.count_nonzero(far_cover > 0.05) <= 1, far_cover
    assert any("skipping" in r.getMessage() and "frame_020" in r.getMessage()
               for r in caplog.records)

    status = await (await client.get("/api/status")).json()
    occ = status["occlusion"]
    assert occ["state"] == "ready" and occ["view"] == "kiosk" and occ["worker"] == "process"
    assert occ["size"] == [kiosk.camera.width, kiosk.camera.height]
    assert occ["frames"] >= len(pairs) and occ["ms_per_frame"] > 0 and occ["round_trip_ms"] > 0
    assert status["clients_occlusion"] == 1 and status["clients_site_camera"] == 1
    assert status["site_camera"]["frames"] >= len(pairs)
    # The phone got nothing at all: no light was measured, and frames are not for it.
    with pytest.raises(asyncio.TimeoutError):
        await phone.receive(timeout=0.3)

    # The operator's reset: the next frames are learned again, then masks come back.
    assert relearn_occlusion(app)
    flags = [m.flags for _, m in await frames_with_masks(ws, 25)]
    assert any(f & Flags.LEARNING for f in flags) and not flags[-1] & Flags.LEARNING

    # A worker process that dies is replaced (and learns the background again).
    runner = app[OCCLUSION]
    os.kill(runner.worker_pid, signal.SIGKILL)
    await wait_for(lambda: runner.worker_restarts == 1 and runner.state == "ready")
    await frames_with_masks(ws, 3)
    assert runner.status()["last_error"] == "the occlusion worker process died"
    await ws.close()
    await phone.close()


async def test_bad_frames_are_skipped_and_the_stream_goes_on(
        aiohttp_client, demo_draft_build, kiosk, tmp_path, caplog):
    site = ManualSource("site")
    settings = settings_for(tmp_path, occlusion__worker="thread")
    app = create_app(demo_draft_build, settings, sky_source=ManualSource(), site_source=site)
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light?streams=site-camera,occlusion")
    await ws.receive(timeout=30)
    await site.started()
    feed = app[SITE_CAMERA]
    good = kiosk.images
    t = 1000.0
    good_times = []

    async def push(image, expect_published: bool):
        nonlocal t
        t += 0.1
        if expect_published:
            good_times.append(t)
        published = app[HUB].frames_published
        skipped = feed.frames_skipped
        site.push(Frame(image, t, bgr=True))
        await wait_for(lambda: app[HUB].frames_published > published or
                       feed.frames_skipped > skipped)
        assert (app[HUB].frames_published > published) == expect_published

    for image in good[:12]:
        await push(image, True)
    h, w = good[0].shape[:2]
    bad = [
        np.zeros((0, 0, 3), np.uint8),  # empty
        np.zeros((h, w, 3), np.float32),  # not 8-bit
        np.zeros((h, w), np.uint8),  # grey
        np.zeros((100, 100, 3), np.uint8),  # another aspect ratio than the view
        cv2.resize(good[12], (w // 2, h // 2)),  # another size than the frames before
    ]
    with caplog.at_level(logging.WARNING):
        for image in bad:
            await push(image, False)
        await push(good[12], True)
    assert feed.frames_skipped == len(bad)
    messages = " | ".join(r.getMessage() for r in caplog.records)
    assert "another aspect ratio" in messages and "the frames before were" in messages
    pairs = await frames_with_masks(ws, len(good_times))
    assert [f.capture_time_s for f, _ in pairs] == good_times  # the bad ones never went out
    assert [bool(m.flags & Flags.LEARNING) for _, m in pairs] == [True] * 10 + [False] * 3
    status = await (await client.get("/api/status")).json()
    assert status["occlusion"]["state"] == "ready" and status["occlusion"]["worker"] == "thread"
    assert status["site_camera"]["frames_skipped"] == len(bad)
    await ws.close()


async def test_a_slow_kiosk_does_not_delay_another(aiohttp_client, demo_draft_build, tmp_path):
    """Frames with masks to a kiosk that never reads: the other kiosk gets every one in step."""
    app = create_app(demo_draft_build, settings_for(tmp_path, occlusion__worker="thread"),
                     sky_source=ManualSource(), site_source=ManualSource("site"))
    client = await aiohttp_client(app)
    hub = app[HUB]
    stalled = await raw_websocket_that_never_reads(client.port, "streams=site-camera,occlusion")
    await wait_for(lambda: len(hub.clients) == 1)
    reader = await client.ws_connect("/ws/light?streams=site-camera,occlusion")
    await reader.receive(timeout=30)
    jpeg = bytes(240_000)  # 14 MB in all: far more than the stalled socket's buffers
    mask = np.zeros((180, 320), np.uint8)
    from server.occlusion import encode_mask

    got = []
    for k in range(60):
        mask[:, k] = 255
        hub.publish_frame(jpeg, 100.0 + k, 0, encode_mask(mask, 1))
        frame, message = (await frames_with_masks(reader, 1))[0]
        assert frame.capture_time_s == message.capture_time_s == 100.0 + k
        assert decode_mask(message.payload)[0][:, k].all()  # the mask of that very frame
        got.append(frame.sequence)
    assert got == list(range(1, 61))
    stalled_client = next(c for c in hub.clients if c.ws is not reader and c.messages_sent < 60)
    assert stalled_client.messages_sent < 40 and len(hub.clients) == 2
    stalled.close()
    await reader.close()


async def test_occlusion_settings_and_when_there_is_none(aiohttp_client, build_dir,
                                                         demo_draft_build, tmp_path):
    with pytest.raises(ConfigError, match=r"\[occlusion\] view 'gate' is not a view"):
        create_app(demo_draft_build, settings_for(tmp_path, occlusion__view="gate"),
                   sky_source=ManualSource(), site_source=ManualSource("site"))
    with pytest.raises(ConfigError, match=r"\[occlusion\] worker must be process \| thread"):
        settings_for(tmp_path, occlusion__worker="fork")
    cases = [
        (demo_draft_build, {"occlusion__enabled": False}, "[occlusion] enabled = false"),
        (build_dir, {}, "the build has no fixed view"),
    ]
    for build, overrides, reason in cases:
        app = create_app(build, settings_for(tmp_path, **overrides), sky_source=ManualSource(),
                         site_source=ManualSource("site"))
        client = await aiohttp_client(app)
        ws = await client.ws_connect("/ws/light?streams=light,site-camera,occlusion")
        hello = json.loads((await ws.receive(timeout=30)).data)
        assert hello["streams"] == ["light", "site-camera"]  # occlusion is not granted
        assert hello["available_streams"] == ["light", "site-camera"]
        assert hello["occlusion"] is None
        status = await (await client.get("/api/status")).json()
        assert status["occlusion"] == {"state": "off", "reason": reason}
        assert not relearn_occlusion(app)
        await ws.close()
        await client.close()
    # Without a site camera there is neither.
    app = create_app(demo_draft_build, settings_for(tmp_path), sky_source=ManualSource())
    client = await aiohttp_client(app)
    assert (await (await client.get("/api/status")).json())["occlusion"] is None


@pytest.mark.slow
def test_serve_with_a_site_camera_relearns_on_sighup_and_stops_cleanly(demo_draft_build,
                                                                       kiosk_replay):
    """``daylit serve --site-camera``: the occlusion worker process starts, SIGHUP re-learns the
    background, and Ctrl-C stops the server and its worker with no traceback."""
    import subprocess
    import sys
    import time
    import urllib.request

    from tests.server.test_cli import ROOT, free_port

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "daylit.cli", "serve", str(demo_draft_build), "--host",
         "127.0.0.1", "--port", str(port), "--site-camera", f"replay:{kiosk_replay}",
         "--set", "sim.size_px=96"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )

    def occlusion():
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status") as resp:
            return json.loads(resp.read())["occlusion"]

    def wait(predicate, what):
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            try:
                state = occlusion()
            except OSError:
                state = None
            if state and predicate(state):
                return state
            time.sleep(0.2)
        raise AssertionError(f"not reached: {what}")

    try:
        lines = []
        while not any("re-learns" in line for line in lines):
            lines.append(proc.stdout.readline())
            assert lines[-1], "".join(lines)
        assert f"kill -HUP {proc.pid}" in lines[-1]
        state = wait(lambda s: s["state"] == "ready", "occlusion ready")
        worker = state["worker_pid"]
        assert worker and worker != proc.pid and state["worker"] == "process"
        proc.send_signal(signal.SIGHUP)
        wait(lambda s: s["relearns"] == 1 and s["state"] == "ready", "re-learned")
    finally:
        interrupt_and_wait(proc, 30)
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "re-learning the background" in err and "stopping after" in err
    with pytest.raises(ProcessLookupError):  # the worker process has gone too
        for _ in range(50):
            os.kill(worker, 0)
            time.sleep(0.1)
