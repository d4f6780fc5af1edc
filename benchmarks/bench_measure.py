"""Measuring time per sky frame: the light vector of a 400-light dome from a fisheye frame.

Prints, for a 1280x960 and a 1920x1920 frame (uint8, sRGB response, the simulated sky with
clouds and a clipped sun), the median time per frame of :meth:`server.measure.SkyMeter.measure`
at several working resolutions (``max_working_pixels``: the default, the next larger one, and
full resolution), with the error against the analytic sky's patch integrals (the truth;
saturated lights left out), next to baselines measured in the same run on the same frame:

- *label mean*: the straightforward method (Sato Sec. 5 as written): linearise every pixel,
  then average the pixels whose centre falls in each patch with ``np.bincount``;
- *float pass*: one plain numpy pass over the frame (``frame.astype(np.float32)``), the floor
  of any method that touches every pixel;
- *sun*: the same frame measured with the sun meter (``server.sunmeter``: the sun found,
  estimated and its disc replaced), timed interleaved with the meter without it, and the
  sun step's own time; the error is then against the sky *without* the sun;
- with ``--previous FILE``: an earlier version of ``server/measure.py`` (e.g.
  ``git show REV:server/measure.py > /tmp/prev_measure.py``) at its own default, timed
  interleaved with the current code, frame by frame, so both see the same load.

Run: ``.venv/bin/python benchmarks/bench_measure.py [--previous FILE]`` (a few minutes; one
core is used).
"""

from __future__ import annotations

import argparse
import importlib.util
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
from daylit.sky import patch_mean_radiance  # noqa: E402
from daylit.spherical import PatchLookup  # noqa: E402
from server.binning import DEFAULT_WORKING_PIXELS  # noqa: E402
from server.fisheye import FisheyeCamera  # noqa: E402
from server.measure import Frame, SkyMeter  # noqa: E402
from server.photometry import Photometry, inverse_response_table  # noqa: E402
from server.simsky import SimulatedSky  # noqa: E402
from server.sunmeter import SunMeter  # noqa: E402

cv2.setNumThreads(1)
LIGHTS = 400
SIZES = [(1280, 960), (1920, 1920)]
BUDGETS = [("default", DEFAULT_WORKING_PIXELS), ("4x", 4 * DEFAULT_WORKING_PIXELS),
           ("full", 1 << 30)]


def timed(fn, repeat: int = 30) -> float:
    """Median wall time of ``fn()`` in milliseconds (after one warm-up call)."""
    fn()
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(samples)


def interleaved(fns: list, repeat: int = 40) -> list[float]:
    """Median milliseconds of each function, timed in turn frame by frame."""
    for fn in fns:
        fn()
    samples = [[] for _ in fns]
    for _ in range(repeat):
        for fn, out in zip(fns, samples, strict=True):
            t0 = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t0)
    return [1e3 * statistics.median(s) for s in samples]


