"""``daylit probe``: irradiance at receiver points of a build, the sky's part plus the sun's.

The interface anyone can use to compare daylit with another renderer (docs/sun.md, "Comparing
with another renderer"): points on receiver surfaces (a CSV file or one ``--point``), a sky
(an equirectangular EXR map of the sky without the sun, a named sky or a light vector) and,
optionally, the sun as its own light. Per point:

- the sky's part ``I = sum_i r_i B_i(x)`` from the baked basis, with the virtual objects
  present (and ``d``, without them, where the receiver has it);
- the sun's direct term ``E_n max(0, n . s) V`` from :mod:`bake.sunlight`, with every caster
  (and without the virtual objects: the real proxies alone on ground and wall receivers,
  no caster on hull planes, as their ``d``);
- the sun's bounce, sunlight reflected once off the ground, walls and models onto the point,
  from the build's sun-bounce stacks (:meth:`Build.sun_bounce`), with and without likewise.

The total is sky + sun direct + sun bounce. A build without sun-bounce stacks (baked before
2026-11-24) or a sun in a patch it never crosses at the site gives ``sun_bounce_W_m2: null``
and a warning: the total is then sky + sun direct.

All in W/m^2, linear RGB, site frame (+X east, +Y up, -Z north), metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bake.evaluate import Build, ProbeError
from daylit.sky import direction_from_azimuth_elevation


@dataclass
class ProbePoint:
    """A point to probe: where on a receiver (metres), its surface's normal, and where it was
    given (``"points.csv line 3"`` or ``"--point"``) for messages."""

    point_m: np.ndarray
    normal: np.ndarray
    origin: str


@dataclass
class SunSpec:
    """The sun as its own light: azimuth (clockwise from north) and elevation in degrees, and
    its direct normal irradiance in W/m^2 (grey)."""

    azimuth_deg: float
    elevation_deg: float
    dni_w_m2: float

    @property
    def direction(self) -> np.ndarray:
        return direction_from_azimuth_elevation(self.azimuth_deg, self.elevation_deg)


def parse_numbers(text: str, count: int, what: str) -> list[float]:
    """``count`` comma-separated finite numbers, else a :class:`ProbeError` naming ``what``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ProbeError(f"{what} must be {count} comma-separated numbers, got {text!r}")
    return values


def parse_sun(text: str) -> SunSpec:
    """``AZ_DEG,EL_DEG,DNI_W_M2`` (e.g. ``180,40,800``) to a :class:`SunSpec`."""
    azimuth, elevation, dni = parse_numbers(text, 3, "--sun AZ_DEG,EL_DEG,DNI_W_M2")
    if not -90.0 <= elevation <= 90.0:
        raise ProbeError(f"--sun: elevation must be within [-90, 90] degrees, got {elevation}")
    if dni < 0.0:
        raise ProbeError(f"--sun: the direct normal irradiance must be >= 0 W/m^2, got {dni}")
    return SunSpec(azimuth, elevation, dni)


def single_point(point: str, normal: str) -> list[ProbePoint]:
    """The ``--point X,Y,Z --normal X,Y,Z`` form."""
    p = np.array(parse_numbers(point, 3, "--point X,Y,Z"))
    n = np.array(parse_numbers(normal, 3, "--normal X,Y,Z"))
    if not np.any(n):
        raise ProbeError("--normal must not be zero; give the receiver surface's normal")
    return [ProbePoint(p, n / np.linalg.norm(n), "--point")]


def read_points(path: Path) -> list[ProbePoint]:
    """Points from a CSV file: ``x,y,z[,nx,ny,nz]`` per line (metres; normal +Y by default).

    Blank lines and lines starting with ``#`` are skipped. A bad line raises
    :class:`ProbeError` naming the file and the line.
    """
    path = Path(path)
    try:
        lines = path.read_text("utf-8").splitlines()
    except FileNotFoundError:
        raise ProbeError(f"{path}: no such points file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ProbeError(f"{path}: cannot read the points file ({exc})") from None
    points = []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        origin = f"{path} line {number}"
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) not in (3, 6) or not all(math.isfinite(v) for v in values):
            raise ProbeError(
                f"{origin}: expected x,y,z or x,y,z,nx,ny,nz (numbers, metres), got {text!r}"
            )
        normal = np.array(values[3:] if len(values) == 6 else [0.0, 1.0, 0.0])
        if not np.any(normal):
            raise ProbeError(f"{origin}: the normal must not be zero")
        points.append(ProbePoint(np.array(values[:3]), normal / np.linalg.norm(normal), origin))
    if not points:
        raise ProbeError(f"{path}: no points (one x,y,z[,nx,ny,nz] per line)")
    return points


