"""Time per scene estimate (issue 16's goal: at least 10 a second on one core, 1280x720, 500
samples), this checkout's estimator and another's (``--baseline-repo``, e.g. main's)
interleaved on the same frames in the same run.

Two views, each a Radiance render scaled up 4x to 1280x720 (so the pixels are a real
render's) through the camera model (noise, JPEG 85) of ``tests/radiance_frames.py``:

- ``known site``: the tests' small site (``known_site``: a building and a wall with wide
  shadows), clear sky at 14:30, rendered here (``CAMERA_RAYS``, about a minute);
- ``kiosk``: a build's first fixed view from a pickle of ``bench_sceneestimate_heldout.py``
  (``--renders``; its 12:00 clear render), where the pool has no sample in shade and this
  checkout tops it up with pixels wholly in the model's shadow (``server/shadepool.py``).

Timed per estimator (``--repeats``, median, the two interleaved): ``SceneEstimator.estimate``
on a linear frame after a warm-up (the per-view pool and the per-sun casts done); and, once,
the pool's preparation and the first estimate (which casts the sun's rays, and for the kiosk
on this checkout finds the shaded pixels of the whole view); and (``--moves``, median) an
estimate just after the sun moved 0.06 degrees, past ``sun_cache_deg`` (the pool's sun rays
cast again and, where the view is topped up with shade, the shaded pixels found again and
their samples prepared).

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_sceneestimate_time.py BUILD \\
        --renders KIOSK.pkl [--baseline-repo /work/main] [--repeats 20] [--json out.json]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

SCALE = 4


def scaled(view, image):
    """The view and a radiance image (H, W, 3) scaled up ``SCALE`` times."""
    import cv2

    from server.sceneestimate import PinholeView

    big_view = PinholeView(np.diag([SCALE, SCALE, 1.0]) @ view.K, view.world_from_camera,
                           view.width * SCALE, view.height * SCALE)
    big = cv2.resize(image.astype(np.float32), (big_view.width, big_view.height),
                     interpolation=cv2.INTER_LINEAR)
    return big_view, big


def scenes(build: Path, renders: Path) -> dict:
    """{name: (mesh, albedo, environment albedo, view, linear frame, radiance per unit, sun)}"""
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.scenemeter import real_proxies
    from tests.radiance_frames import camera_frame, known_site, linearise, render_sky

    out = {}
    site = known_site()
    rendered = render_sky(site, SkySpec("clear", 10, 15, "14.5", 800.0, 80.0))
    view, big = scaled(site.view, rendered.image())
    codes, exposure = camera_frame(big, np.random.default_rng(0))
    mesh, albedo = site.mesh_and_albedo()
    sun = sun_position(34.47, 135.82, 100.0, [rendered.when_unix_s]).direction[0]
    out["known site"] = (mesh, albedo, 0.2, view, linearise(codes), 1.0 / exposure, sun)
    manifest = manifest_io.load(build)
    mesh, albedo = real_proxies(build, manifest)
    ground = float(np.mean(manifest["ground"]["albedo"]))
    kiosk, kiosk_view = pickle.loads(renders.read_bytes())["clear", "12"]
    view, big = scaled(kiosk_view, kiosk.image())
    codes, exposure = camera_frame(big, np.random.default_rng(0))
    scene = manifest["scene"]
    sun = sun_position(scene["latitude_deg"], scene["longitude_deg"],
                       scene.get("elevation_m", 0.0), [kiosk.when_unix_s]).direction[0]
    out["kiosk"] = (mesh, albedo, ground, view, linearise(codes), 1.0 / exposure, sun)
    return out


def main() -> None:
    from benchmarks.bench_sceneestimate_heldout import estimator_class

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path, help="a baked build (its real proxies)")
    parser.add_argument("--renders", type=Path, required=True,
                        help="bench_sceneestimate_heldout.py's pickle of the kiosk view")
    parser.add_argument("--baseline-repo", type=Path)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--moves", type=int, default=5,
                        help="estimates timed just after a sun move of 0.06 degrees")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    classes = {"this": estimator_class(None)}
    if args.baseline_repo is not None:
        classes["baseline"] = estimator_class(args.baseline_repo)
    rows = []
    for name, (mesh, albedo, env, view, linear, per_unit, sun) in scenes(
            args.build, args.renders).items():
        ests, once = {}, {}
        for label, cls in classes.items():
            est = cls(mesh, albedo, view, environment_albedo=env, samples=args.samples)
            t0 = time.perf_counter()
            _ = est.pool_samples
            t1 = time.perf_counter()
            light = est.estimate(linear, sun, per_unit, clip_level=0.99)
            t2 = time.perf_counter()
            ests[label] = est
            once[label] = (t1 - t0, t2 - t1, light)
        times = {label: [] for label in classes}
        for _ in range(args.repeats):
            for label, est in ests.items():
                t0 = time.perf_counter()
                est.estimate(linear, sun, per_unit, clip_level=0.99)
                times[label].append(time.perf_counter() - t0)
        moved = {label: [] for label in classes}
        axis = np.cross(sun, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        for k in range(1, args.moves + 1):
            # rotated about a horizontal axis: the sun's elevation 0.06 degrees lower each move
            a = np.radians(0.06 * k)
            sun_k = sun * np.cos(a) + np.cross(axis, sun) * np.sin(a) + axis * (
                axis @ sun) * (1.0 - np.cos(a))
            for label, est in ests.items():
                t0 = time.perf_counter()
                est.estimate(linear, sun_k, per_unit, clip_level=0.99)
                moved[label].append(time.perf_counter() - t0)
        for label in classes:
            ms = 1e3 * float(np.median(times[label]))
            move_s = float(np.median(moved[label])) if moved[label] else float("nan")
            pool_s, first_s, light = once[label]
            row = {"view": name, "estimator": label, "size": f"{view.width}x{view.height}",
                   "estimate_ms_median": ms, "estimates_per_s": 1e3 / ms,
                   "pool_prepare_s": pool_s, "first_estimate_s": first_s,
                   "after_sun_move_s": move_s,
                   "shaded_samples": int(getattr(light, "shaded", -1))}
            rows.append(row)
            print(f"{name:10s} {label:9s} {row['size']}  {ms:7.1f} ms  "
                  f"{row['estimates_per_s']:5.1f}/s  pool {pool_s:5.2f} s  "
                  f"first estimate {first_s:5.2f} s  after a sun move {move_s:5.2f} s  "
                  f"shaded samples {row['shaded_samples']}",
                  flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
