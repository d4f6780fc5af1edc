"""A live site camera over HTTP: ``camera:http://.../mjpeg`` read by the real CameraSource
through OpenCV's FFmpeg backend, from an MJPEG stream this test serves itself (aiohttp)."""

from __future__ import annotations

import asyncio
import contextlib
import functools

import cv2
import numpy as np
from aiohttp import web

from server.sources.camera import CameraSource, open_video_capture

BOUNDARY = b"frame"


def numbered_frames(count: int = 6) -> list[bytes]:
    """JPEG frames that differ in brightness and show their number."""
    out = []
    for i in range(count):
        image = np.full((120, 160, 3), 30 + 35 * i, np.uint8)
        cv2.putText(image, str(i), (55, 85), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
        out.append(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
    return out


async def serve_mjpeg(jpegs: list[bytes], stop_after: int | None = None):
    """An aiohttp server on a free port sending ``jpegs`` over and over as
    multipart/x-mixed-replace (what IP cameras' /mjpeg URLs send); returns (runner, url)."""

    async def mjpeg(request):
        resp = web.StreamResponse(headers={
            "Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY.decode()}"})
        await resp.prepare(request)
        k = 0
        while stop_after is None or k < stop_after:
            jpeg = jpegs[k % len(jpegs)]
            await resp.write(b"--" + BOUNDARY + b"\r\nContent-Type: image/jpeg\r\n"
                             b"Content-Length: %d\r\n\r\n" % len(jpeg) + jpeg + b"\r\n")
            k += 1
            await asyncio.sleep(0.03)
        await asyncio.sleep(3600)  # the camera hangs: sends nothing, keeps the connection
        return resp

    app = web.Application()
    app.router.add_get("/mjpeg", mjpeg)
    runner = web.AppRunner(app, shutdown_timeout=0.5)  # the hanging handler is cut off
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = site._server.sockets[0].getsockname()[1]
    return runner, f"http://127.0.0.1:{port}/mjpeg"


def decoded(jpegs: list[bytes]) -> list[np.ndarray]:
    """The served JPEGs as OpenCV decodes them (BGR)."""
    return [cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_COLOR) for j in jpegs]


def which(image: np.ndarray, images: list[np.ndarray]) -> tuple[int, float]:
    """The served picture nearest to a received image, and the mean absolute difference."""
    errors = [np.abs(image.astype(int) - i).mean() for i in images]
    return int(np.argmin(errors)), float(min(errors))


@contextlib.asynccontextmanager
async def running(source: CameraSource, runner: web.AppRunner):
    """The source reading in a task for the block, the frames it delivers in the yielded list;
    after it, the task cancelled and the test's stream server closed."""
    got = []
    task = asyncio.create_task(source.run(got.append))
    try:
        yield got
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await runner.cleanup()


async def wait_until(done, tries: int, period_s: float = 0.05) -> None:
    """Polls ``done()`` up to ``tries`` times, ``period_s`` apart (the test's assertions then
    say what was missing)."""
    for _ in range(tries):
        if done():
            return
        await asyncio.sleep(period_s)


async def test_a_camera_url_delivers_the_served_mjpeg_frames():
    jpegs = numbered_frames()
    images = decoded(jpegs)
    runner, url = await serve_mjpeg(jpegs)
    source = CameraSource(url, rate_hz=100.0)
    async with running(source, runner) as got:
        await wait_until(lambda: len(got) >= 12, 300)
        assert len(got) >= 12, (len(got), source.last_error)
        assert source.connected and source.name == f"camera:{url}"
        found = []
        for frame in got:
            assert frame.bgr and frame.image.shape == (120, 160, 3)
            index, error = which(frame.image, images)
            assert error < 2.0, error  # FFmpeg's JPEG decoder against libjpeg's: same picture
            found.append(index)
        steps = {(b - a) % len(jpegs) for a, b in zip(found, found[1:], strict=False)}
        assert steps <= {0, 1, 2}, found  # in the served order (the newest, maybe one skipped)
        assert len(set(found)) == len(jpegs)


async def test_a_camera_that_stops_sending_is_reconnected():
    """A stream that hangs (connection open, no frames) times out instead of blocking the
    reader forever; the source marks itself disconnected and opens the stream again."""
    jpegs = numbered_frames(3)
    runner, url = await serve_mjpeg(jpegs, stop_after=5)
    source = CameraSource(url, rate_hz=100.0, reconnect_min_s=0.2,
                          open_capture=functools.partial(open_video_capture, timeout_ms=1500))
    async with running(source, runner) as got:
        await wait_until(lambda: source.reconnects >= 1 and len(got) >= 6, 400)
        assert source.reconnects >= 1, source.last_error
        assert "stopped delivering frames" in source.last_error
        assert len(got) >= 6  # frames again after the reconnect
