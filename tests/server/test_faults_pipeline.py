"""Faults of the measuring pipeline (issue 19): frames of mixed sizes (one matrix per size,
built off the measuring path, logged once) and a source that never delivers a frame."""

from __future__ import annotations

import asyncio
import logging
import time

import cv2
import numpy as np
from aiohttp import WSMsgType

from server import protocol
from server.app import PIPELINE, create_app
from tests.server.helpers import settings_for, wait_for


def srgb_to_linear(code: int) -> float:
    """IEC 61966-2-1, written out here (not the server's table)."""
    c = code / 255.0
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4



async def test_frames_of_two_sizes_build_one_matrix_each_logged_once(
        aiohttp_client, build_dir, tmp_path, caplog):
    folder = tmp_path / "mixed"
    folder.mkdir()
    codes = {96: 100, 128: 170}  # each size its own grey, so each vector says which it was
    for i in range(6):
        size = 96 if i % 2 == 0 else 128
        cv2.imwrite(str(folder / f"f{i}.png"), np.full((size, size, 3), codes[size], np.uint8))
    settings = settings_for(tmp_path, sky__source=f"replay:{folder}", sky__rate_hz=20.0,
                            sun__enabled=False, sky__stale_after_s=30.0)
    caplog.set_level(logging.INFO)
    app = create_app(build_dir, settings)
    client = await aiohttp_client(app)
    pipeline = app[PIPELINE]
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)  # hello
    seen: set[float] = set()
    flags = set()
    while len(seen) < 2 or pipeline.frames_measured < 12:
        msg = await ws.receive(timeout=60)
        assert msg.type == WSMsgType.BINARY
        m = protocol.decode(msg.data)
        flags.add(m.flags)
        # Uniform grey frames: every light has the grey's linear value (exposure 1).
        expected = [srgb_to_linear(c) for c in codes.values()]
        value = float(np.median(m.rgb))
        nearest = min(expected, key=lambda e: abs(e - value))
        np.testing.assert_allclose(m.rgb, nearest, rtol=0.02)
        seen.add(nearest)
    await ws.close()
    builds = [r.getMessage() for r in caplog.records if "building the measuring matrix" in
              r.getMessage()]
    assert len(builds) == 2, builds
    assert any("96x96" in b for b in builds) and any("128x128" in b for b in builds)
    assert pipeline.meter.matrix_builds == 2
    assert not any(f & protocol.Flags.STALE for f in flags)


async def test_a_source_that_never_delivered_is_stale_with_its_error(
        aiohttp_client, build_dir, tmp_path):
    folder = tmp_path / "unreadable"
    folder.mkdir()
    (folder / "sky.png").write_bytes(b"not a PNG at all")
    settings = settings_for(tmp_path, sky__source=f"replay:{folder}", sky__stale_after_s=0.5)
    client = await aiohttp_client(create_app(build_dir, settings))
    status = {}
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        status = await (await client.get("/api/status")).json()
        if status["stale"] and status["last_error"]:
            break
        await asyncio.sleep(0.1)
    assert status["stale"] is True
    assert status["connected"] is False
    assert "sky.png" in status["last_error"]
    assert status["frames_measured"] == 0 and status["sequence"] == 0


async def test_frames_of_the_known_size_are_measured_while_a_new_size_builds(
        aiohttp_client, build_dir, tmp_path):
    import threading

    from tests.server.helpers import ManualSource, sky_frame

    source = ManualSource()
    app = create_app(build_dir, settings_for(tmp_path, sun__enabled=False), sky_source=source)
    client = await aiohttp_client(app)
    pipeline = app[PIPELINE]
    meter = pipeline.meter
    building, release, built = threading.Event(), threading.Event(), threading.Event()
    prepare = meter.prepare

    def slow_prepare(width, height):  # the first 128 px build takes as long as the test says
        if (width, height) == (128, 128) and not building.is_set():
            building.set()
            assert release.wait(60)
            matrix = prepare(width, height)
            built.set()
            return matrix
        return prepare(width, height)

    meter.prepare = slow_prepare
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    await source.started()

    async def light_of(value: float) -> None:
        """Wait for the vector of a uniform frame of ``value`` (never one flagged stale)."""
        expected = srgb_to_linear(round(value * 255))
        deadline = time.monotonic() + 30
        while True:
            msg = await ws.receive(timeout=max(0.1, deadline - time.monotonic()))
            if msg.type != WSMsgType.BINARY:
                continue
            m = protocol.decode(msg.data)
            assert not m.flags & protocol.Flags.STALE
            if np.allclose(m.rgb, expected, rtol=0.02):
                return

    source.push(sky_frame(0.2, size=64))
    await light_of(0.2)
    source.push(sky_frame(0.6, size=128))  # a new size: its matrix is held back
    await wait_for(building.is_set)
    for value in (0.3, 0.4):  # 64 px frames go on being measured meanwhile
        source.push(sky_frame(value, size=64))
        await light_of(value)
    release.set()
    await wait_for(built.is_set)
    source.push(sky_frame(0.6, size=128))
    await light_of(0.6)
    await ws.close()
