"""Fidelity against Radiance (issue 15): daylit's irradiance at points of a build beside rtrace's.

Radiance (``pyradiance``'s wheel: ``gendaylit``, ``oconv``, ``rtrace``) renders the same scene
under the same skies, and ``daylit probe`` answers the same points:

- **Scene**: the ``virtual`` and ``real`` meshes of the build's ``site.glb`` as opaque
  Lambertian polygons (``plastic``, no specular) with their albedos, the ground as a
  Lambertian square of the manifest's ground albedo 40 km wide (to the horizon within 0.02
  degrees seen from 5 m up); never the shadowing planes. Site frame (+X east, +Y up, -Z
  north) to Radiance's (+X east, +Y north, +Z up): ``(x, y, z) -> (x, -z, y)``.
- **Skies**: ``gendaylit`` (Perez all-weather, solar radiometric units ``-O 1``) at the site's
  latitude and longitude for a clear, an intermediate and an overcast condition. Radiance gets
  its sky function as a ``glow`` over the whole sphere plus the sun as a ``light`` source of
  0.533 degrees; daylit gets the same sky function, sampled by ``rtrace`` from the origin
  into an equirectangular EXR (2 x 2 rays per pixel), as ``--env``, and the sun as ``--sun
  AZ,EL,DNI`` with gendaylit's direction and DNI = the sun's radiance times its disc's solid
  angle.
- **Points**: a grid over the ground atlas's ground receivers, a grid on the real proxies'
  wall receivers (neither buried inside a part), points on the models' own faces (virtual
  and real; faces of at least 0.5 m^2, in the middle of their triangle, none buried inside
  another part), and for each sky with a sun, lines of closely spaced ground points across
  the sun's shadow edges of the hall, the fence and the visitor centre (found by projecting
  each object's vertices along the sun onto the ground: the far edge of the projected
  outline).
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
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from daylit.envmap import pixel_directions  # noqa: E402
from daylit.sky import SUN_ANGULAR_RADIUS_DEG, direction_from_azimuth_elevation  # noqa: E402

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
# Points


@dataclass
class PointSet:
    """Points in the site frame with their normals, what they are and where, for one sky."""

    points: np.ndarray  # (m, 3)
    normals: np.ndarray  # (m, 3)
    group: list  # "ground", "wall" (real proxies' walls), "model" (models' own faces), "line"
    label: list  # receiver or object name
    lines: dict = field(default_factory=dict)  # name -> dict(index, t, ...)

    def __len__(self) -> int:
        return len(self.points)

    def extend(self, points, normals, group: str, labels) -> np.ndarray:
        start = len(self.points)
        self.points = np.concatenate([self.points, np.asarray(points, float).reshape(-1, 3)])
        self.normals = np.concatenate([self.normals, np.asarray(normals, float).reshape(-1, 3)])
        labels = [labels] * len(points) if isinstance(labels, str) else list(labels)
        self.group += [group] * len(points)
        self.label += labels
        return np.arange(start, len(self.points))


def empty_points() -> PointSet:
    return PointSet(np.zeros((0, 3)), np.zeros((0, 3)), [], [])


def receiver_grid(receiver: dict, step_m: float) -> np.ndarray:
    """Texel centres of a plane receiver every ``step_m`` (at least 1.5 texels off its
    border), site frame."""
    t = receiver["texel_m"]
    w, h = receiver["rect"][2], receiver["rect"][3]
    step = max(1, round(step_m / t))
    xs = np.arange(2, w - 2, step) + 0.5
    ys = np.arange(2, h - 2, step) + 0.5
    X, Y = np.meshgrid(xs, ys)
    o, u, v = (np.array(receiver[k], float) for k in ("origin_m", "axis_u", "axis_v"))
    return o + t * X.reshape(-1, 1) * u + t * Y.reshape(-1, 1) * v


def locatable(build, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Which points ``daylit probe`` can put on a receiver."""
    from bake.evaluate import ProbeError

    ok = np.zeros(len(points), bool)
    for k, (p, n) in enumerate(zip(points, normals, strict=True)):
        try:
            build.locate(p, n)
            ok[k] = True
        except ProbeError:
            pass
    return ok


