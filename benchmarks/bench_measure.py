"""Measuring time per sky frame: the light vector of a 400-light dome from a fisheye frame.

Prints, for a 1280x960 and a 1920x1920 frame (uint8, sRGB response), the median time per frame
of :meth:`server.measure.SkyMeter.measure` at the default working resolution and at full
resolution, next to two baselines measured in the same run on the same frame:

- *label mean*: the straightforward method (Sato Sec. 5 as written): linearise every pixel,
  then average the pixels whose centre falls in each patch with ``np.bincount``;
- *float pass*: one plain numpy pass over the frame (``frame.astype(np.float32)``), the floor
  of any method that touches every pixel.

Run: ``.venv/bin/python benchmarks/bench_measure.py`` (about a minute; one core is used).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bake.dome import Dome  # noqa: E402
from daylit.spherical import PatchLookup  # noqa: E402
from server.fisheye import FisheyeCamera  # noqa: E402
from server.measure import (  # noqa: E402
    DEFAULT_WORKING_PIXELS,
    Frame,
    Photometry,
    SkyMeter,
    inverse_response_table,
)
from server.simsky import SimulatedSky  # noqa: E402

cv2.setNumThreads(1)
LIGHTS = 400
SIZES = [(1280, 960), (1920, 1920)]


def timed(fn, repeat: int = 30) -> float:
    """Median wall time of ``fn()`` in milliseconds (after one warm-up call)."""
    fn()
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(samples)


def main() -> None:
    dome = Dome.for_light_count(LIGHTS)
    print(f"{dome.count} lights; median of 30 frames; one core\n")
    header = (
        f"{'frame':>10} {'MP':>5} {'build s':>8} {'working':>10} {'measure ms':>10} "
        f"{'ms/MP':>6} {'label mean ms':>13} {'speed-up':>8} {'float pass ms':>13}"
    )
    print(header)
    for width, height in SIZES:
        camera = FisheyeCamera.equidistant(width, height)
        sim = SimulatedSky.for_site(45.0, 10.0, 0.0, "UTC", camera=camera, cloud_cover=0.4)
        frame = sim.render_at(sim.clock.start_s + 3600.0)
        image = frame.image
        mp = width * height / 1e6
        # Baseline: label image of pixel centres, linearise, bincount per channel.
        lookup = PatchLookup(dome.vertices)
        dirs, ok = camera.unproject(camera.pixel_grid())
        labels = np.where(ok, lookup(dirs), -1)
        valid = labels >= 0
        lab = labels[valid]
        lut = inverse_response_table("srgb")

        def label_mean(image=image, valid=valid, lab=lab, lut=lut):
            linear = lut[image.reshape(-1, 3)[valid], np.arange(3)]
            counts = np.bincount(lab, minlength=LIGHTS)
            return np.stack(
                [np.bincount(lab, linear[:, c], minlength=LIGHTS) for c in range(3)], 1
            ) / counts[:, None]

        base_ms = timed(label_mean, 10)
        floor_ms = timed(lambda image=image: image.astype(np.float32))
        for label, max_px in (("default", DEFAULT_WORKING_PIXELS), ("full", 1 << 30)):
            meter = SkyMeter(dome.vertices, Photometry(), max_working_pixels=max_px)
            t0 = time.perf_counter()
            meter.prepare(width, height)
            build_s = time.perf_counter() - t0
            m = meter.matrix
            f = Frame(image, frame.capture_time_s, bgr=False, exposure=frame.exposure)
            ms = timed(lambda meter=meter, f=f: meter.measure(f))
            work = f"{m.camera.width}x{m.camera.height}"
            print(
                f"{width}x{height:<5} {mp:5.2f} {build_s:8.1f} {work:>10} {ms:10.2f} "
                f"{ms / mp:6.2f} {base_ms:13.1f} {base_ms / ms:7.1f}x {floor_ms:13.2f}"
                f"  ({label})"
            )


if __name__ == "__main__":
    main()
