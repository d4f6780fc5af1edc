"""Radiance as the independent judge: a build's scene, gendaylit skies and rtrace (site frame).

The tests and benchmarks that check daylit against another renderer (``bench_fidelity.py``,
``tests/radiance_frames.py``, the scene estimate's and the phone's tests) take Radiance from
here (``pyradiance``'s wheel: ``gendaylit``, ``oconv``, ``rtrace``):

- **Scene**: the ``virtual`` and ``real`` meshes of the build's ``site.glb`` as opaque
  Lambertian polygons (``plastic``, no specular) with their albedos, the ground as a
  Lambertian square of the manifest's ground albedo 40 km wide (to the horizon within 0.02
  degrees seen from 5 m up); never the shadowing planes. Site frame (+X east, +Y up, -Z
  north) to Radiance's (+X east, +Y north, +Z up): ``(x, y, z) -> (x, -z, y)``.
- **Skies**: ``gendaylit`` (Perez all-weather, solar radiometric units ``-O 1``) at the site's
  latitude and longitude; its sky function as a ``glow`` over the whole sphere plus the sun as
  a ``light`` source of 0.533 degrees, and the same sky function sampled by ``rtrace`` from the
  origin into an equirectangular map (2 x 2 rays per pixel).
- **Self-check** (``self_check``): open ground under a uniform sky gives pi L, the sun alone
  DNI max(0, n.s) on four walls and the ground, the sky map integrates to rtrace's irradiance,
  and a straight edge's penumbra is the disc's.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.fidelity_metrics import profile_points
from daylit.envmap import pixel_directions
from daylit.sky import direction_from_azimuth_elevation

REPO = Path(__file__).resolve().parents[1]
PYRADIANCE = "pyradiance==1.3.1"
RADIANCE_SUN_DIAMETER_DEG = 0.533  # gendaylit's sun
GROUND_HALF_M = 20_000.0
# The 10-90 % width of a uniform disc's straight-edge penumbra over its whole width (2 r):
# the circular segment holds 10 % of the disc at 0.6870 r from the centre.
DISC_10_90 = 0.68705
SURFACE_OFFSET_M = 0.002  # Radiance's measurement points sit this far off their surface
SKY_MAP_HEIGHT = 360  # 0.5 degree pixels, 2 x 2 rays each
# Radiance settings. Ambient caching off (-aa 0): every point gets its own hemisphere
# samples, no interpolation across shadow edges. -lw small enough that no sample is dropped.
SKY_DIRECT = ["-ab", "1", "-aa", "0", "-ad", "2048", "-as", "0", "-lw", "1e-7"]
SKY_BOUNCE = ["-ab", "2", "-aa", "0", "-ad", "2048", "-as", "0", "-lw", "1e-7"]
SKY_TWO_BOUNCES = ["-ab", "3", "-aa", "0", "-ad", "1024", "-as", "0", "-lw", "1e-7"]
SUN_DIRECT = ["-ab", "0", "-dj", "1", "-ds", "0", "-dc", "1", "-dt", "0", "-lw", "1e-7"]
SUN_HARD = ["-dj", "0", "-ds", "0", "-dc", "1", "-dt", "0", "-lw", "1e-7"]
SUN_BOUNCE_AMB = ["-aa", "0", "-ad", "2048", "-as", "0"]


@dataclass
class SkySpec:
    """A gendaylit condition: date and local standard time, DNI and DHI in W/m^2."""

    name: str
    month: int
    day: int
    hour: str
    dni: float
    dhi: float
    year: int = 2026


SKIES = [
    SkySpec("clear", 10, 15, "15:00", 800.0, 80.0),
    SkySpec("intermediate", 3, 20, "10:00", 400.0, 200.0),
    SkySpec("overcast", 12, 10, "12:00", 0.0, 150.0),
]


# ------------------------------------------------------------------------------------------
# Radiance: where it is, frames, scene files


def radiance_env() -> tuple[Path, dict]:
    """pyradiance's bin directory and an environment whose RAYPATH finds its .cal files."""
    try:
        import pyradiance
    except ImportError:
        sys.exit(f"bench_fidelity needs Radiance: .venv/bin/pip install {PYRADIANCE}")
    root = Path(pyradiance.__file__).parent
    env = dict(os.environ)
    env["RAYPATH"] = f".{os.pathsep}{root / 'lib'}"
    env["PATH"] = f"{root / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return root / "bin", env