def site_points(build, nodes: dict, ground_step_m: float, wall_step_m: float,
                model_points: int, seed: int = 15) -> PointSet:
    """The sky-independent points: a grid on the ground receivers, a grid on the real
    proxies' wall receivers, and points on the models' own faces (virtual and real)."""
    ps = empty_points()
    ground = build.atlases["ground"]["receivers"]
    for r in ground:
        step = ground_step_m if r["kind"] == "ground" else wall_step_m
        p = receiver_grid(r, step)
        group = "ground" if r["kind"] == "ground" else "wall"
        ps.extend(p, np.tile(r["normal"], (len(p), 1)), group, r["name"])
    # The models' faces: area-weighted over faces of at least 0.5 m^2 not facing down, each
    # point drawn in the middle 60 % of its triangle (away from edges and texel gutters).
    rng = np.random.default_rng(seed)
    tri, names, areas = [], [], []
    for name, node in nodes.items():
        if node["extras"].get("atlas") != "lightmap":
            continue
        v, f = node["vertices"], node["faces"]
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        area = 0.5 * np.linalg.norm(cross, axis=1)
        normal = cross / np.maximum(2 * area, 1e-12)[:, None]
        keep = (area >= 0.5) & (normal[:, 1] > -0.2)
        for k in np.flatnonzero(keep):
            tri.append((v[f[k]], normal[k]))
            names.append(name)
            areas.append(area[k])
    if tri and model_points:
        areas = np.array(areas)
        # Half by area, half evenly per object so small parts get points too.
        objects = sorted(set(names))
        per_object = np.array([1.0 / names.count(names[k]) for k in range(len(names))])
        weight = 0.5 * areas / areas.sum() + 0.5 * per_object / len(objects)
        picks = rng.choice(len(tri), size=3 * model_points, p=weight / weight.sum())
        points, normals, labels = [], [], []
        for k in picks:
            corners, normal = tri[k]
            b = rng.dirichlet([1.0, 1.0, 1.0])
            b = 0.2 / 3 + 0.8 * b  # the middle of the triangle
            points.append(b @ corners)
            normals.append(normal)
            labels.append(names[k])
        points, normals = np.array(points), np.array(normals)
        ok = locatable(build, points, normals) & ~buried(nodes, points, normals)
        ok = np.flatnonzero(ok)[:model_points]
        ps.extend(points[ok], normals[ok], "model", [labels[k] for k in ok])
    ok = locatable(build, ps.points, ps.normals)
    # Grid points buried inside a part (the ground under the podium and the visitor centre):
    # nobody sees them, Radiance gives them nothing, and the bake gives their texels the
    # bounce of the nearest open texel (so that filtering at a wall's foot reads open values).
    flat = np.isin(ps.group, ("ground", "wall"))
    ok[flat] &= ~buried(nodes, ps.points[flat], ps.normals[flat])
    return PointSet(ps.points[ok], ps.normals[ok], [g for g, k in zip(ps.group, ok, strict=True)
                                                    if k],
                    [g for g, k in zip(ps.label, ok, strict=True) if k])


def buried(nodes: dict, points: np.ndarray, normals: np.ndarray, rays: int = 32) -> np.ndarray:
    """Points on faces buried inside another part (a wall's face inside a column): every ray
    over the hemisphere hits the back of a face (half of them: some solids are open).
    Nobody sees them; Radiance gives them
    nothing, the bake's texels bleed light into them: they are left out."""
    from bake.raytrace import Geometry, RayScene

    meshes = [(n["vertices"], n["faces"]) for n in nodes.values()
              if n["extras"].get("role") in ("virtual", "real")]
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])[:-1]
    v = np.concatenate([m[0] for m in meshes])
    f = np.concatenate([m[1] + o for m, o in zip(meshes, offsets, strict=True)])
    scene = RayScene(Geometry(v, f, np.zeros((len(f), 3)), np.zeros(len(f), bool),
                              np.zeros(len(f), int)))
    # Cosine-distributed Fibonacci directions about +Z, turned onto each normal.
    k = np.arange(rays) + 0.5
    r, phi = np.sqrt(k / rays), k * np.pi * (3.0 - np.sqrt(5.0))
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r**2)], -1)
    out = np.zeros(len(points), bool)
    for i, (p, n) in enumerate(zip(points, normals, strict=True)):
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        d = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:] * n
        face, _ = scene.first_hit(np.tile(p + SURFACE_OFFSET_M * n, (rays, 1)), d)
        hit = face >= 0
        back = np.einsum("ij,ij->i", scene.face_normals[face[hit]], d[hit]) > 0.0
        out[i] = back.sum() >= rays // 2
    return out


LINE_OBJECTS = ("hall", "fence", "visitor_centre")


