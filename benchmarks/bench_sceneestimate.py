"""The scene estimate (issue 16): time per estimate and accuracy against Radiance.

- **Time**: one core (``OMP_NUM_THREADS=1`` etc. set before numpy loads), a 1280x720 view of
  the test site of ``tests/radiance_frames.py`` (the 320x180 Radiance frame scaled up 4x, so the
  pixels are a real render's), ``samples`` per estimate; the pool is prepared once (its time is
  reported apart). Timed: :meth:`SceneEstimator.estimate` on a linear frame, and the server's
  whole step, :meth:`SceneMeter.measure` (the JPEG's codes linearised, the estimate, the sky
  integrated over a 160-light dome). Baseline in the same run: linearising the whole frame
  through the response table (what the meter avoids by linearising the sampled pixels only).
- **Accuracy per sky type**: gendaylit clear (DNI 800, DHI 80 W/m^2), intermediate (400, 200)
  and overcast (0, 150) on 2026-10-15 at 9:30, 12:00 and 14:30 (standard time) at the test
  site, rendered by Radiance (rtrace, two bounces) at 320x180 with a person in view;
  ``frames`` camera frames each (noise, JPEG 85), the estimate of the last frame of each
  stream against the truth: the sun's normal irradiance and the sky's horizontal irradiance
  (rtrace -I of the sky alone).
- **The sky camera's measurement of the same skies** (:func:`sky_camera_errors`): a fisheye
  of each gendaylit sky rendered by Radiance, one 8-bit frame through the server's sky meter.
- **Accuracy vs samples**: the clear streams again at 100 ... 2000 samples per estimate.

Run (about 5 minutes on the 2-core reference machine; pyradiance is a dev dependency)::

    nice -n 10 .venv/bin/python benchmarks/bench_sceneestimate.py [--json out.json]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

HOURS = ("9.5", "12", "14.5")  # decimal hours: see radiance_frames.local_time
SKIES = {"clear": (800.0, 80.0), "intermediate": (400.0, 200.0), "overcast": (0.0, 150.0)}
SAMPLE_COUNTS = (100, 250, 500, 1000, 2000)


def render_all() -> dict:
    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import PERSON_ALBEDO, known_site, person_mesh, render_sky

    site = known_site()
    out = {}
    for k, hour in enumerate(HOURS):
        person = ("person", person_mesh((-4.0 + 3.0 * k, 0.0, -11.0)), PERSON_ALBEDO)
        for name, (dni, dhi) in SKIES.items():
            out[name, hour] = render_sky(site, SkySpec(name, 10, 15, hour, dni, dhi),
                                         extra=[person])
    return site, out


def stream_errors(site, rendered, samples: int, frames: int, seed: int) -> dict:
    """Relative errors of the last estimate of a stream of ``frames`` camera frames."""
    from daylit.sun import sun_position
    from server.sceneestimate import SceneEstimator
    from tests.radiance_frames import last_estimate

    mesh, albedo = site.mesh_and_albedo()
    est = SceneEstimator(mesh, albedo, site.view, samples=samples, seed=seed)
    sun = sun_position(34.47, 135.82, 100.0, [rendered.when_unix_s]).direction[0]
    light = last_estimate(est, rendered, sun, seed, frames)
    e_sun = float(np.mean(light.sun_normal_irradiance))
    e_sky = float(np.mean(light.sky_horizontal_irradiance))
    return {
        "sun_w_m2": e_sun, "sky_w_m2": e_sky,
        "sun_truth_w_m2": rendered.dni_w_m2, "sky_truth_w_m2": rendered.dhi_w_m2,
        "sun_rel_err": (e_sun / rendered.dni_w_m2 - 1.0) if rendered.dni_w_m2 > 0 else None,
        "sky_rel_err": e_sky / rendered.dhi_w_m2 - 1.0,
        "sun_over_sky": e_sun / max(e_sky, 1e-9), "sky_type": light.sky_type,
    }


def sky_camera_errors(name: str, hour: str, size_px: int = 256, dome_lights: int = 160) -> dict:
    """The sky camera's measurement of the same sky: a zenith fisheye of the gendaylit sky
    rendered by Radiance (``tests/radiance_frames.render_sky_camera``), one 8-bit sRGB frame
    exposed so that the sky's 99th percentile is at 0.8 (the sun clips: the clear-sky model,
    Linke turbidity 3, times the clear fraction), measured by the server's
    :class:`server.measure.SkyMeter` over a ``dome_lights`` dome; the sky's horizontal
    irradiance is its patch radiances times their projected solid angles."""
    from bake.dome import Dome
    from benchmarks.radiance import SkySpec
    from server.fusion import projected_solid_angles_sr
    from server.measure import Frame, SkyMeter
    from server.photometry import Photometry
    from server.sunmeter import SunMeter
    from tests.radiance_frames import SITE, local_time, render_sky_camera, srgb_encode

    dni, dhi = SKIES[name]
    spec = SkySpec(name, 10, 15, hour, dni, dhi)
    radiance, sky = render_sky_camera(spec, SITE, size_px)
    exposure = 0.8 / float(np.percentile(radiance[radiance > 0], 99.0))
    codes = np.round(srgb_encode(radiance * exposure) * 255.0).astype(np.uint8)
    dome = Dome.for_light_count(dome_lights).vertices
    meter = SkyMeter(dome, Photometry(exposure=exposure),
                     sun=SunMeter(34.47, 135.82, 100.0))
    when_s = local_time(spec, SITE["scene"]["timezone"])
    m = meter.measure(Frame(codes, when_s, bgr=False, sky_time_s=when_s))
    e_sky = float(np.mean(projected_solid_angles_sr(dome) @ m.radiance.astype(float)))
    e_sun = float(np.mean(m.sun.normal_irradiance_w_m2))
    truth_sun = sky.dni if sky.has_sun else 0.0
    return {
        "cam_sun_w_m2": e_sun, "cam_sun_source": m.sun.source.label,
        "cam_sun_rel_err": (e_sun / truth_sun - 1.0) if truth_sun > 0 else None,
        "cam_sky_w_m2": e_sky, "cam_sky_truth_w_m2": dhi, "cam_sky_rel_err": e_sky / dhi - 1.0,
    }


def timing(site, rendered, samples: int, repeats: int) -> dict:
    """Milliseconds per estimate at 1280x720 on one core."""
    import cv2

    from bake.dome import Dome
    from daylit.sun import SunPath
    from server.measure import Frame
    from server.sceneestimate import PinholeView, SceneEstimator
    from server.scenemeter import SceneMeter
    from tests.radiance_frames import camera_frame, linearise

    scale = 4
    view = PinholeView(np.diag([scale, scale, 1.0]) @ site.view.K, site.view.world_from_camera,
                       site.view.width * scale, site.view.height * scale)
    big = cv2.resize(rendered.image().astype(np.float32), (view.width, view.height),
                     interpolation=cv2.INTER_LINEAR)
    codes, exposure = camera_frame(big, np.random.default_rng(0))
    mesh, albedo = site.mesh_and_albedo()
    est = SceneEstimator(mesh, albedo, view, samples=samples)
    t0 = time.perf_counter()
    pool = est.pool_samples
    pool_s = time.perf_counter() - t0
    sun_path = SunPath(34.47, 135.82, 100.0)
    sun = sun_path.at(rendered.when_unix_s).direction
    t0 = time.perf_counter()
    est.in_sun(sun)
    sun_cast_s = time.perf_counter() - t0
    linear = linearise(codes)
    est.estimate(linear, sun, 1.0 / exposure, clip_level=0.99)  # warm (sky-term cache)
    # baseline in the same run: the stated albedos used as they are (no surface scales)
    stated = SceneEstimator(mesh, albedo, view, samples=samples, learn_albedo=False)
    stated.estimate(linear, sun, 1.0 / exposure, clip_level=0.99)
    times, stated_times = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        est.estimate(linear, sun, 1.0 / exposure, clip_level=0.99)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        stated.estimate(linear, sun, 1.0 / exposure, clip_level=0.99)
        stated_times.append(time.perf_counter() - t0)
    # the fusion's drift check (server.skycheck) on the same frame: its extra cost per frame
    from server.fusion import projected_solid_angles_sr
    from server.skycheck import SkyPatches, sky_camera_gain

    dome = Dome.for_light_count(160).vertices
    sky = np.full((len(dome), 3), rendered.dhi_w_m2 / np.pi)
    patches = SkyPatches(est, dome)
    e_h = float(np.mean(projected_solid_angles_sr(dome) @ sky))
    sky_camera_gain(patches, linear, sun, sky, e_h, 1.0 / exposure, 0.99)
    gain_times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sky_camera_gain(patches, linear, sun, sky, e_h, 1.0 / exposure, 0.99)
        gain_times.append(time.perf_counter() - t0)
    meter = SceneMeter(est, Dome.for_light_count(160).vertices, sun_path,
                       radiance_per_unit=1.0 / exposure, saturation_level=0.99)
    frame = Frame(codes, rendered.when_unix_s, bgr=False)
    meter.measure(frame)
    meter_times, lut_times = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        meter.measure(frame)
        meter_times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        np.stack([meter.table[codes[:, :, c], c] for c in range(3)], axis=-1)
        lut_times.append(time.perf_counter() - t0)
    return {
        "size": f"{view.width}x{view.height}", "samples": samples,
        "pool_prepare_s": pool_s, "pool": len(pool.albedo),
        "sun_cast_s": sun_cast_s,
        "estimate_ms_median": 1e3 * float(np.median(times)),
        "estimates_per_s": 1.0 / float(np.median(times)),
        "baseline_stated_albedo_ms_median": 1e3 * float(np.median(stated_times)),
        "meter_ms_median": 1e3 * float(np.median(meter_times)),
        "meter_per_s": 1.0 / float(np.median(meter_times)),
        "baseline_linearise_ms_median": 1e3 * float(np.median(lut_times)),
        "sky_camera_gain_ms_median": 1e3 * float(np.median(gain_times)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4, help="camera frames per stream")
    parser.add_argument("--repeats", type=int, default=30, help="timed estimates")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    from tests.radiance_frames import radiance_version

    t0 = time.perf_counter()
    site, rendered = render_all()
    print(f"Radiance {radiance_version()}: {len(rendered)} conditions rendered in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    result = {"timing": timing(site, rendered["clear", "12"], 500, args.repeats)}
    print(json.dumps(result["timing"], indent=1), flush=True)
    per_sky = []
    for k, ((name, hour), r) in enumerate(rendered.items()):
        # (a fixed seed per condition: until 2026-11-24 it was hash((name, hour)), which
        # Python randomises per process, so runs differed in their camera noise and samples)
        e = stream_errors(site, r, 500, args.frames, seed=100 + k)
        e.update(sky_camera_errors(name, hour))
        per_sky.append({"sky": name, "hour": hour, **e})
        sun = "-" if e["sun_rel_err"] is None else f"{100 * e['sun_rel_err']:+.1f} %"
        print(f"{name:12s} {hour}: sun {e['sun_w_m2']:7.1f} (truth {e['sun_truth_w_m2']:6.1f}, "
              f"{sun}), sky {e['sky_w_m2']:6.1f} (truth {e['sky_truth_w_m2']:6.1f}, "
              f"{100 * e['sky_rel_err']:+.1f} %), sun/sky {e['sun_over_sky']:.3f}, CIE type "
              f"{e['sky_type']}; sky camera: sun {e['cam_sun_w_m2']:7.1f} "
              f"({e['cam_sun_source']}), sky {e['cam_sky_w_m2']:6.1f} (gendaylit DHI "
              f"{e['cam_sky_truth_w_m2']:.0f}, {100 * e['cam_sky_rel_err']:+.1f} %)", flush=True)
    result["per_sky"] = per_sky
    vs_samples = []
    for n in SAMPLE_COUNTS:
        errs = [stream_errors(site, rendered["clear", h], n, args.frames, seed=s)
                for h in HOURS for s in (1, 2, 3)]
        sun = np.abs([e["sun_rel_err"] for e in errs])
        sky = np.abs([e["sky_rel_err"] for e in errs])
        row = {"samples": n, "sun_abs_err_median": float(np.median(sun)),
               "sun_abs_err_max": float(sun.max()), "sky_abs_err_median": float(np.median(sky)),
               "sky_abs_err_max": float(sky.max()), "streams": len(errs)}
        vs_samples.append(row)
        print(f"{n:5d} samples: sun |err| median {100 * row['sun_abs_err_median']:.1f} % max "
              f"{100 * row['sun_abs_err_max']:.1f} %; sky median "
              f"{100 * row['sky_abs_err_median']:.1f} % max {100 * row['sky_abs_err_max']:.1f} %",
              flush=True)
    result["vs_samples"] = vs_samples
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
