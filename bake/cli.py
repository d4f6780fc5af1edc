"""``daylit bake`` and ``daylit probe``.

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
    bake.add_argument("--no-progress", action="store_true", help="no progress bar")
    bake.set_defaults(run=run_bake)

    probe = subparsers.add_parser(
        "probe",
        help="irradiance at a point of a build under a sky",
        description=(
            "Evaluate a build at a world point on a receiver (ground, wall, hull plane or a "
            "model's surface): irradiance with and without the virtual objects under a named "
            "sky or a light vector, computed from the baked basis."
        ),
        epilog="example: daylit probe build/demo --point 10,0,20 --normal 0,1,0 --sky clear:135,40",
    )
    probe.add_argument("build", type=Path, help="build directory (with manifest.json)")
    probe.add_argument("--point", required=True, metavar="X,Y,Z", help="world point, metres")
    probe.add_argument(
        "--normal", default="0,1,0", metavar="X,Y,Z", help="surface normal (default: up)"
    )
    group = probe.add_mutually_exclusive_group()
    group.add_argument(
        "--sky",
        default="uniform:1",
        help="uniform[:L] | overcast[:Lz] | clear:AZIMUTH_DEG,ELEVATION_DEG (default: uniform:1)",
    )
    group.add_argument(
        "--light-vector", type=Path, metavar="FILE", help="JSON list of n [r, g, b] patch radiances"
    )
    probe.add_argument(
        "--compact",
        action="store_true",
        help="answer from the compact GPU textures (as the web client sums them) "
        "instead of the EXR masters",
    )
    probe.add_argument("--json", action="store_true", help="print JSON")
    probe.set_defaults(run=run_probe)


def run_bake(args) -> int:
    from bake.pipeline import BakeError, bake
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
        )
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BakeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


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


def _vector(text: str, name: str):
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3:
        raise ValueError(f"{name} must be three numbers X,Y,Z, got {text!r}")
    return values


def run_probe(args) -> int:
    from bake.evaluate import Build, ProbeError
    from daylit.manifest import ManifestError

    try:
        point = _vector(args.point, "--point")
        normal = _vector(args.normal, "--normal")
        build = Build(args.build)
        sky = args.sky
        if args.light_vector:
            sky = json.loads(args.light_vector.read_text())
        result = build.irradiance(
            point, normal, sky, source="compact" if args.compact else "master"
        )
    except (ValueError, ProbeError, ManifestError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    sample = result["sample"]
    out = {
        "receiver": sample.receiver,
        "atlas": sample.atlas,
        "kind": sample.kind,
        "texel": [round(sample.x, 3), round(sample.y, 3)],
        "irradiance_with_W_m2": [round(float(v), 6) for v in result["with"]],
        "irradiance_without_W_m2": None
        if result["without"] is None
        else [round(float(v), 6) for v in result["without"]],
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"receiver  {out['receiver']} ({out['kind']}, atlas {out['atlas']}, "
            f"texel {out['texel'][0]}, {out['texel'][1]})"
        )
        print("with virtual objects     E = " + " ".join(f"{v:.4g}" for v in result["with"]))
        if result["without"] is not None:
            print("without virtual objects  E = " + " ".join(f"{v:.4g}" for v in result["without"]))
    return 0