def shadow_lines(build, nodes: dict, sun_dir: np.ndarray, count: int) -> list[dict]:
    """Ground lines across the sun's shadow edge of each of :data:`LINE_OBJECTS`.

    Each object's vertices are projected along the sun onto the ground; the far edge of the
    projected outline (convex hull; both ends from vertices at least 0.5 m up) is the shadow
    edge its top casts. A line crosses it at right angles in the ground plane, from the
    umbra (``t < 0``) to full sun (``t > 0``), half as long as 3 times the disc's geometric
    penumbra there (at least 0.3 m), at a place along the edge where the oracle's visible
    fraction goes from under 2 % to over 98 % and every point is on a ground receiver.
    """
    from scipy.spatial import ConvexHull

    s = sun_dir / np.linalg.norm(sun_dir)
    tan_r = math.tan(math.radians(SUN_ANGULAR_RADIUS_DEG))
    lines = []
    for obj in LINE_OBJECTS:
        verts = [n["vertices"] for n in nodes.values()
                 if n["extras"].get("role") in ("virtual", "real")
                 and n["extras"].get("object", n.get("name")) == obj]
        if not verts:
            verts = [n["vertices"] for name, n in nodes.items() if name.endswith("/" + obj)]
        if not verts:
            continue
        v = np.concatenate(verts)
        ground = v - (v[:, 1] / s[1])[:, None] * s
        flat = ground[:, [0, 2]]
        hull = ConvexHull(flat)
        centre = flat[hull.vertices].mean(axis=0)
        away = np.array([-s[0], -s[2]])
        away /= np.linalg.norm(away)
        best = None
        for a, b in hull.simplices:
            if min(v[a, 1], v[b, 1]) < 0.5:
                continue
            mid = 0.5 * (flat[a] + flat[b])
            edge = flat[b] - flat[a]
            length = np.linalg.norm(edge)
            if length < 1.0:
                continue
            outward = np.array([edge[1], -edge[0]]) / length
            if outward @ (mid - centre) < 0:
                outward = -outward
            score = (mid @ away) * min(length, 4.0)
            if outward @ away > 0.3 and (best is None or score > best[0]):
                best = (score, a, b, outward)
        if best is None:
            continue
        _, a, b, outward = best
        height = 0.5 * (v[a, 1] + v[b, 1])
        distance = height / s[1]  # along the sun's ray, ground to the edge
        # Across the edge in the ground plane: the disc's angular diameter seen along the
        # ray, stretched by the ray's slant onto the ground across this edge.
        stretch = 1.0 / max(0.05, abs(s[1]))
        penumbra = 2.0 * distance * tan_r * stretch
        half = max(0.3, 1.5 * penumbra)
        t = np.linspace(-half, half, count)
        out3 = np.array([outward[0], 0.0, outward[1]])
        for frac in (0.5, 0.35, 0.65, 0.2, 0.8):
            c2 = flat[a] + frac * (flat[b] - flat[a])
            centre3 = np.array([c2[0], 0.0, c2[1]])
            points = centre3 + t[:, None] * out3
            normals = np.tile([0.0, 1.0, 0.0], (count, 1))
            vis = build.sun_casters.visible_fraction(points, normals, s, "all")
            if vis[: count // 20].max() > 0.02 or vis[-(count // 20):].min() < 0.98:
                continue
            if not locatable(build, points[[0, count // 2, -1]], normals[:3]).all():
                continue
            if not locatable(build, points, normals).all():
                continue
            lines.append({"name": obj, "points": points, "t": t, "outward": out3,
                          "edge_height_m": float(height), "distance_m": float(distance),
                          "penumbra_geometric_m": float(penumbra)})
            break
    return lines


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


# ------------------------------------------------------------------------------------------
# Metrics


def psnr_rms(got: np.ndarray, ref: np.ndarray) -> dict:
    """PSNR (dB, peak = the largest reference value over these points and channels) and RMS
    error relative to the mean reference (%)."""
    keep = np.all(np.isfinite(got), axis=1) & np.all(np.isfinite(ref), axis=1)
    got, ref = got[keep], ref[keep]
    if len(ref) == 0:
        return {"n": 0, "psnr_db": float("nan"), "rms_pct": float("nan")}
    mse = float(np.mean((got - ref) ** 2))
    peak = float(ref.max())
    psnr = float("inf") if mse == 0 else 10.0 * math.log10(peak**2 / mse)
    return {"n": int(len(ref)), "psnr_db": psnr, "rms_pct": 100.0 * math.sqrt(mse) / ref.mean(),
            "peak_W_m2": peak, "mean_W_m2": float(ref.mean()),
            "bias_pct": 100.0 * float((got - ref).mean() / ref.mean())}


def isotonic(y: np.ndarray) -> np.ndarray:
    """Least-squares non-decreasing fit (pool adjacent violators)."""
    values, weights, sizes = [], [], []
    for v in y:
        values.append(float(v))
        weights.append(1.0)
        sizes.append(1)
        while len(values) > 1 and values[-2] > values[-1]:
            w = weights[-2] + weights[-1]
            values[-2] = (values[-2] * weights[-2] + values[-1] * weights[-1]) / w
            weights[-2] = w
            sizes[-2] += sizes[-1]
            del values[-1], weights[-1], sizes[-1]
    return np.repeat(values, sizes)


def profile_points(t: np.ndarray, e: np.ndarray) -> dict:
    """10, 50 and 90 % points of a profile across a shadow edge (umbra at low ``t``),
    normalised by its own ends (the mean of its first and last 8 %), after an isotonic fit."""
    k = max(2, len(e) // 12)
    lo, hi = float(e[:k].mean()), float(e[-k:].mean())
    f = isotonic((e - lo) / (hi - lo))
    out = {"umbra_W_m2": lo, "lit_W_m2": hi}
    for level in (0.1, 0.5, 0.9):
        i = int(np.argmax(f >= level))
        if i == 0:
            out[f"t{round(100 * level)}_m"] = float(t[0])
            continue
        f0, f1 = f[i - 1], f[i]
        out[f"t{round(100 * level)}_m"] = float(t[i - 1] + (level - f0) / max(f1 - f0, 1e-12)
                                                * (t[i] - t[i - 1]))
    out["width_m"] = out["t90_m"] - out["t10_m"]
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
