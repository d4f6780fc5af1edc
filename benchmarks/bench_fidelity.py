"""Fidelity against Radiance (issue 15): daylit's irradiance at points of a build beside rtrace's.

Radiance (``pyradiance``'s wheel: ``gendaylit``, ``oconv``, ``rtrace``) renders the same scene
under the same skies, and ``daylit probe`` answers the same points:

- **Scene** and **skies**: as ``benchmarks/radiance.py`` converts them (the build's meshes as
  Lambertian polygons, the ground a 40 km square; gendaylit's Perez skies at the site) for a
  clear, an intermediate and an overcast condition. daylit gets the same sky function sampled
  into an equirectangular EXR as ``--env``, and the sun as ``--sun AZ,EL,DNI`` with
  gendaylit's direction and DNI = the sun's radiance times its disc's solid angle.
- **Points** (``benchmarks/fidelity_points.py``): grids over the ground and the real proxies'
  walls, points on the models' own faces, and for each sky with a sun, lines of closely
  spaced ground points across the sun's shadow edges of the hall, the fence and the visitor
  centre.
- **Radiance's answer**: ``rtrace -I`` (irradiance at the point with its normal, 2 mm off the
  surface), sky and sun rendered apart (Radiance is linear in its sources): the sky with
  ``-ab 1`` (direct) and ``-ab 2`` (plus one bounce); the sun's direct term with ``-ab 0 -dj
  1`` repeated (jittered over the disc) and averaged; the sun's first bounce as ``-ab 1``
  minus ``-ab 0`` with ``-dj 0``. The reference is *direct + one bounce of sky and sun*
  (*full*), what daylit's bake models (the sky's bounce in the basis stacks, the sun's in the
  sun-bounce stacks); *no sun bounce* sets daylit's total without its sun-bounce part beside
  Radiance's without the sun's bounce (what the bake had before the sun-bounce stacks), and
  the sun's bounce part alone is compared too; a second bounce (sky ``-ab 3``, sun ``-ab 2``)
  is printed for the record. Ground and wall points are also rendered without the virtual
  objects (real proxies only), as daylit's ``without_virtual_objects``.
- **daylit's answer**: ``daylit probe BUILD --points FILE --env SKY.exr --sun AZ,EL,DNI
  --json`` from the masters and with ``--compact``: ``irradiance_W_m2`` (sky + sun direct +
  sun bounce) and its parts.

Metrics per sky: PSNR with the largest reference value over the group's points as peak (all
three channels), RMS error relative to the mean reference, on all points, ground only, walls
and roofs only, against the full reference; along each shadow line the 10-90 % penumbra width
and the 50 % point of the normalised profile, daylit's against Radiance's; the worst points.
Before that a self-check of the conversion (seconds): open ground under a uniform sky gives
pi L, the sun alone DNI max(0, n.s) on four walls and the ground, and the sky map integrates
to rtrace's irradiance.

Run (a bake at 160 lights, then about 5 minutes on the 2-core reference machine; pyradiance
is a benchmark-only dependency, no test needs it)::

    .venv/bin/pip install pyradiance==1.3.1
    .venv/bin/daylit bake scenes/demo -o build/demo160 --lights 160 --quality final
    nice -n 10 .venv/bin/python benchmarks/bench_fidelity.py build/demo160

``--self-check`` runs the known-answer checks alone; ``--json FILE`` writes the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.fidelity_metrics import profile_points, psnr_rms  # noqa: E402
from benchmarks.fidelity_points import PointSet, shadow_lines, site_points  # noqa: E402
from benchmarks.radiance import (  # noqa: E402
    REPO,
    SKIES,
    SKY_BOUNCE,
    SKY_DIRECT,
    SKY_TWO_BOUNCES,
    SUN_BOUNCE_AMB,
    SUN_DIRECT,
    SUN_HARD,
    Sky,
    gendaylit,
    measurement_rays,
    oconv,
    radiance_env,
    rtrace,
    scene_files,
    self_check,
    sky_map,
    sky_rad,
    sun_direct,
    sun_rad,
)

# ------------------------------------------------------------------------------------------
# One sky: Radiance's and daylit's answers


def radiance_answers(sky: Sky, ps: PointSet, scene: dict, env: dict, work: Path, procs: int,
                     repeats: int, line_repeats: int, progress) -> dict:
    """rtrace's parts at every point (W/m^2, (m, 3)): ``sky_direct`` (-ab 1), ``sky`` (-ab 2),
    ``sun`` (direct, disc jittered), ``sun_bounce`` (the sun's first bounce), and the same
    without the virtual objects (``*_real``) where the point has a ``d`` (ground, walls)."""
    name = sky.spec.name
    f = scene["files"]
    sky.files["sky"] = work / f"sky_{name}.rad"
    sky.files["sky"].write_text(sky_rad(sky.skyfunc))
    sky.files["sun"] = work / f"sun_{name}.rad"
    sky.files["sun"].write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance))
    octrees = {}
    for light in ("sky", "sun"):
        octrees[light] = oconv(work / f"{light}_{name}_all.oct",
                               [sky.files[light], f["virtual"], f["real"], f["ground"]], env)
        octrees[light + "_real"] = oconv(work / f"{light}_{name}_real.oct",
                                         [sky.files[light], f["real"], f["ground"]], env)
    rays = measurement_rays(ps.points, ps.normals)
    has_d = np.array([g != "model" for g in ps.group])
    is_line = np.array([g == "line" for g in ps.group])
    out = {}
    for suffix, keep in (("", np.ones(len(ps), bool)), ("_real", has_d)):
        part = rays[keep]
        t0 = time.perf_counter()
        sky_direct = rtrace(octrees["sky" + suffix], part, SKY_DIRECT, env, procs=procs)
        progress(f"rtrace sky -ab 1{suffix}", len(part), t0)
        t0 = time.perf_counter()
        sky_bounce = rtrace(octrees["sky" + suffix], part, SKY_BOUNCE, env, procs=procs)
        progress(f"rtrace sky -ab 2{suffix}", len(part), t0)
        sun = np.zeros((len(part), 3))
        sun_bounce = np.zeros((len(part), 3))
        if sky.has_sun:
            t0 = time.perf_counter()
            lines = is_line[keep]
            sun[~lines] = sun_direct(octrees["sun" + suffix], part[~lines], repeats, env, procs)
            sun[lines] = sun_direct(octrees["sun" + suffix], part[lines], line_repeats, env,
                                    procs)
            progress(f"rtrace sun -ab 0 -dj 1{suffix}", len(part), t0)
            t0 = time.perf_counter()
            hard = rtrace(octrees["sun" + suffix], part, ["-ab", "0", *SUN_HARD], env,
                          procs=procs)
            with_bounce = rtrace(octrees["sun" + suffix], part,
                                 ["-ab", "1", *SUN_HARD, *SUN_BOUNCE_AMB], env, procs=procs)
            sun_bounce = with_bounce - hard
            progress(f"rtrace sun bounce (-ab 1 - -ab 0){suffix}", len(part), t0)
        if not suffix:
            # Two bounces (sky -ab 3, sun -ab 2): what one bounce leaves out, for the record.
            t0 = time.perf_counter()
            out["sky_2b"] = rtrace(octrees["sky"], part, SKY_TWO_BOUNCES, env, procs=procs)
            out["sun_bounce_2b"] = np.zeros((len(part), 3))
            if sky.has_sun:
                out["sun_bounce_2b"] = rtrace(octrees["sun"], part,
                                              ["-ab", "2", *SUN_HARD, *SUN_BOUNCE_AMB], env,
                                              procs=procs) - hard
            progress("rtrace two bounces (sky -ab 3, sun -ab 2)", len(part), t0)
        for key, value in (("sky_direct", sky_direct), ("sky", sky_bounce), ("sun", sun),
                           ("sun_bounce", sun_bounce)):
            full = np.full((len(ps), 3), np.nan)
            full[keep] = value
            out[key + suffix] = full
    return out


def daylit_answers(build_dir: Path, sky: Sky, ps: PointSet, work: Path, compact: bool) -> dict:
    """``daylit probe --json`` at the points: ``irradiance`` (sky + sun + sun bounce),
    ``sky``, ``sun``, ``sun_bounce``, ``visible``, and the ``*_real`` (without the virtual
    objects; NaN where the receiver has no d). Exits if the build has no sun bounce for a sky
    with a sun (a build baked before 2026-11-24): its figures would not be daylit's."""
    csv = work / "points.csv"
    if not csv.exists():
        lines = [",".join(f"{x:.6f}" for x in (*p, *n))
                 for p, n in zip(ps.points, ps.normals, strict=True)]
        csv.write_text("# x,y,z,nx,ny,nz (site frame, metres)\n" + "\n".join(lines) + "\n")
    cmd = [sys.executable, "-m", "daylit.cli", "probe", str(build_dir), "--points", str(csv),
           "--env", str(sky.exr), "--json"]
    if sky.has_sun:
        cmd += ["--sun", sky.sun_arg()]
    if compact:
        cmd.append("--compact")
    env = dict(os.environ)
    env["PYTHONPATH"] = f"{REPO}{os.pathsep}{env.get('PYTHONPATH', '')}"
    done = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"daylit probe failed ({' '.join(cmd)}):\n{done.stderr}")
    if sky.has_sun and "no sun bounce" in done.stderr:
        sys.exit(f"daylit probe: {done.stderr.strip()}\nbake the build again: its figures would "
                 "leave the sun's bounce out")
    results = json.loads(done.stdout)
    m = len(results)
    out = {k: np.full((m, 3), np.nan) for k in ("irradiance", "sky", "sun", "sun_bounce",
                                                "irradiance_real", "sky_real", "sun_real",
                                                "sun_bounce_real")}
    out["visible"] = np.full(m, np.nan)
    out["atlas"] = []
    for k, r in enumerate(results):
        out["atlas"].append(r["receiver"]["atlas"])
        for suffix, part in (("", r), ("_real", r["without_virtual_objects"])):
            if part is None:
                continue
            out["irradiance" + suffix][k] = part["irradiance_W_m2"]
            out["sky" + suffix][k] = part["sky_W_m2"]
            out["sun" + suffix][k] = part["sun_W_m2"] or [0.0, 0.0, 0.0]
            out["sun_bounce" + suffix][k] = part["sun_bounce_W_m2"] or [0.0, 0.0, 0.0]
        out["visible"][k] = r["sun_visible_fraction"] if r["sun_visible_fraction"] is not None \
            else np.nan
    return out