def evaluate(
    build: Build,
    points: list[ProbePoint],
    light_vector: np.ndarray,
    sun: SunSpec | None = None,
    source: str = "master",
    warn=None,
) -> list[dict]:
    """Probe every point: a list of JSON-ready dicts (see the module's docstring).

    Keys: ``point_m``, ``normal``, ``receiver`` (``name``, ``atlas``, ``kind``, ``texel``),
    ``irradiance_W_m2`` (sky + sun + sun bounce), ``sky_W_m2``, ``sun_W_m2``,
    ``sun_bounce_W_m2`` and ``sun_visible_fraction`` (``None`` without a sun),
    ``without_virtual_objects`` (the same five, or ``None`` where the receiver has no ``d``:
    the models' own surfaces). ``warn`` (a callable taking a message) is told when the sun's
    bounce is missing.
    """
    skies = []
    for p in points:
        try:
            skies.append(build.irradiance(p.point_m, p.normal, light_vector, source=source))
        except ProbeError as exc:
            raise ProbeError(
                f"{p.origin}: {exc}; put the point on the ground, a wall, a hull plane or a "
                "model's surface, with that surface's outward normal"
            ) from None
    sun_parts = None
    if sun is not None:
        positions = np.array([p.point_m for p in points])
        normals = np.array([p.normal for p in points])
        hull = np.array([s["sample"].atlas == "hull" for s in skies])
        casters = build.sun_casters
        v_all = casters.visible_fraction(positions, normals, sun.direction, "all")
        v_real = casters.visible_fraction(positions, normals, sun.direction, "real")
        # A hull plane's d has nothing but the open ground: no caster, only the horizon.
        v_none = casters.visible_fraction(positions[hull], normals[hull], sun.direction, "none")
        v_without = v_real.copy()
        v_without[hull] = v_none
        cos = np.maximum(0.0, normals @ sun.direction)
        sun_parts = (v_all, v_without, cos)
        try:
            bounce = build.sun_bounce(
                positions, normals, sun.direction, sun.dni_w_m2, source=source
            )
        except ProbeError as exc:
            if warn is not None:
                warn(f"no sun bounce: {exc}")
            bounce = None
    results = []
    for k, (p, sky) in enumerate(zip(points, skies, strict=True)):
        sample = sky["sample"]
        out = {
            "point_m": _round(p.point_m),
            "normal": _round(p.normal),
            "receiver": {
                "name": sample.receiver,
                "atlas": sample.atlas,
                "kind": sample.kind,
                "texel": [round(sample.x, 3), round(sample.y, 3)],
            },
        }
        parts = {"with": (sky["with"], None, None, None), "without": None}
        if sky["without"] is not None:
            parts["without"] = (sky["without"], None, None, None)
        if sun_parts is not None:
            v_all, v_without, cos = sun_parts
            direct = sun.dni_w_m2 * cos[k]
            bounce_with = None if bounce is None else bounce["with"][k]
            bounce_without = None if bounce is None else bounce["without"][k]
            parts["with"] = (sky["with"], np.full(3, direct * v_all[k]), v_all[k], bounce_with)
            if sky["without"] is not None:
                parts["without"] = (
                    sky["without"], np.full(3, direct * v_without[k]), v_without[k],
                    bounce_without,
                )
        out.update(_parts(*parts["with"]))
        out["without_virtual_objects"] = (
            None if parts["without"] is None else _parts(*parts["without"])
        )
        results.append(out)
    return results


def _parts(sky_rgb, sun_rgb, visible, bounce_rgb) -> dict:
    # Each part rounded first, the total their sum: the JSON's parts add up to its total.
    sky_r = np.array(_round(sky_rgb))
    total = sky_r
    if sun_rgb is not None:
        total = total + np.array(_round(sun_rgb))
    if bounce_rgb is not None:
        total = total + np.array(_round(bounce_rgb))
    return {
        "irradiance_W_m2": _round(total),
        "sky_W_m2": _round(sky_r),
        "sun_W_m2": None if sun_rgb is None else _round(sun_rgb),
        "sun_bounce_W_m2": None if bounce_rgb is None else _round(bounce_rgb),
        "sun_visible_fraction": None if visible is None else round(float(visible), 6),
    }


def _round(values) -> list[float]:
    return [round(float(v), 6) for v in values]


def format_table(results: list[dict]) -> str:
    """A readable table: one line per point, RGB triples to 4 significant digits."""

    def rgb(values) -> str:
        return "-" if values is None else " ".join(f"{v:.4g}" for v in values)

    def xyz(values) -> str:
        return ",".join(f"{v:g}" for v in values)

    header = [
        "point_m",
        "normal",
        "receiver",
        "E_W_m2 (R G B)",
        "sky_W_m2",
        "sun_W_m2",
        "sun_bounce_W_m2",
        "V_sun",
        "without virtual: E_W_m2",
    ]
    rows = []
    for r in results:
        without = r["without_virtual_objects"]
        visible = r["sun_visible_fraction"]
        rows.append(
            [
                xyz(r["point_m"]),
                xyz(r["normal"]),
                f"{r['receiver']['name']} ({r['receiver']['kind']})",
                rgb(r["irradiance_W_m2"]),
                rgb(r["sky_W_m2"]),
                rgb(r["sun_W_m2"]),
                rgb(r["sun_bounce_W_m2"]),
                "-" if visible is None else f"{visible:.3f}",
                "-" if without is None else rgb(without["irradiance_W_m2"]),
            ]
        )
    widths = [max(len(row[c]) for row in [header, *rows]) for c in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) for row in rows]
    head = "  ".join(cell.ljust(w) for cell, w in zip(header, widths, strict=True))
    return "\n".join([head.rstrip(), *[line.rstrip() for line in lines]])