def to_radiance(v: np.ndarray) -> np.ndarray:
    """Site frame (+X east, +Y up, -Z north) to Radiance's (+X east, +Y north, +Z up)."""
    v = np.asarray(v, dtype=np.float64)
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def from_radiance(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


def material(name: str, albedo) -> str:
    r, g, b = (float(a) for a in albedo)
    return f"void plastic {name}\n0\n0\n5 {r:.6g} {g:.6g} {b:.6g} 0 0\n"


def polygons(mat: str, vertices: np.ndarray, faces: np.ndarray, prefix: str) -> str:
    """Triangles (site frame) as Radiance polygons (their winding kept: the map is a
    rotation)."""
    v = to_radiance(vertices)
    out = []
    for k, f in enumerate(faces):
        a, b, c = v[f]
        if np.linalg.norm(np.cross(b - a, c - a)) < 1e-12:
            continue
        coords = " ".join(f"{x:.6f}" for x in (*a, *b, *c))
        out.append(f"{mat} polygon {prefix}.{k}\n0\n0\n9 {coords}\n")
    return "".join(out)


def ground_polygon(albedo, half: float = GROUND_HALF_M) -> str:
    h = half
    coords = f"{-h} {-h} 0 {h} {-h} 0 {h} {h} 0 {-h} {h} 0"
    return material("ground_mat", albedo) + f"ground_mat polygon ground\n0\n0\n12 {coords}\n"


def scene_files(build_dir: Path, work: Path) -> dict:
    """Write ``virtual.rad``, ``real.rad`` and ``ground.rad`` for a build; returns their paths
    and the triangle counts."""
    from bake.gltf import read_site_glb
    from daylit import manifest as manifest_io

    manifest = manifest_io.load(build_dir)
    nodes = read_site_glb(build_dir / manifest["model"]["path"])
    parts = {"virtual": [], "real": []}
    counts = {"virtual": 0, "real": 0}
    for k, (name, node) in enumerate(nodes.items()):
        role = node["extras"].get("role")
        if role not in parts:
            continue  # the ground is drawn to the horizon below; shadowing planes never
        mat = f"m{k}"
        parts[role].append(material(mat, node["albedo"]))
        parts[role].append(polygons(mat, node["vertices"], node["faces"], name.replace("/", "_")))
        counts[role] += len(node["faces"])
    files = {}
    for role, text in parts.items():
        files[role] = work / f"{role}.rad"
        files[role].write_text("".join(text))
    files["ground"] = work / "ground.rad"
    files["ground"].write_text(ground_polygon(manifest["ground"]["albedo"]))
    return {"files": files, "triangles": counts, "manifest": manifest}


# ------------------------------------------------------------------------------------------
# Skies


@dataclass
class Sky:
    """One gendaylit sky: its sky function (a Radiance brightfunc), its sun."""

    spec: SkySpec
    skyfunc: str
    sun_dir_rad: np.ndarray  # unit, Radiance frame
    sun_radiance: float  # W/(m^2 sr), grey
    header: str
    exr: Path | None = None
    files: dict = field(default_factory=dict)

    @property
    def dni(self) -> float:
        half = math.radians(RADIANCE_SUN_DIAMETER_DEG / 2)
        return self.sun_radiance * 2.0 * math.pi * (1.0 - math.cos(half))

    @property
    def sun_dir(self) -> np.ndarray:
        return from_radiance(self.sun_dir_rad)

    @property
    def azimuth_deg(self) -> float:
        d = self.sun_dir_rad
        return math.degrees(math.atan2(d[0], d[1])) % 360.0

    @property
    def elevation_deg(self) -> float:
        return math.degrees(math.asin(float(np.clip(self.sun_dir_rad[2], -1, 1))))

    @property
    def has_sun(self) -> bool:
        return self.dni > 0.0 and self.elevation_deg > 0.0

    def sun_arg(self) -> str:
        return f"{self.azimuth_deg:.4f},{self.elevation_deg:.4f},{self.dni:.4f}"


def gendaylit(spec: SkySpec, scene: dict, env: dict) -> Sky:
    """Run gendaylit for the site in the manifest (Radiance's longitudes are west-positive)."""
    site = scene["scene"]
    import datetime
    import zoneinfo

    when = datetime.datetime(spec.year, spec.month, spec.day, 12, tzinfo=zoneinfo.ZoneInfo(
        site["timezone"]))
    meridian = -15.0 * when.utcoffset().total_seconds() / 3600.0  # standard meridian, west +
    cmd = [
        "gendaylit", str(spec.month), str(spec.day), spec.hour, "-y", str(spec.year),
        "-a", f"{site['latitude_deg']}", "-o", f"{-site['longitude_deg']}", "-m", f"{meridian}",
        "-W", f"{spec.dni}", f"{spec.dhi}", "-O", "1",
    ]
    text = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    blocks = [b.split() for b in text.split("\n\n")]
    header = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    words = text.split()
    light = words.index("light")
    sun_radiance = float(words[light + 5])  # "void light solar 0 0 3 R G B"
    source = words.index("source")
    sun_dir = np.array([float(w) for w in words[source + 5 : source + 8]])
    start = text.index("void brightfunc skyfunc")
    del blocks
    return Sky(spec, text[start:].strip() + "\n", sun_dir / np.linalg.norm(sun_dir),
               sun_radiance, header)


def sky_rad(skyfunc: str) -> str:
    return (
        skyfunc
        + "\nskyfunc glow sky_glow\n0\n0\n4 1 1 1 0\n"
        + "\nsky_glow source sky\n0\n0\n4 0 0 1 180\n"
    )


def sun_rad(direction_rad: np.ndarray, radiance: float) -> str:
    d = " ".join(f"{x:.6f}" for x in direction_rad)
    return (
        f"void light solar\n0\n0\n3 {radiance:.6g} {radiance:.6g} {radiance:.6g}\n"
        f"\nsolar source sun\n0\n0\n4 {d} {RADIANCE_SUN_DIAMETER_DEG}\n"
    )


def uniform_sky_rad(radiance: float) -> str:
    return (
        f"void glow sky_glow\n0\n0\n4 {radiance} {radiance} {radiance} 0\n"
        "\nsky_glow source sky\n0\n0\n4 0 0 1 180\n"
    )


# ------------------------------------------------------------------------------------------
# Running Radiance


def oconv(out: Path, files: list[Path], env: dict) -> Path:
    with open(out, "wb") as f:
        subprocess.run(["oconv", *map(str, files)], env=env, check=True, stdout=f)
    return out


def rtrace(octree: Path, rays: np.ndarray, options: list[str], env: dict, irradiance=True,
           procs: int = 1) -> np.ndarray:
    """rtrace over (m, 6) rays (Radiance frame), RGB (m, 3): irradiance with ``-I``, else
    radiance along the rays."""
    if len(rays) == 0:
        return np.zeros((0, 3))
    cmd = ["rtrace", "-h", "-ov", "-ff", *options]
    if irradiance:
        cmd.append("-I")
    if procs > 1:
        cmd += ["-n", str(procs)]
    cmd.append(str(octree))
    data = np.ascontiguousarray(rays, dtype=np.float32).tobytes()
    out = subprocess.run(cmd, input=data, env=env, check=True, capture_output=True).stdout
    values = np.frombuffer(out, dtype=np.float32).reshape(-1, 3).astype(np.float64)
    if len(values) != len(rays):
        raise RuntimeError(f"rtrace answered {len(values)} rays of {len(rays)}")
    return values


def measurement_rays(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """rtrace -I rays: points 2 mm off their surface, directions their normals (Radiance
    frame)."""
    p = to_radiance(points + SURFACE_OFFSET_M * normals)
    return np.concatenate([p, to_radiance(normals)], axis=1)


def sun_direct(octree: Path, rays: np.ndarray, repeats: int, env: dict, procs: int) -> np.ndarray:
    """The sun's direct irradiance, the disc sampled by ``repeats`` jittered shadow rays per
    point (-dj 1), averaged."""
    rep = np.repeat(rays, repeats, axis=0)
    values = rtrace(octree, rep, SUN_DIRECT, env, procs=procs)
    return values.reshape(len(rays), repeats, 3).mean(axis=1)


def sky_map(sky: Sky, work: Path, env: dict, height: int = SKY_MAP_HEIGHT) -> np.ndarray:
    """The sky function (no sun) as an equirectangular map, daylit's conventions: row 0 at the
    zenith, column 0 north, azimuth toward east; each pixel the mean of 2 x 2 rays."""
    octree = oconv(work / f"sky_only_{sky.spec.name}.oct", [sky.files["sky"]], env)
    w = 2 * height
    sub = 2
    i = (np.arange(height * sub) + 0.5) / (height * sub)
    j = (np.arange(w * sub) + 0.5) / (w * sub)
    zen, az = np.meshgrid(np.pi * i, 2 * np.pi * j, indexing="ij")
    dirs = np.stack([np.sin(zen) * np.sin(az), np.sin(zen) * np.cos(az), np.cos(zen)], -1)
    rays = np.concatenate([np.zeros_like(dirs), dirs], axis=-1).reshape(-1, 6)
    values = rtrace(octree, rays, ["-ab", "0"], env, irradiance=False)
    image = values.reshape(height, sub, w, sub, 3).mean(axis=(1, 3))
    return image


def map_irradiance(image: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Irradiance (3,) from an equirectangular map's upper hemisphere on a surface with a
    site-frame normal: the check that the map's orientation is Radiance's."""
    d, sr = pixel_directions(image.shape[0])
    cos = np.maximum(0.0, d @ normal) * (d[..., 1] > 0)
    return np.einsum("hw,hwc->c", cos * sr, image)


# ------------------------------------------------------------------------------------------
# Self-check: known answers of the conversion

CHECK_NORMALS = {
    "up": [0.0, 1.0, 0.0],
    "east": [1.0, 0.0, 0.0],
    "south": [0.0, 0.0, 1.0],
    "west": [-1.0, 0.0, 0.0],
    "north": [0.0, 0.0, -1.0],
}


def self_check(scene: dict, env: dict, work: Path, tolerance: float = 0.02) -> list[dict]:
    """Known answers, printed and returned; exits if one fails.

    1. open ground under a uniform sky L: pi L (rtrace -ab 1, the ground polygon present);
    2. the sun alone (the clear sky's): DNI max(0, n . s) on the ground and four walls, with
       ``s`` from daylit's own azimuth/elevation convention;
    3. the clear sky map (the EXR daylit reads), integrated over its upper hemisphere, against
       rtrace -ab 1 under the same sky function over a black ground, on the same five normals
       (2 %: rtrace's sampling noise on walls; a turned or mirrored map is off by 60 % and more);
    4. informative: Radiance's own 10-90 % penumbra behind a straight edge against a uniform
       disc's (its jittered sun samples make it a few per cent wider).
    """
    work.mkdir(parents=True, exist_ok=True)
    rows = []

    def row(what, got, want):
        err = float(np.max(np.abs(np.asarray(got) - want) / np.maximum(np.abs(want), 1e-9)))
        rows.append({"check": what, "radiance": float(np.mean(got)), "expected":
                     float(np.mean(want)), "rel_err": err, "ok": err <= tolerance})

    L = 100.0
    (work / "uniform.rad").write_text(uniform_sky_rad(L))
    octree = oconv(work / "uniform.oct", [work / "uniform.rad", scene["files"]["ground"]], env)
    up = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
    got = rtrace(octree, measurement_rays(*up), SKY_DIRECT, env)
    row(f"uniform sky L={L:g}: open ground = pi L", got, np.pi * L)

    sky = gendaylit(SKIES[0], scene["manifest"], env)
    (work / "check_sun.rad").write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance))
    octree = oconv(work / "check_sun.oct", [work / "check_sun.rad", scene["files"]["ground"]],
                   env)
    s = direction_from_azimuth_elevation(sky.azimuth_deg, sky.elevation_deg)
    normals = np.array(list(CHECK_NORMALS.values()))
    points = np.tile([0.0, 1.0, 0.0], (len(normals), 1))
    got = sun_direct(octree, measurement_rays(points, normals), 16, env, 1)
    for k, name in enumerate(CHECK_NORMALS):
        want = sky.dni * max(0.0, float(normals[k] @ s))
        if want > 0:
            row(f"sun alone (az {sky.azimuth_deg:.1f}, el {sky.elevation_deg:.1f}, DNI "
                f"{sky.dni:.1f}): {name} = DNI cos", got[k], want)
        else:
            rows.append({"check": f"sun alone: {name} faces away = 0", "radiance":
                         float(got[k].mean()), "expected": 0.0, "rel_err": float(
                             got[k].max() / sky.dni), "ok": got[k].max() < 1e-6 * sky.dni})

    sky.files["sky"] = work / "check_sky.rad"
    sky.files["sky"].write_text(sky_rad(sky.skyfunc))
    image = sky_map(sky, work, env)
    (work / "black.rad").write_text(ground_polygon([0.0, 0.0, 0.0]).replace(
        "ground_mat", "black_mat"))
    octree = oconv(work / "check_sky.oct", [sky.files["sky"], work / "black.rad"], env)
    got = rtrace(octree, measurement_rays(points, normals), SKY_DIRECT, env)
    for k, name in enumerate(CHECK_NORMALS):
        row(f"clear sky map vs rtrace -ab 1, black ground: {name}", got[k],
            map_irradiance(image, normals[k]))
    # Radiance's own penumbra: 10 m behind a straight 5 m edge (sun due south at 30 degrees)
    # against the exact profile of a uniform disc of gendaylit's size; informative (10 %).
    el = math.radians(30.0)
    sun = np.array([0.0, -math.cos(el), math.sin(el)])
    (work / "edge_sun.rad").write_text(sun_rad(sun, 1e7))
    (work / "edge.rad").write_text("void plastic w\n0\n0\n5 .5 .5 .5 0 0\n"
                                   "w polygon wall\n0\n0\n12 -50 0 0 50 0 0 50 0 5 -50 0 5\n")
    octree = oconv(work / "edge.oct", [work / "edge_sun.rad", work / "edge.rad"], env)
    edge_y = 5.0 / math.tan(el)
    y = np.linspace(edge_y - 0.2, edge_y + 0.2, 201)
    rays = np.zeros((len(y), 6))
    rays[:, 1], rays[:, 2], rays[:, 5] = y, SURFACE_OFFSET_M, 1.0
    got = profile_points(y, sun_direct(octree, rays, 1024, env, 1).mean(axis=1))
    radius = math.radians(RADIANCE_SUN_DIAMETER_DEG / 2)
    whole = 2.0 * (5.0 / math.sin(el)) * math.tan(radius) / math.sin(el)
    want = whole * DISC_10_90
    ratio = got["width_m"] / want - 1.0
    rows.append({"check": "Radiance's 10-90 % penumbra behind an edge vs a uniform disc's "
                 "(m, informative)", "radiance": got["width_m"], "expected": want,
                 "rel_err": ratio, "ok": abs(ratio) < 0.1})
    width = max(len(r["check"]) for r in rows)
    print("self-check of the Radiance scene conversion:")
    for r in rows:
        print(f"  {r['check']:<{width}}  rtrace {r['radiance']:9.4g}  expected "
              f"{r['expected']:9.4g}  {100 * r['rel_err']:+6.3f} %  "
              f"{'ok' if r['ok'] else 'FAILED'}")
    if not all(r["ok"] for r in rows):
        sys.exit("self-check failed: the Radiance scene conversion is wrong")
    return rows
