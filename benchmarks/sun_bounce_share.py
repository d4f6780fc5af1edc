"""The sun's bounce's share of the irradiance at points near walls (docs/sun.md, item 5).

    PYTHONPATH=. python benchmarks/sun_bounce_share.py BUILD [--sun AZ,EL]

Under ``daylit.sky.clear_sky(AZ, EL)`` (its sky without the disc as the light vector, its
DNI as the sun), per point: the sky ``I``, the sun's direct term (every caster) and the sun's
bounce ``I``, all from the EXR masters; the share is bounce / (sky + direct + bounce), on
luminance (Rec. 709 weights). Points, found from the build itself:

- ``ground near a wall, shaded``: ground-atlas texels in the sun's shadow (every caster)
  0.25-2 m from a virtual or real surface;

in every group only points with at least a tenth of the open ground's sky irradiance (not
under a roof or inside a model);
- ``wall in shade``: wall texels (real proxies' faces) the sun does not reach;
- ``hull, shaded faces``: hull-plane texels on vertical planes facing away from the sun;
- ``lightmap, shaded faces``: points on the virtual models' vertical faces facing away from
  the sun (sampled on ``site.glb``);
- ``open ground, sunlit, far from walls``: ground texels in full sun more than 8 m from any
  surface.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import trimesh

from bake.evaluate import Build, ProbeError
from bake.gltf import read_site_glb
from daylit.sky import (
    SUN_SOLID_ANGLE_SR,
    clear_sky,
    direction_from_azimuth_elevation,
    patch_mean_radiance,
)

LUMA = np.array([0.2126, 0.7152, 0.0722])


def plane_texels(build: Build, atlas: str, kinds: tuple, step: int):
    """Every ``step``-th texel centre (point, normal) of the plane receivers of ``kinds``."""
    points, normals = [], []
    for r in build.atlases.get(atlas, {}).get("receivers", []):
        if r["kind"] not in kinds:
            continue
        w, h = r["rect"][2], r["rect"][3]
        for y in range(1, h - 1, step):
            for x in range(1, w - 1, step):
                points.append(
                    np.array(r["origin_m"])
                    + (x + 0.5) * r["texel_m"] * np.array(r["axis_u"])
                    + (y + 0.5) * r["texel_m"] * np.array(r["axis_v"])
                )
                normals.append(r["normal"])
    return np.array(points).reshape(-1, 3), np.array(normals, dtype=float).reshape(-1, 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("build")
    parser.add_argument("--sun", default="235,30", help="AZ_DEG,EL_DEG (default 235,30)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    az, el = (float(v) for v in args.sun.split(","))
    build = Build(args.build)
    sky = clear_sky(az, el)
    r = patch_mean_radiance(sky, build.dome_vertices, include_sun=False)
    dni = np.asarray(sky.sun_radiance, dtype=float) * SUN_SOLID_ANGLE_SR
    s = direction_from_azimuth_elevation(az, el)
    up = np.array([light["cosine_weighted_sr"] for light in build.manifest["dome"]["lights"]])
    open_sky = float((up @ r) @ LUMA)  # the open ground's sky irradiance
    started = time.perf_counter()

    nodes = read_site_glb(build.dir / build.manifest["model"]["path"])
    meshes = [
        trimesh.Trimesh(n["vertices"], n["faces"], process=False)
        for n in nodes.values()
        if n["extras"].get("role") in ("virtual", "real")
    ]
    solid = trimesh.util.concatenate(meshes)
    virtual = trimesh.util.concatenate(
        [
            trimesh.Trimesh(n["vertices"], n["faces"], process=False)
            for n in nodes.values()
            if n["extras"].get("role") == "virtual"
        ]
    )

    def distance(points):
        return trimesh.proximity.closest_point(solid, points)[1]

    casters = build.sun_casters
    groups = {}
    ground, ground_n = plane_texels(build, "ground", ("ground",), 1)
    v = casters.visible_fraction(ground, ground_n, s, "all")
    dist = distance(ground)
    groups["ground near a wall, shaded (0.25-2 m)"] = (
        ground[(v == 0) & (dist >= 0.25) & (dist <= 2.0)],
        ground_n[(v == 0) & (dist >= 0.25) & (dist <= 2.0)],
    )
    far = (v == 1) & (dist > 8.0)
    groups["open ground, sunlit, > 8 m from walls"] = (ground[far], ground_n[far])
    wall, wall_n = plane_texels(build, "ground", ("wall",), 1)
    v = casters.visible_fraction(wall, wall_n, s, "all")
    groups["wall in shade"] = (wall[v == 0], wall_n[v == 0])
    hull, hull_n = plane_texels(build, "hull", ("hull",), 1)
    away = (np.abs(hull_n[:, 1]) < 0.3) & (hull_n @ s < 0.0)
    groups["hull, vertical faces away from the sun"] = (hull[away], hull_n[away])
    samples, faces = trimesh.sample.sample_surface_even(virtual, 4000, seed=3)
    fn = virtual.face_normals[faces]
    away = (np.abs(fn[:, 1]) < 0.3) & (fn @ s < 0.0)
    groups["lightmap, vertical faces away from the sun"] = (
        samples[away] + 0.0 * fn[away], fn[away]
    )

    rows = []
    for name, (points, normals) in groups.items():
        if len(points) > 400:  # at most 400 per group, spread evenly
            keep = np.linspace(0, len(points) - 1, 400).astype(int)
            points, normals = points[keep], normals[keep]
        sky_part, direct, bounce, used = [], [], [], []
        vis = casters.visible_fraction(points, normals, s, "all") if len(points) else []
        for k, (p, n) in enumerate(zip(points, normals, strict=True)):
            try:
                e_sky = build.irradiance(p, n, r)["with"]
                e_bounce = build.sun_bounce([p], [n], s, dni)["with"][0]
            except ProbeError:
                continue  # e.g. a model point hidden by a hull plane's locate, or none
            sky_part.append(e_sky)
            direct.append(dni * max(0.0, float(n @ s)) * vis[k])
            bounce.append(e_bounce)
            used.append(k)
        if not used:
            rows.append({"group": name, "points": 0})
            continue
        sky_l = np.array(sky_part) @ LUMA
        direct_l = np.array(direct) @ LUMA
        bounce_l = np.array(bounce) @ LUMA
        # Points under a roof or inside a model (the ground atlas runs under the buildings):
        # less than a tenth of the open ground's sky. Left out.
        outdoors = sky_l > 0.1 * open_sky
        sky_l, direct_l, bounce_l = sky_l[outdoors], direct_l[outdoors], bounce_l[outdoors]
        used = [k for k, ok in zip(used, outdoors, strict=True) if ok]
        if not used:
            rows.append({"group": name, "points": 0})
            continue
        share = bounce_l / (sky_l + direct_l + bounce_l)
        rows.append(
            {
                "group": name,
                "points": len(used),
                "share_median": round(float(np.median(share)), 4),
                "share_p10": round(float(np.percentile(share, 10)), 4),
                "share_p90": round(float(np.percentile(share, 90)), 4),
                "sky_W_m2": round(float(np.median(sky_l)), 1),
                "sun_W_m2": round(float(np.median(direct_l)), 1),
                "sun_bounce_W_m2": round(float(np.median(bounce_l)), 1),
            }
        )
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    lights = build.light_count
    print(
        f"{args.build}: {lights} lights; clear sky, sun at azimuth {az:g}, elevation {el:g}, "
        f"DNI {dni.round(0).tolist()} W/m^2 ({time.perf_counter() - started:.0f} s)"
    )
    print(f"{'points':<45}{'n':>5}{'share median':>14}{'p10-p90':>14}"
          f"{'sky':>8}{'sun':>8}{'bounce':>8}  (medians, W/m^2, luminance)")
    for row in rows:
        if not row["points"]:
            print(f"{row['group']:<45}{0:>5}")
            continue
        print(
            f"{row['group']:<45}{row['points']:>5}{row['share_median']:>14.1%}"
            f"{row['share_p10']:>7.1%}-{row['share_p90']:<6.1%}{row['sky_W_m2']:>8}"
            f"{row['sun_W_m2']:>8}{row['sun_bounce_W_m2']:>8}"
        )


if __name__ == "__main__":
    main()