GROUPS = {
    "all": ("ground", "wall", "model"),
    "ground": ("ground",),
    "walls+roofs": ("wall", "model"),
}


def report_sky(sky: Sky, ps: PointSet, rad: dict, dl: dict, dlc: dict) -> dict:
    """Print and return one sky's figures.

    *full*: daylit's total (sky + sun + sun bounce) against Radiance's direct + one bounce of
    sky and sun, the goal's reference; *no sun bounce*: both without the sun's bounce (the
    like-for-like figure of the bake before its sun-bounce stacks); *sun bounce*: daylit's
    sun-bounce part against Radiance's, with its own peak."""
    full = rad["sky"] + rad["sun"] + rad["sun_bounce"]
    like = rad["sky"] + rad["sun"]
    two = rad["sky_2b"] + rad["sun"] + rad["sun_bounce_2b"]
    ours_like = dl["irradiance"] - dl["sun_bounce"]
    group = np.array(ps.group)
    out = {"sun": {"azimuth_deg": sky.azimuth_deg, "elevation_deg": sky.elevation_deg,
                   "dni_W_m2": sky.dni}, "gendaylit": sky.header, "groups": {}, "lines": {},
           "worst": []}
    print(f"  {'points':<12} {'n':>4}  {'PSNR full':>9} {'RMS':>6} {'bias':>6}  {'compact':>7}  "
          f"{'no s.b.':>7} {'RMS':>6}  {'sun bounce':>10} {'RMS':>6} {'bias':>6}  "
          f"{'sky part':>8}  {'sun part':>8}  {'peak W/m2':>9}")
    for gname, members in GROUPS.items():
        keep = np.isin(group, members)
        row = {
            "full": psnr_rms(dl["irradiance"][keep], full[keep]),
            "compact": psnr_rms(dlc["irradiance"][keep], full[keep]),
            "no_sun_bounce": psnr_rms(ours_like[keep], like[keep]),
            "sky_part": psnr_rms(dl["sky"][keep], rad["sky"][keep]),
            "sky_part_vs_ab1": psnr_rms(dl["sky"][keep], rad["sky_direct"][keep]),
            "sun_part": psnr_rms(dl["sun"][keep], rad["sun"][keep]) if sky.has_sun else None,
            "sun_bounce_part": psnr_rms(dl["sun_bounce"][keep], rad["sun_bounce"][keep])
            if sky.has_sun else None,
            "two_bounces": psnr_rms(dl["irradiance"][keep], two[keep]),
        }
        # The share of the squared error that the sun bounce's error makes (1 - the mean square
        # of the rest over the whole's).
        mse_full = np.nanmean((dl["irradiance"][keep] - full[keep]) ** 2)
        mse_rest = np.nanmean((ours_like[keep] - like[keep]) ** 2)
        row["sun_bounce_share_of_sq_error"] = float(1.0 - mse_rest / mse_full) if mse_full else 0.0
        out["groups"][gname] = row
        sun_part = f"{row['sun_part']['psnr_db']:8.1f}" if row["sun_part"] else f"{'-':>8}"
        b = row["sun_bounce_part"]
        bounce = (f"{b['psnr_db']:10.1f} {b['rms_pct']:5.1f}% {b['bias_pct']:+5.1f}%" if b
                  else f"{'-':>10} {'-':>6} {'-':>6}")
        print(f"  {gname:<12} {row['full']['n']:>4}  {row['full']['psnr_db']:9.1f} "
              f"{row['full']['rms_pct']:5.1f}% {row['full']['bias_pct']:+5.1f}%  "
              f"{row['compact']['psnr_db']:7.1f}  {row['no_sun_bounce']['psnr_db']:7.1f} "
              f"{row['no_sun_bounce']['rms_pct']:5.1f}%  {bounce}  "
              f"{row['sky_part']['psnr_db']:8.1f}  {sun_part}  {row['full']['peak_W_m2']:9.1f}")
    print("  (PSNR in dB, peak = the largest Radiance value of the group; RMS and bias relative "
          "to the mean; full = daylit's total against Radiance's direct + one bounce of sky and "
          "sun; compact: the same from the compact textures; no s.b. = both without the sun's "
          "bounce; sun bounce, sky part, sun part: daylit's part against Radiance's own, each "
          "with its own peak; no virtual: ground and walls without the virtual objects, "
          "daylit's d against Radiance with the real proxies alone)")
    # Without the virtual objects: daylit's d against Radiance with the real proxies alone.
    keep = np.isin(group, ("ground", "wall"))
    full_real = rad["sky_real"] + rad["sun_real"] + rad["sun_bounce_real"]
    like_real = rad["sky_real"] + rad["sun_real"]
    row = {"full": psnr_rms(dl["irradiance_real"][keep], full_real[keep]),
           "compact": psnr_rms(dlc["irradiance_real"][keep], full_real[keep]),
           "no_sun_bounce": psnr_rms(dl["irradiance_real"][keep] - dl["sun_bounce_real"][keep],
                                     like_real[keep]),
           "sun_bounce_part": psnr_rms(dl["sun_bounce_real"][keep], rad["sun_bounce_real"][keep])
           if sky.has_sun else None}
    out["groups"]["without virtual (ground+walls)"] = row
    b = row["sun_bounce_part"]
    bounce = (f"{b['psnr_db']:10.1f} {b['rms_pct']:5.1f}% {b['bias_pct']:+5.1f}%" if b
              else f"{'-':>10} {'-':>6} {'-':>6}")
    print(f"  {'no virtual':<12} {row['full']['n']:>4}  "
          f"{row['full']['psnr_db']:9.1f} {row['full']['rms_pct']:5.1f}% "
          f"{row['full']['bias_pct']:+5.1f}%  {row['compact']['psnr_db']:7.1f}  "
          f"{row['no_sun_bounce']['psnr_db']:7.1f} {row['no_sun_bounce']['rms_pct']:5.1f}%  "
          f"{bounce}")

    if ps.lines:
        print(f"  {'shadow line':<15} {'edge':>5} {'D m':>5} {'disc mm':>8} {'Radiance 10-90':>14} "
              f"{'daylit':>7} {'diff':>6}  {'compact':>7}  {'50% pt: daylit-Radiance':>23}")
    if ps.lines:
        print("  (edge: height of the casting edge, D: its distance along the sun's ray, disc: "
              "2 D tan(r) / sin(el), the disc's whole penumbra; widths: 10-90 % of the "
              "normalised total irradiance, Radiance's full against daylit's masters)")
    for lname, line in ps.lines.items():
        idx, t = line["index"], line["t"]
        ref = profile_points(t, full[idx].mean(axis=1))
        ours = profile_points(t, dl["irradiance"][idx].mean(axis=1))
        comp = profile_points(t, dlc["irradiance"][idx].mean(axis=1))
        sun_ref = profile_points(t, rad["sun"][idx].mean(axis=1))
        sun_ours = profile_points(t, dl["sun"][idx].mean(axis=1))
        entry = {
            "edge_height_m": line["edge_height_m"], "distance_m": line["distance_m"],
            "penumbra_geometric_m": line["penumbra_geometric_m"],
            "start_m": line["points"][0], "end_m": line["points"][-1],
            "radiance": ref, "daylit": ours, "compact": comp, "radiance_sun": sun_ref,
            "daylit_sun": sun_ours,
            "width_ratio": ours["width_m"] / ref["width_m"],
            "compact_width_ratio": comp["width_m"] / ref["width_m"],
            "t50_offset_m": ours["t50_m"] - ref["t50_m"],
            "compact_t50_offset_m": comp["t50_m"] - ref["t50_m"],
            "t": t, "profile_radiance": full[idx].mean(axis=1),
            "profile_daylit": dl["irradiance"][idx].mean(axis=1),
            "profile_compact": dlc["irradiance"][idx].mean(axis=1),
        }
        out["lines"][lname] = entry
        print(f"  {lname:<15} {line['edge_height_m']:5.1f} {line['distance_m']:5.1f} "
              f"{1e3 * line['penumbra_geometric_m']:8.0f} {1e3 * ref['width_m']:11.0f} mm "
              f"{1e3 * ours['width_m']:4.0f} mm {100 * (entry['width_ratio'] - 1):+5.0f}%  "
              f"{100 * (entry['compact_width_ratio'] - 1):+6.0f}%  "
              f"{1e3 * entry['t50_offset_m']:+10.1f} mm "
              f"({100 * entry['t50_offset_m'] / ref['width_m']:+.0f} % of the width)")

    # The worst points (not on the lines), against the full reference.
    keep = np.flatnonzero(group != "line")
    err = (dl["irradiance"][keep] - full[keep]).mean(axis=1)
    order = keep[np.argsort(-np.abs(err))][:8]
    print("  worst points (daylit - Radiance full, channel mean; the sun's bounce, daylit's "
          "and Radiance's, and V):")
    for k in order:
        ref_k, ours_k = full[k].mean(), dl["irradiance"][k].mean()
        cos = max(0.0, float(ps.normals[k] @ sky.sun_dir))
        v_rad = rad["sun"][k].mean() / (sky.dni * cos) if sky.has_sun and cos > 0 else np.nan
        item = {"group": ps.group[k], "label": ps.label[k], "atlas": dl["atlas"][k],
                "point_m": ps.points[k], "normal": ps.normals[k], "radiance_W_m2": ref_k,
                "daylit_W_m2": ours_k, "sun_bounce_W_m2": rad["sun_bounce"][k].mean(),
                "sun_bounce_daylit_W_m2": dl["sun_bounce"][k].mean(),
                "sky_radiance_W_m2": rad["sky"][k].mean(), "sky_daylit_W_m2": dl["sky"][k].mean(),
                "v_daylit": dl["visible"][k], "v_radiance": v_rad}
        out["worst"].append(item)
        p, n = ps.points[k], ps.normals[k]
        where = f"{ps.label[k]} [{dl['atlas'][k]}]"
        pct = 100 * (ours_k - ref_k) / max(ref_k, 1e-9)
        sky_pair = f"{dl['sky'][k].mean():6.1f} vs {rad['sky'][k].mean():6.1f}"
        print(f"    {where:<34} ({p[0]:7.2f},{p[1]:5.2f},{p[2]:7.2f}) n ({n[0]:+.2f},"
              f"{n[1]:+.2f},{n[2]:+.2f})  {ours_k:6.1f} vs {ref_k:6.1f} ({pct:+5.1f} %)  sky "
              f"{sky_pair}  sun bounce {dl['sun_bounce'][k].mean():5.1f} vs "
              f"{rad['sun_bounce'][k].mean():5.1f}  V "
              f"{dl['visible'][k]:.2f} vs {v_rad:.2f}")
    return out


