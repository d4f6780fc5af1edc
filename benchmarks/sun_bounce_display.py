"""The sun-bounce images judged as displayed (issue 15, item 8; docs/sun.md).

    PYTHONPATH=. python benchmarks/sun_bounce_display.py BUILD [--json OUT]

For every sun-bounce stack of the build (atlases and fixed views) and every light that has
images, the sun is put at that patch's centroid under a clear sky from Radiance's
``gendaylit`` (pyradiance; Perez all-weather sky, DNI and DHI from pvlib's Ineichen-Perez
clear-sky model for that elevation): its sky *without the disc* as the light vector (each
patch's mean radiance, rtrace of the sky function along directions uniform over the patch),
its DNI as the sun. The displayed irradiance (or the view's radiance) of a stack is then

    D(x) = sum_i r_i S_i(x) + DNI / omega_p * (max(S_p(x) - B_p(x), 0) + B_p(x))

with ``S`` the sky stack's EXR master and ``B`` the sun-bounce stack's EXR master: the sky
relit, the sun's direct term and the sun's bounce, what the client shows. The direct term is
estimated here from the two masters (the sky stack's column ``p`` is the sun's direct light
and its bounce with the sun spread over patch ``p``; its shadow edges are the patch's, softer
than the client's, which the RMS over the mean does not see); ``direct=False`` leaves it out
(the judge before 2026-12-06). The error of a decoded column ``B'_p`` is
``DNI / omega_p * (B'_p - B_p)``, over the receiver texels (the sky stack's non-zero texels):
``rms`` is its RMS over the mean of ``D``, ``p99`` the 99th percentile of ``|error| / D`` per
texel and channel (``D`` at least a tenth of its mean: :data:`DARK_FLOOR`). Measured with the
coarse level alone and with every level the build stores (the refinement, where it has one);
bytes are the files' sizes.

Nothing here is the baker's own estimate: the sky is gendaylit's, not ``daylit.sky``'s.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.radiance import (  # noqa: E402
    from_radiance,
    oconv,
    radiance_env,
    rtrace,
    sky_rad,
    to_radiance,
)

DARK_FLOOR = 0.1  # p99's denominator: at least this fraction of the mean displayed value
DECODE_CHUNK = 16  # light images decoded at a time (one decoder run each)
SAMPLES_PER_PATCH = 96  # rays per dome patch for its mean radiance (0.3 % RMS on a clear sky)


def uniform_in_patch(vertices: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(count, 3) directions uniform in solid angle inside a spherical triangle ``vertices``
    (3, 3), by rejection from the smallest spherical cap around its centre that holds it
    (uniform in the cap: cos(theta) uniform), keeping those inside its three edges' great
    circles."""
    rng = np.random.default_rng(seed)
    centre = vertices.sum(axis=0)
    centre /= np.linalg.norm(centre)
    edges = np.cross(vertices, np.roll(vertices, -1, axis=0))
    edges *= np.sign(edges @ centre)[:, None]  # inside: dot >= 0, whatever the winding
    cos_cap = float((vertices @ centre).min())
    # An orthonormal frame around the centre.
    u = np.cross(centre, [1.0, 0.0, 0.0] if abs(centre[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(centre, u)
    out, have = [], 0
    while have < count:
        cos_t = rng.uniform(cos_cap, 1.0, 4 * count)
        phi = rng.uniform(0.0, 2 * np.pi, 4 * count)
        sin_t = np.sqrt(1.0 - cos_t**2)
        d = (cos_t[:, None] * centre + (sin_t * np.cos(phi))[:, None] * u
             + (sin_t * np.sin(phi))[:, None] * v)
        d = d[np.all(d @ edges.T >= 0.0, axis=1)]
        out.append(d)
        have += len(d)
    return np.concatenate(out)[:count]


def patch_directions(patch_vertices: np.ndarray, samples: int = SAMPLES_PER_PATCH) -> np.ndarray:
    """(n * samples, 3) directions, ``samples`` uniform in each patch, patch by patch."""
    return np.concatenate([uniform_in_patch(v, samples, seed=i)
                           for i, v in enumerate(patch_vertices)])


def gendaylit_sky(sun_dir: np.ndarray, dni_W_m2: float, dhi_W_m2: float, env: dict) -> str:
    """gendaylit's sky function (text, no sun) for the sun along ``sun_dir`` (site frame,
    unit), radiometric (``-O 1``). gendaylit's ``-ang`` azimuth is from south toward west;
    checked against the direction it writes back."""
    d = np.asarray(sun_dir, float)
    el = float(np.degrees(np.arcsin(np.clip(d[1], -1, 1))))
    compass = float(np.degrees(np.arctan2(d[0], -d[2])))  # from north toward east
    cmd = ["gendaylit", "-ang", f"{el:.6f}", f"{compass - 180.0:.6f}",
           "-W", f"{dni_W_m2:.6f}", f"{dhi_W_m2:.6f}", "-O", "1"]
    text = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    words = text.split()
    source = words.index("source")
    back = from_radiance(np.array([float(w) for w in words[source + 5: source + 8]]))
    if back @ d < 0.99999:
        raise RuntimeError(f"gendaylit placed the sun at {back}, asked {d}")
    return text[text.index("void brightfunc skyfunc"):].strip() + "\n"


def gendaylit_vector(sun_dir, dni_W_m2: float, dhi_W_m2: float, patch_vertices: np.ndarray,
                     env: dict, dirs: np.ndarray | None = None) -> np.ndarray:
    """The light vector (n, 3) W/(m^2 sr) of gendaylit's clear sky without its sun's disc:
    each patch's mean radiance over directions uniform in it (``dirs`` from
    :func:`patch_directions`, made here if not given; rtrace -ab 0 of the sky function).
    ``patch_vertices`` (n, 3, 3), site frame."""
    skyfunc = gendaylit_sky(sun_dir, dni_W_m2, dhi_W_m2, env)
    if dirs is None:
        dirs = patch_directions(patch_vertices)
    samples = len(dirs) // len(patch_vertices)
    with tempfile.TemporaryDirectory(prefix="daylit-sbd-") as tmp:
        work = Path(tmp)
        (work / "sky.rad").write_text(sky_rad(skyfunc))
        octree = oconv(work / "sky.oct", [work / "sky.rad"], env)
        rays = np.hstack([np.zeros((len(dirs), 3)), to_radiance(dirs)])
        values = rtrace(octree, rays, ["-ab", "0"], env, irradiance=False)
    values[dirs[:, 1] <= 0.0] = 0.0  # below the horizon: the ground, not the sky
    return values.reshape(len(patch_vertices), samples, 3).mean(axis=1)


def clear_sky_sun(sun_dir, elevation_m: float, day_of_year: float = 80.0) -> tuple[float, float]:
    """(DNI, DHI) W/m^2 of pvlib's Ineichen-Perez clear sky (Linke turbidity 3) for the sun
    along ``sun_dir``: the conditions handed to gendaylit."""
    from pvlib import atmosphere, clearsky, irradiance

    zenith = float(np.degrees(np.arccos(np.clip(sun_dir[1], -1, 1))))
    relative = atmosphere.get_relative_airmass(zenith)
    absolute = atmosphere.get_absolute_airmass(relative, atmosphere.alt2pres(elevation_m))
    cs = clearsky.ineichen(np.array([zenith]), absolute, 3.0, altitude=elevation_m,
                           dni_extra=float(irradiance.get_extra_radiation(day_of_year)))
    return float(np.asarray(cs["dni"])[0]), float(np.asarray(cs["dhi"])[0])


def displayed_errors(sky_shown: np.ndarray, bounce: np.ndarray, columns: dict,
                     weight: np.ndarray, direct: np.ndarray | None = None) -> dict:
    """As-displayed errors of decoded sun-bounce columns, over the receiver texels (V of
    them).

    ``sky_shown`` (V, 3) the sky stack relit with the sky without the disc (:func:`sky_relit`);
    ``bounce`` (V, 3) the master column of the sun's patch; ``columns`` {name: (V, 3) decoded
    column}; ``weight`` (3,) DNI / omega_p; ``direct`` (V, 3) the sun's direct term per unit
    of ``weight`` (None: left out). Returns {name: {"rms", "p99"}}, fractions of the
    displayed value."""
    truth = sky_shown + bounce * weight
    if direct is not None:
        truth = truth + direct * weight
    mean = max(float(truth.mean()), 1e-30)
    # Texels darker than a tenth of the mean (under roofs, in corners) are judged against a
    # tenth of the mean: near black, a display shows no relative error.
    floor = mean * DARK_FLOOR
    out = {}
    for name, column in columns.items():
        err = (column.astype(np.float64) - bounce) * weight
        out[name] = {
            "rms": float(np.sqrt((err**2).mean()) / mean),
            "p99": float(np.percentile(np.abs(err) / np.maximum(truth, floor), 99.0)),
        }
    return out


def sky_relit(sky_valid: list, r: np.ndarray) -> np.ndarray:
    """(V, 3) the sky stack's receiver texels (``sky_valid``: per channel (V, n)) times the
    light vector ``r`` (n, 3)."""
    return np.stack([sky_valid[c] @ r[:, c] for c in range(3)], axis=1)


def level_reader(build_dir: Path, entry: dict, shape, levels: int):
    """A CompactReader of a sun-bounce entry that reads only its first ``levels`` levels."""
    from bake.compact_reader import CompactReader

    table = entry["lights"]
    cut = {
        "k": 0,
        "lights": {
            **table,  # as it is but for the levels (a shared image's holder: ``image``)
            "ktx2": table["ktx2"][:levels],
            "scale": [None if s is None else s[:levels] for s in table["scale"]],
            "offset": [None if o is None else o[:levels] for o in table["offset"]],
        },
    }
    return CompactReader(build_dir, cut, shape)


def measure(build_dir: Path, log=print, direct: bool = True) -> list[dict]:
    """One row per stack and light with images: stack, light, sun (az, el), levels stored,
    bytes per level, and the as-displayed ``coarse`` and ``stored`` errors (with the sun's
    direct term in the displayed value, or without it: ``direct``)."""
    from bake.compact_reader import image_holders
    from bake.evaluate import Build
    from daylit.sky import azimuth_elevation_from_direction
    from daylit.stackio import read_stack_exr

    build = Build(build_dir)
    m = build.manifest
    _, env = radiance_env()
    lights = m["dome"]["lights"]
    sizes = {f["path"]: f["bytes"] for f in m["files"]}
    owners = [(a, "exr") for a in m["atlases"]] + [(v, "views") for v in m["views"]]
    needed = sorted({i for o, _ in owners for s in o.get("sun_bounce", {}).values()
                     for i, sc in enumerate(s["compact"]["lights"]["scale"]) if sc is not None})
    log(f"{len(needed)} lights with sun-bounce images; gendaylit skies ...")
    skies = {}
    dirs = patch_directions(build.dome_vertices)
    for p in needed:
        sun = np.asarray(lights[p]["centroid"], float)
        sun /= np.linalg.norm(sun)
        dni, dhi = clear_sky_sun(sun, m["scene"]["elevation_m"])
        r = gendaylit_vector(sun, dni, dhi, build.dome_vertices, env, dirs)
        skies[p] = (sun, dni, dhi, r, np.full(3, dni / lights[p]["solid_angle_sr"]))
    rows = []
    for owner, _ in owners:
        shape = (owner["height"], owner["width"])
        for stack, sb in owner.get("sun_bounce", {}).items():
            name = f"{owner['id']}.{stack}"
            log(f"  {name} ...")
            sky_stack = read_stack_exr(build_dir / owner["stacks"][stack]["master"])
            valid = np.any(sky_stack != 0.0, axis=(2, 3))
            sky_valid = [sky_stack[..., c][valid].astype(np.float64) for c in range(3)]
            del sky_stack
            master = read_stack_exr(build_dir / sb["master"])
            table = sb["compact"]["lights"]
            coarse = level_reader(build_dir, sb["compact"], shape, 1)
            stored = level_reader(build_dir, sb["compact"], shape, len(table["ktx2"]))
            have = [p for p, scale in enumerate(table["scale"]) if scale is not None]
            holder = image_holders(table)  # a shared image is its holder's files
            for start in range(0, len(have), DECODE_CHUNK):
                chunk = have[start: start + DECODE_CHUNK]
                two = [p for p in chunk if len(table["scale"][p]) > 1]
                decoded_coarse = coarse.lights(chunk)
                decoded_stored = stored.lights(two) if two else {}
                for p in chunk:
                    scale = table["scale"][p]
                    sun, dni, dhi, r, weight = skies[p]
                    cols = {"coarse": decoded_coarse[p][valid]}
                    if p in decoded_stored:
                        cols["stored"] = decoded_stored[p][valid]
                    bounce = master[:, :, p][valid].astype(np.float64)
                    sun_direct = None
                    if direct:  # the sky stack's column p less its bounce: direct light
                        sun_direct = np.clip(np.stack([sky_valid[c][:, p] for c in range(3)],
                                                      axis=1) - bounce, 0.0, None)
                    errors = displayed_errors(sky_relit(sky_valid, r), bounce, cols, weight,
                                              sun_direct)
                    errors.setdefault("stored", errors["coarse"])
                    az, el = azimuth_elevation_from_direction(sun[None, :])
                    rows.append({
                        "stack": name, "light": p,
                        "sun_az_el_deg": [round(float(az[0]), 2), round(float(el[0]), 2)],
                        "dni_dhi_W_m2": [round(dni, 1), round(dhi, 1)],
                        "levels": len(scale),
                        "holder": holder[p],
                        "bytes": [sizes[pat.format(index=holder[p])]
                                  for pat in table["ktx2"][:len(scale)]],
                        **errors,
                    })
                coarse.forget_lights()
                stored.forget_lights()
            del sky_valid, master
    return rows


def summary(rows: list[dict]) -> list[dict]:
    """Per stack: lights, worst and median coarse-only / stored errors (RMS, p99), bytes."""
    out = []
    for name in dict.fromkeys(r["stack"] for r in rows):
        rs = [r for r in rows if r["stack"] == name]
        c_rms = np.array([r["coarse"]["rms"] for r in rs])
        c_p99 = np.array([r["coarse"]["p99"] for r in rs])
        s_rms = np.array([r["stored"]["rms"] for r in rs])
        s_p99 = np.array([r["stored"]["p99"] for r in rs])
        files = {r.get("holder", r["light"]): r for r in rs}  # a shared image counted once
        out.append({
            "stack": name, "lights": len(rs),
            "coarse_rms_max": float(c_rms.max()), "coarse_rms_median": float(np.median(c_rms)),
            "coarse_p99_max": float(c_p99.max()), "coarse_p99_median": float(np.median(c_p99)),
            "stored_rms_max": float(s_rms.max()), "stored_p99_max": float(s_p99.max()),
            "coarse_bytes": int(sum(r["bytes"][0] for r in files.values())),
            "refine_bytes": int(sum(sum(r["bytes"][1:]) for r in files.values())),
            "two_levels": int(sum(r["levels"] > 1 for r in rs)),
        })
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("build", type=Path)
    ap.add_argument("--json", type=Path, help="write every row here")
    ap.add_argument("--no-direct", action="store_true",
                    help="leave the sun's direct term out of the displayed value")
    args = ap.parse_args()
    rows = measure(args.build, log=lambda s: print(s, file=sys.stderr),
                   direct=not args.no_direct)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print(f"{'stack':<14}{'lights':>7}{'2 lvl':>6}{'coarse RMS max':>16}{'(median)':>10}"
          f"{'p99 max':>9}{'stored RMS max':>16}{'p99 max':>9}{'coarse MB':>11}{'refine MB':>11}")
    for s in summary(rows):
        print(f"{s['stack']:<14}{s['lights']:>7}{s['two_levels']:>6}"
              f"{s['coarse_rms_max']:>16.3%}{s['coarse_rms_median']:>10.3%}"
              f"{s['coarse_p99_max']:>9.3%}{s['stored_rms_max']:>16.3%}{s['stored_p99_max']:>9.3%}"
              f"{s['coarse_bytes'] / 1e6:>11.2f}{s['refine_bytes'] / 1e6:>11.2f}")


if __name__ == "__main__":
    main()
