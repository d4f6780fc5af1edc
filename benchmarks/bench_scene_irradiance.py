"""The scene estimate's composite irradiance at a site's points against Radiance (issue 16).

For each gendaylit sky (clear DNI 800 / DHI 80, intermediate 400 / 200, overcast 0 / 150
W/m^2, 2026-10-15 11:00 standard time at the build's site):

1. Radiance renders the build's first fixed view (its real proxies and ground) as the site
   camera sees it; a camera model makes the frame (noise, sRGB, 8-bit, JPEG 85:
   ``tests/radiance_frames.camera_frame``);
2. the server's :class:`server.scenemeter.SceneMeter` turns the frame into the light vector
   the scene source streams (the sky's patch radiances and the sun's normal irradiance);
3. ``daylit probe``'s :func:`bake.probe.evaluate` turns that vector, with the sun as its own
   light (``--sun``), into irradiance at the site's points the way the client lights them
   (the baked sky basis, the sun's direct term and its bounce): ground and wall grids and
   points on the models (``benchmarks.fidelity_points.site_points``);
4. Radiance gives the irradiance at the same points for the same sky (``rtrace -I``, sky and
   sun, every part of the build, two ambient bounces): the truth.

The figure is ``benchmarks.fidelity_metrics.psnr_rms``'s RMS error relative to the mean truth
(%), over all points and channels. Baseline in the same run: the true sky (gendaylit's sky
function mapped by Radiance, ``equirect_light_vector``) and the true sun through the same
probe: what the bake and the probe alone leave, with no estimate in between.

Run (pyradiance is a dev dependency; the build: ``tests/server/conftest.scene_build``'s site or
any build with a fixed view)::

    nice -n 10 .venv/bin/python benchmarks/bench_scene_irradiance.py BUILD [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

SKIES = {"clear": (800.0, 80.0), "intermediate": (400.0, 200.0), "overcast": (0.0, 150.0)}
HOUR = "11"
RTRACE_POINTS = ["-ab", "2", "-aa", "0", "-ad", "1024", "-as", "0", "-lw", "1e-6",
                 "-dj", "0", "-ds", "0", "-dc", "1", "-dt", "0", "-u-"]


def site_point_set(build_dir: Path, ground_step_m: float = 5.0, wall_step_m: float = 1.5,
                   model_points: int = 20):
    """The points (``benchmarks.fidelity_points.PointSet``) probed on the build."""
    from bake.evaluate import Build
    from bake.gltf import read_site_glb
    from benchmarks.fidelity_points import site_points

    build = Build(build_dir)
    nodes = read_site_glb(build_dir / build.manifest["model"]["path"])
    return build, site_points(build, nodes, ground_step_m, wall_step_m, model_points)


def condition(build, ps, name: str, dni: float, dhi: float, seed: int = 0,
              frames: int = 4) -> dict:
    """One sky: the estimate, the probe with it and with the true sky, and Radiance."""
    from bake.probe import ProbePoint, SunSpec, evaluate
    from benchmarks.fidelity_metrics import psnr_rms
    from benchmarks.radiance import (
        SkySpec,
        gendaylit,
        measurement_rays,
        oconv,
        radiance_env,
        rtrace,
        scene_files,
        sky_map,
        sky_rad,
        sun_rad,
    )
    from daylit.envmap import equirect_light_vector
    from daylit.sky import azimuth_elevation_from_direction
    from daylit.sun import SunPath
    from server.measure import Frame
    from server.sceneestimate import PinholeView
    from server.scenemeter import scene_meter_for_build
    from tests.radiance_frames import CAMERA_RAYS, camera_frame, camera_rays, local_time

    _, env = radiance_env()
    manifest = build.manifest
    site = manifest["scene"]
    spec = SkySpec(name, 10, 15, HOUR, dni, dhi)
    when_s = local_time(spec, site["timezone"])
    with tempfile.TemporaryDirectory(prefix="daylit-radiance-") as tmp:
        work = Path(tmp)
        files = scene_files(build.dir, work)["files"]
        sky = gendaylit(spec, manifest, env)
        sky.files["sky"] = work / "sky.rad"
        sky.files["sky"].write_text(sky_rad(sky.skyfunc))
        (work / "sun.rad").write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance)
                                      if sky.has_sun else "")
        lights = [sky.files["sky"], work / "sun.rad"]
        view = PinholeView.from_manifest(manifest["views"][0])
        real = oconv(work / "real.oct", [*lights, files["real"], files["ground"]], env)
        image = rtrace(real, camera_rays(view), CAMERA_RAYS, env,
                       irradiance=False).reshape(view.height, view.width, 3)
        everything = oconv(work / "all.oct", [*lights, files["virtual"], files["real"],
                                              files["ground"]], env)
        truth = rtrace(everything, measurement_rays(ps.points, ps.normals), RTRACE_POINTS, env)
        true_vector = equirect_light_vector(sky_map(sky, work, env), build.dome_vertices)
    sun_path = SunPath(site["latitude_deg"], site["longitude_deg"], site["elevation_m"])
    rng = np.random.default_rng(seed)
    exposure = None
    meter = None
    for _ in range(frames):
        codes, exposure = camera_frame(image, rng, exposure=exposure)
        if meter is None:
            meter = scene_meter_for_build(build.dir, manifest, "", sun_path, 500,
                                          radiance_per_unit=1.0 / exposure)
        m = meter.measure(Frame(codes, when_s, bgr=False, sky_time_s=when_s))
    points = [ProbePoint(p, n, "point") for p, n in zip(ps.points, ps.normals, strict=True)]

    def probe(vector, sun_dir, dni_w_m2) -> np.ndarray:
        az, el = azimuth_elevation_from_direction(sun_dir)
        sun = SunSpec(float(az), float(el), float(dni_w_m2)) if el > 0 else None
        out = evaluate(build, points, np.asarray(vector, float), sun)
        return np.array([r["irradiance_W_m2"] for r in out])

    estimated = probe(m.radiance, m.sun.direction, float(np.mean(m.sun.normal_irradiance_w_m2)))
    baseline = probe(true_vector, sky.sun_dir, sky.dni if sky.has_sun else 0.0)
    light = meter.latest
    return {
        "sky": name, "points": len(ps),
        "estimate": {"sun_w_m2": float(np.mean(light.sun_normal_irradiance)),
                     "sky_w_m2": float(np.mean(light.sky_horizontal_irradiance)),
                     "sky_type": light.sky_type},
        "truth": {"dni_w_m2": sky.dni if sky.has_sun else 0.0, "dhi_w_m2": dhi},
        "scene_vector": psnr_rms(estimated, truth),
        "baseline_true_vector": psnr_rms(baseline, truth),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    build, ps = site_point_set(args.build)
    rows = []
    for k, (name, (dni, dhi)) in enumerate(SKIES.items()):
        r = condition(build, ps, name, dni, dhi, seed=k)
        rows.append(r)
        s, b = r["scene_vector"], r["baseline_true_vector"]
        print(f"{name:12s} {r['points']} points: scene estimate RMS {s['rms_pct']:.1f} % "
              f"(bias {s['bias_pct']:+.1f} %), true sky {b['rms_pct']:.1f} % (bias "
              f"{b['bias_pct']:+.1f} %); sun {r['estimate']['sun_w_m2']:.0f} (truth "
              f"{r['truth']['dni_w_m2']:.0f}), sky {r['estimate']['sky_w_m2']:.0f} (truth "
              f"{r['truth']['dhi_w_m2']:.0f})", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