def print_summary(results: dict) -> None:
    """The figures against the issue's goals: PSNR >= 35 dB, penumbra width within 20 %."""
    print("\nsummary against the goals (PSNR >= 35 dB on all points against the full "
          "reference; 10-90 % penumbra width within 20 % of Radiance's):")
    print(f"  {'sky':<13} {'PSNR full':>9} {'2 bounces':>9} {'ground':>7} {'walls+roofs':>11} "
          f"{'compact':>7} {'no s.b.':>7} {'sun bounce':>10} {'its share':>9}  penumbra width "
          "(daylit / Radiance - 1), 50 % point")
    for name, sky in results["skies"].items():
        g = sky["groups"]
        widths = ", ".join(f"{k} {100 * (v['width_ratio'] - 1):+.0f}% "
                           f"{1e3 * v['t50_offset_m']:+.1f} mm"
                           for k, v in sky["lines"].items()) or "-"
        a = g["all"]
        bounce = (f"{a['sun_bounce_part']['psnr_db']:10.1f}" if a["sun_bounce_part"]
                  else f"{'-':>10}")
        print(f"  {name:<13} {a['full']['psnr_db']:9.1f} {a['two_bounces']['psnr_db']:9.1f} "
              f"{g['ground']['full']['psnr_db']:7.1f} {g['walls+roofs']['full']['psnr_db']:11.1f} "
              f"{a['compact']['psnr_db']:7.1f} {a['no_sun_bounce']['psnr_db']:7.1f} {bounce} "
              f"{100 * a['sun_bounce_share_of_sq_error']:8.0f}%  {widths}")
    print("  full: daylit's total against Radiance's direct + one bounce of sky and sun (ground, "
          "walls+roofs, compact likewise); 2 bounces: against + a second; no s.b.: both without "
          "the sun's bounce; sun bounce: daylit's sun-bounce part against Radiance's (its own "
          "peak); its share: the sun bounce's share of the squared error against 'full'")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("build", type=Path, help="a baked build (e.g. build/demo160)")
    parser.add_argument("--work", type=Path, help="keep Radiance's files here (default: a "
                        "temporary folder)")
    parser.add_argument("--skies", default=",".join(s.name for s in SKIES),
                        help="which of " + ", ".join(s.name for s in SKIES))
    parser.add_argument("--ground-step", type=float, default=6.0, help="ground grid, metres")
    parser.add_argument("--wall-step", type=float, default=3.0, help="wall grid, metres")
    parser.add_argument("--model-points", type=int, default=200,
                        help="points on the models' own faces")
    parser.add_argument("--line-points", type=int, default=81, help="points per shadow line")
    parser.add_argument("--repeats", type=int, default=64,
                        help="jittered sun samples per point (-dj 1 runs averaged)")
    parser.add_argument("--line-repeats", type=int, default=1024,
                        help="jittered sun samples per shadow-line point")
    parser.add_argument("--procs", type=int, default=1, help="rtrace -n")
    parser.add_argument("--self-check", action="store_true", help="the known answers only")
    parser.add_argument("--json", type=Path, help="write the figures as JSON")
    args = parser.parse_args()
    started = time.perf_counter()
    _, env = radiance_env()
    work = args.work or Path(tempfile.mkdtemp(prefix="daylit-fidelity-"))
    work.mkdir(parents=True, exist_ok=True)
    scene = scene_files(args.build, work)
    print(f"scene: {scene['triangles']['virtual']} virtual and {scene['triangles']['real']} real "
          f"triangles, ground albedo {scene['manifest']['ground']['albedo']}; work in {work}")
    checks = self_check(scene, env, work / "check")
    results = {"command": " ".join(sys.argv), "build": str(args.build), "self_check": checks,
               "radiance": {"sky_direct": SKY_DIRECT, "sky": SKY_BOUNCE, "sun": SUN_DIRECT,
                            "sun_bounce": SUN_HARD + SUN_BOUNCE_AMB, "repeats": args.repeats,
                            "line_repeats": args.line_repeats}, "skies": {}}
    if args.self_check:
        return

    from bake.evaluate import Build
    from bake.gltf import read_site_glb
    from daylit.envmap import write_equirect_exr

    build = Build(args.build)
    nodes = read_site_glb(args.build / build.manifest["model"]["path"])
    base = site_points(build, nodes, args.ground_step, args.wall_step, args.model_points)
    print("points: " + ", ".join(f"{base.group.count(g)} {g}" for g in ("ground", "wall",
                                                                         "model")))

    def progress(what, count, t0):
        print(f"    {what}: {count} points, {time.perf_counter() - t0:.1f} s", flush=True)

    specs = {s.name: s for s in SKIES}
    for name in args.skies.split(","):
        spec = specs[name]
        sky = gendaylit(spec, scene["manifest"], env)
        sky_work = work / name
        sky_work.mkdir(exist_ok=True)
        print(f"\nsky {name}: {spec.year}-{spec.month:02d}-{spec.day:02d} {spec.hour} "
              f"(standard time), DNI {spec.dni:g}, DHI {spec.dhi:g} W/m^2 -> sun az "
              f"{sky.azimuth_deg:.2f} el {sky.elevation_deg:.2f} deg, DNI {sky.dni:.1f}")
        ps = PointSet(base.points.copy(), base.normals.copy(), list(base.group), list(base.label))
        if sky.has_sun:
            for line in shadow_lines(build, nodes, sky.sun_dir, args.line_points):
                index = ps.extend(line["points"], np.tile([0.0, 1.0, 0.0], (len(line["t"]), 1)),
                                  "line", line["name"])
                ps.lines[line["name"]] = {**line, "index": index}
        t0 = time.perf_counter()
        sky.files["sky"] = sky_work / "sky.rad"
        sky.files["sky"].write_text(sky_rad(sky.skyfunc))
        sky.exr = sky_work / "sky.exr"
        write_equirect_exr(sky.exr, sky_map(sky, sky_work, env))
        progress("sky map (rtrace, 720 x 360, 2 x 2 rays a pixel)", 0, t0)
        rad = radiance_answers(sky, ps, scene, env, sky_work, args.procs, args.repeats,
                               args.line_repeats, progress)
        t0 = time.perf_counter()
        dl = daylit_answers(args.build, sky, ps, sky_work, compact=False)
        progress("daylit probe", len(ps), t0)
        t0 = time.perf_counter()
        dlc = daylit_answers(args.build, sky, ps, sky_work, compact=True)
        progress("daylit probe --compact", len(ps), t0)
        results["skies"][name] = report_sky(sky, ps, rad, dl, dlc)
    print_summary(results)
    print(f"\ntotal {time.perf_counter() - started:.0f} s")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=_jsonable))


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return float(value)


if __name__ == "__main__":
    main()