def errors(radiance: np.ndarray, saturated: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Largest and mean relative error (%) of the unsaturated lights."""
    rel = np.abs(radiance[~saturated] / truth[~saturated] - 1.0)
    return 100 * float(rel.max()), 100 * float(rel.mean())


def load_previous(path: str):
    spec = importlib.util.spec_from_file_location("previous_measure", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def sun_line(dome_vertices: np.ndarray, sim: SimulatedSky, frame: Frame, sky_time_s: float,
             width: int, height: int) -> str:
    """The sun meter's cost on one frame: measure with and without it, and the sun step."""
    plain = SkyMeter(dome_vertices, Photometry())
    with_sun = SkyMeter(dome_vertices, Photometry(),
                        sun=SunMeter(sim.latitude_deg, sim.longitude_deg, sim.elevation_m))
    f = Frame(frame.image, frame.capture_time_s, bgr=False, exposure=frame.exposure,
              sky_time_s=sky_time_s)
    plain_ms, sun_ms = interleaved([lambda: plain.measure(f), lambda: with_sun.measure(f)])
    steps = [with_sun.measure(f).sun_ms for _ in range(30)]
    r = with_sun.measure(f)
    truth = patch_mean_radiance(frame.truth, dome_vertices, samples_per_side=32,
                                include_sun=False)
    err_max, err_mean = errors(r.radiance, r.saturated, truth)
    return (f"{width}x{height:<5} sun meter: {sun_ms:.2f} ms a frame against {plain_ms:.2f} ms "
            f"without (sun step {statistics.median(steps):.2f} ms; source "
            f"{r.sun.source.label}, {int(r.saturated.sum())} saturated lights; sky without "
            f"the sun: error max {err_max:.2f} %, mean {err_mean:.3f} %)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--previous", help="an earlier server/measure.py to compare with")
    args = parser.parse_args()
    previous = load_previous(args.previous) if args.previous else None
    dome = Dome.for_light_count(LIGHTS)
    print(f"{dome.count} lights; median of 30 frames; one core; load average "
          f"{os.getloadavg()[0]:.1f}\n")
    header = (
        f"{'frame':>10} {'MP':>5} {'budget':>8} {'build s':>8} {'working':>10} {'measure ms':>10} "
        f"{'ms/MP':>6} {'err max %':>9} {'err mean %':>10} {'label mean ms':>13} "
        f"{'speed-up':>8} {'float pass ms':>13}"
    )
    print(header)
    for width, height in SIZES:
        camera = FisheyeCamera.equidistant(width, height)
        sim = SimulatedSky.for_site(45.0, 10.0, 0.0, "UTC", camera=camera, cloud_cover=0.4)
        frame = sim.render_at(sim.clock.start_s + 3600.0)
        truth = patch_mean_radiance(frame.truth, dome.vertices, samples_per_side=32)
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
        f = Frame(image, frame.capture_time_s, bgr=False, exposure=frame.exposure)
        for label, max_px in BUDGETS:
            meter = SkyMeter(dome.vertices, Photometry(), max_working_pixels=max_px)
            t0 = time.perf_counter()
            meter.prepare(width, height)
            build_s = time.perf_counter() - t0
            m = meter.matrix
            ms = timed(lambda meter=meter, f=f: meter.measure(f))
            result = meter.measure(f)
            err_max, err_mean = errors(result.radiance, result.saturated, truth)
            work = f"{m.camera.width}x{m.camera.height}"
            print(
                f"{width}x{height:<5} {mp:5.2f} {label:>8} {build_s:8.1f} {work:>10} {ms:10.2f} "
                f"{ms / mp:6.2f} {err_max:9.2f} {err_mean:10.3f} {base_ms:13.1f} "
                f"{base_ms / ms:7.1f}x {floor_ms:13.2f}"
            )
        print(sun_line(dome.vertices, sim, frame, sim.clock.start_s + 3600.0, width, height))
        if previous is not None:
            old = previous.SkyMeter(dome.vertices, previous.Photometry())
            old.prepare(width, height)
            new = SkyMeter(dome.vertices, Photometry())
            new.prepare(width, height)
            old_frame = previous.Frame(image, frame.capture_time_s, bgr=False,
                                       exposure=frame.exposure)
            old_ms, new_ms = interleaved([lambda old=old, g=old_frame: old.measure(g),
                                          lambda new=new, g=f: new.measure(g)])
            r = old.measure(old_frame)
            old_err = errors(r.radiance, r.saturated, truth)
            r = new.measure(f)
            new_err = errors(r.radiance, r.saturated, truth)
            om, nm = old.matrix.camera, new.matrix.camera
            print(f"{'':>10} interleaved, defaults: previous {old_ms:.2f} ms at "
                  f"{om.width}x{om.height} (error max {old_err[0]:.2f} %, mean "
                  f"{old_err[1]:.3f} %), current {new_ms:.2f} ms at {nm.width}x{nm.height} "
                  f"(max {new_err[0]:.2f} %, mean {new_err[1]:.3f} %): "
                  f"{old_ms / new_ms:.2f}x as fast")
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
