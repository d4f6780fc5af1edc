"""``daylit bake``, ``daylit sun-bounce`` and ``daylit probe``.

Exit status: 0 done; 2 bad input (the message names the file and key; nothing is written);
130 interrupted (a later bake of the same scene resumes from the finished parts).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EXIT_BAD_INPUT = 2


def add_subcommands(subparsers) -> None:
    bake = subparsers.add_parser(
        "bake",
        help="bake a site description into relightable assets",
        description=(
            "Bake scenes/<site>/scene.toml into a build directory: the light dome, shadowing "
            "planes, lightmaps and fixed views with their basis images (EXR masters), site.glb "
            "and manifest.json. Output appears only when complete; an interrupted bake resumes."
        ),
        epilog="example: daylit bake scenes/demo -o build/demo --quality draft",
    )
    bake.add_argument("scene", type=Path, help="site folder holding scene.toml (or the file)")
    bake.add_argument("-o", "--out", type=Path, required=True, help="build directory to write")
    bake.add_argument(
        "--lights",
        type=int,
        metavar="N",
        help="dome size (overrides the scene's dome.lights; the nearest geodesic "
        "count is used: 40, 160, 360, 640... or 36, 64, ..., 400, ...)",
    )
    bake.add_argument(
        "--quality",
        choices=("draft", "final"),
        help="draft for quick looks and tests, final for the site "
        "(default: the scene's quality.default)",
    )
    bake.add_argument(
        "--budget",
        type=_budget,
        metavar="E",
        help="error budget of the compact textures: composite RMS error over the mean on the "
        "test skies, as a fraction or a percentage (0.01 or 1%%; default: the scene's "
        "compression.budget, else 1%%)",
    )
    bake.add_argument(
        "--workers", type=int, metavar="N", help="processes to use (default: one per core)"
    )
    bake.add_argument(
        "--cluster",
        metavar="tcp://HOST:8786",
        help="trace on the workers of this Dask scheduler instead of local processes (the "
        "same output byte for byte; each worker needs the same daylit installed)",
    )
    bake.add_argument(
        "--sun-bounce-dates",
        type=_sun_bounce_dates,
        metavar="FIRST..LAST",
        help="make sun-bounce images only for the dome patches the sun crosses on these local "
        "dates (2026-06-01..2026-08-31, at most a year): a shorter write stage and fewer "
        "files to serve; outside them a client draws no sun bounce (default: every patch "
        "the sun crosses in a year)",
    )
    bake.add_argument("--no-progress", action="store_true", help="no progress bar")
    bake.set_defaults(run=run_bake)

    sun = subparsers.add_parser(
        "sun-bounce",
        help="make a build's sun-bounce images again for other dates, from its masters",
        description=(
            "Make the sun-bounce images of a build again, for the dome patches the sun "
            "crosses on the dates given, from the build's EXR masters (no tracing), judged "
            "as the bake judges them under the scene's compression settings; the old images "
            "are replaced in one step (the manifest is renamed into place) and deleted. Run it "
            "ahead of the dates a site serves, then restart the server."
        ),
        epilog="example: daylit sun-bounce scenes/demo build/demo --dates 2027-04-01..2027-04-30",
    )
    sun.add_argument("scene", type=Path, help="the site folder (or scene.toml) the build was "
                     "baked from")
    sun.add_argument("build", type=Path, help="build directory (with manifest.json and its "
                     "exr/ masters)")
    sun.add_argument("--dates", type=_sun_bounce_dates, required=True, metavar="FIRST..LAST",
                     help="local dates whose sun patches get images (2027-04-01..2027-04-30, "
                     "at most a year)")
    sun.add_argument("--no-progress", action="store_true", help="no progress bar")
    sun.set_defaults(run=run_sun_bounce)

    probe = subparsers.add_parser(
        "probe",
        help="irradiance at points of a build under a sky (and the sun)",
        description=(
            "Evaluate a build at points on its receivers (ground, wall, hull plane or a "
            "model's surface): RGB irradiance in W/m^2, the sky's part from the baked basis "
            "with the virtual objects present, plus the sun's direct term (--sun) ray cast "
            "against the virtual models and real proxies, and each part without the virtual "
            "objects where the receiver has it. Site frame: +X east, +Y up, -Z north, metres. "
            "Negative numbers work as they are: --point -8,0,0 or --point=-8,0,0."
        ),
        epilog=(
            "examples:\n"
            "  daylit probe build/demo --points points.csv --env sky.exr --sun 135,40,850\n"
            "  daylit probe build/demo --point -8,0,20 --normal 0,1,0 --sky overcast:30 --json\n"
            "\n"
            "points file: one 'x,y,z' or 'x,y,z,nx,ny,nz' per line (metres; normal +Y by "
            "default); blank lines and lines starting with # are skipped.\n"
            "sky map: an equirectangular linear-RGB OpenEXR of the sky without the sun's disc, "
            "radiance in W/(m^2 sr), twice as wide as high; row 0 at the zenith, the last row "
            "at the nadir, column 0 starting at north with azimuth growing toward east. Each "
            "dome patch gets its solid-angle weighted mean; the lower half is ignored.\n"
            "exit status: 0 done, 2 bad input (the message says what to fix)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    probe.add_argument("build", type=Path, help="build directory (with manifest.json)")
    where = probe.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--point", metavar="X,Y,Z", help="one point on a receiver surface, metres (site frame)"
    )
    where.add_argument(
        "--points",
        type=Path,
        metavar="FILE",
        help="CSV of points: x,y,z[,nx,ny,nz] per line (see below)",
    )
    probe.add_argument(
        "--normal",
        metavar="X,Y,Z",
        help="the receiver surface's outward normal for --point (default: up, 0,1,0)",
    )
    group = probe.add_mutually_exclusive_group()
    group.add_argument(
        "--env",
        type=Path,
        metavar="SKY.exr",
        help="equirectangular linear-RGB sky map without the sun, W/(m^2 sr) (see below)",
    )
    group.add_argument(
        "--sky",
        default="uniform:1",
        help="a named sky: uniform[:L] | overcast[:Lz] | clear:AZIMUTH_DEG,ELEVATION_DEG "
        "(default: uniform:1; with --sun, a clear sky's own sun disc is left out)",
    )
    group.add_argument(
        "--light-vector", type=Path, metavar="FILE", help="JSON list of n [r, g, b] patch radiances"
    )
    probe.add_argument(
        "--sun",
        metavar="AZ_DEG,EL_DEG,DNI_W_M2",
        help="the sun as its own light: azimuth clockwise from north, elevation above the "
        "horizon (degrees) and direct normal irradiance (W/m^2, grey); its direct term, "
        "shadowed by the virtual models and real proxies, and its bounce off the ground, walls "
        "and models are added",
    )
    probe.add_argument(
        "--compact",
        action="store_true",
        help="the sky's part and the sun's bounce from the compact GPU textures (as the web "
        "client sums them) instead of the EXR masters",
    )
    probe.add_argument(
        "--json",
        action="store_true",
        help="print a JSON list, one object per point: point_m, normal, receiver, "
        "irradiance_W_m2 (sky + sun + sun bounce), sky_W_m2, sun_W_m2, sun_bounce_W_m2, "
        "sun_visible_fraction, without_virtual_objects",
    )
    probe.set_defaults(run=run_probe)


def run_bake(args) -> int:
    from bake.errors import BakeError
    from bake.pipeline import bake
    from bake.scene import SceneError

    try:
        bake(
            args.scene,
            args.out,
            lights=args.lights,
            quality=args.quality,
            workers=args.workers,
            progress=not args.no_progress,
            budget=args.budget,
            cluster=args.cluster,
            sun_bounce_dates=args.sun_bounce_dates,
        )
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BakeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


def run_sun_bounce(args) -> int:
    from bake.errors import BakeError
    from bake.scene import SceneError
    from bake.sunremake import remake_sun_bounce
    from daylit.manifest import ManifestError

    try:
        remake_sun_bounce(args.scene, args.build, args.dates, progress=not args.no_progress)
    except (SceneError, BakeError, ManifestError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


def _sun_bounce_dates(text: str):
    """``--sun-bounce-dates``: "2026-06-01..2026-08-31" -> SunBounceDates."""
    from bake.sundates import SunBounceDates

    try:
        return SunBounceDates.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _budget(text: str) -> float:
    """``--budget``: "0.01" or "1%" -> 0.01 (the range is checked with the scene's settings)."""
    number = text.strip()
    percent = number.endswith("%")
    try:
        value = float(number.rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction or a percentage such as 0.01 or 1%, got {text!r}"
        ) from None
    return value / 100.0 if percent else value


def run_probe(args) -> int:
    from bake import probe
    from bake.evaluate import Build, ProbeError, parse_sky
    from daylit import sky as skies
    from daylit.envmap import EnvMapError, equirect_light_vector, read_equirect_exr
    from daylit.manifest import ManifestError

    try:
        sun = probe.parse_sun(args.sun) if args.sun else None
        if args.points is not None:
            if args.normal is not None:
                raise ProbeError("--normal goes with --point; give normals in the points file")
            points = probe.read_points(args.points)
        else:
            points = probe.single_point(args.point, args.normal or "0,1,0")
        build = Build(args.build)
        if args.env is not None:
            light_vector = equirect_light_vector(read_equirect_exr(args.env), build.dome_vertices)
        elif args.light_vector is not None:
            light_vector = build.light_vector(_json_file(args.light_vector))
        else:
            # With --sun, a clear sky's own disc would count the sun twice: it is left out.
            light_vector = skies.patch_mean_radiance(
                parse_sky(args.sky), build.dome_vertices, include_sun=sun is None
            )
        results = probe.evaluate(
            build, points, light_vector, sun, source="compact" if args.compact else "master",
            warn=lambda message: print(f"warning: {message}", file=sys.stderr),
        )
    except (ProbeError, ManifestError, EnvMapError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        print(json.dumps(results))
    else:
        print(probe.format_table(results))
    return 0


def _json_file(path: Path):
    from bake.evaluate import ProbeError

    try:
        return json.loads(path.read_text("utf-8"))
    except FileNotFoundError:
        raise ProbeError(f"{path}: no such light-vector file") from None
    except (OSError, ValueError) as exc:
        raise ProbeError(f"{path}: not a JSON light vector ({exc})") from None
