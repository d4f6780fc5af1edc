"""What the server offers of the sun's bounce, and two designs that would offer less, judged
as displayed (issue 15, item 8; docs/sun.md, "The sun's bounce").

    PYTHONPATH=. python benchmarks/sun_bounce_designs.py BUILD [--truth REF] [--json OUT]

Prints what the build's compact files are made of (per sun-bounce stack and level, and the
rest), then for every sun-bounce stack the as-displayed error of these columns, each judged
by the independent judge of ``benchmarks/sun_bounce_display.py`` (gendaylit's clear sky
without its disc, rtrace patch means, pvlib DNI/DHI, EXR masters; RMS over the mean of the
displayed value, p99 per texel):

- ``stored``: the build's images as the client decodes them (every level it keeps);
- ``low/2``, ``low/3``: the column at 1/2 or 1/3 of the atlas's (view's) resolution, the
  best such image in least squares over the receiver texels, drawn as the GPU would
  (bilinear, texel centres, clamp to edge): the design "bounce images at a lower
  resolution";
- ``blend/1``, ``blend/2``: the bounce per unit normal irradiance at the vertices of the
  dome (``/1``) or of the dome of half its frequency (``/2``, a quarter of the images),
  each vertex's image the mean of the columns of the sun-path patches around it over their
  solid angle, the sun in patch ``p`` drawn as the barycentric blend of its coarse
  triangle's three vertices at the patch's centroid: the design "the bounce on a coarser
  dome, blended by the sun's direction" (no jump at patch edges).

With ``--truth REF`` (the same scene baked with more rays, the same dome and texels) the
judge's masters (sky stacks and the sun's bounce) are REF's, and the build's own ``master``
columns are judged too: the bake's own sampling error, which every design inherits.
Encoding is left out of the designs (their error with UASTC would be larger).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.radiance import radiance_env  # noqa: E402
from benchmarks.sun_bounce_display import (  # noqa: E402
    DECODE_CHUNK,
    clear_sky_sun,
    displayed_errors,
    gendaylit_vector,
    patch_directions,
    sky_relit,
)

LOW_FACTORS = (2, 3)
BLEND_FACTORS = (1, 2)
SMOOTHNESS = 1e-4  # the low-resolution fit's weight on neighbour differences (unseen texels)


def offering(build_dir: Path) -> dict:
    """Bytes of the build's compact files: per sun-bounce stack ``{stack: {"coarse",
    "refine", "files"}}``, the rest by top folder, and ``bake.downloads.download_bytes``."""
    from bake.downloads import download_bytes

    manifest = json.loads((build_dir / "manifest.json").read_text())
    stacks: dict = collections.defaultdict(lambda: {"coarse": 0, "refine": 0, "files": 0})
    rest: dict = collections.defaultdict(int)
    for f in manifest["files"]:
        path = f["path"]
        if path.startswith("ktx2/") and ".sun_bounce." in path:
            s = stacks[path[5:].rsplit(".L", 1)[0]]
            s["refine" if path.endswith("r.ktx2") else "coarse"] += f["bytes"]
            s["files"] += 1
        else:
            rest[path.split("/")[0]] += f["bytes"]
    return {"sun_bounce": dict(stacks), "rest": dict(rest),
            "downloads": download_bytes(manifest, build_dir)}


def bilinear_operator(H: int, W: int, h: int, w: int):
    """(H*W, h*w) sparse: an (h, w) image drawn at (H, W) as the GPU's bilinear filter does
    (texel centres, clamp to edge)."""
    import scipy.sparse as sp

    def axis(n_out, n_in):
        t = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0.0, n_in - 1)
        i0 = np.floor(t).astype(int)
        return i0, np.minimum(i0 + 1, n_in - 1), t - i0

    y0, y1, ay = axis(H, h)
    x0, x1, ax = axis(W, w)
    Y, X = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    rows, cols, vals = [], [], []
    for yy, wy in ((y0, 1 - ay), (y1, ay)):
        for xx, wx in ((x0, 1 - ax), (x1, ax)):
            rows.append((Y * W + X).ravel())
            cols.append((yy[Y] * w + xx[X]).ravel())
            vals.append((wy[Y] * wx[X]).ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(H * W, h * w))


def low_resolution(columns: np.ndarray, valid: np.ndarray, factor: int) -> np.ndarray:
    """``columns`` (H, W, L, 3) as images at 1/``factor`` of the resolution, fitted in least
    squares over the ``valid`` (H, W) texels and drawn back bilinearly: (H, W, L, 3)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    H, W, L, _ = columns.shape
    h, w = -(-H // factor), -(-W // factor)
    U = bilinear_operator(H, W, h, w)
    Uv = U[valid.ravel()]
    index = np.arange(h * w).reshape(h, w)
    diffs = []
    for a, b in ((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])):
        k = np.arange(a.size)
        diffs.append(sp.csr_matrix((np.r_[np.ones(a.size), -np.ones(a.size)],
                                    (np.r_[k, k], np.r_[a.ravel(), b.ravel()])),
                                   shape=(a.size, h * w)))
    D = sp.vstack(diffs)
    # Texels no receiver sees (gutters) are kept smooth, so they are defined.
    lu = spl.splu((Uv.T @ Uv + SMOOTHNESS * (D.T @ D)).tocsc())
    rhs = columns[valid].reshape(-1, L * 3).astype(np.float64)
    low = lu.solve(np.asarray(Uv.T @ rhs))
    return (U @ low).astype(np.float32).reshape(H, W, L, 3)


def coarse_dome_blend(manifest: dict, lights, factor: int):
    """The blend design's nodes for the sun-path ``lights``: the vertices of the dome of
    1/``factor`` of the build's frequency (the same family) whose triangles hold a light's
    centroid. Returns ``(around, blend)``: ``around[j]`` the sun-path lights with node ``j``
    as a vertex (the node's image is their columns' mean over their solid angle; the nearest
    light when none), ``blend[p]`` = (three node indices, three barycentric weights) at light
    ``p``'s centroid."""
    from bake.dome import Dome
    from daylit.manifest import dome_vertices

    fine = dome_vertices(manifest)
    centroids = fine.mean(axis=1)
    centroids /= np.linalg.norm(centroids, axis=1, keepdims=True)
    dome = manifest["dome"]
    coarse = Dome.build(dome["kind"], dome["frequency"] // factor).vertices
    edges = [np.cross(coarse[:, e], coarse[:, (e + 1) % 3]) for e in range(3)]
    nodes: list[np.ndarray] = []

    def node(v):
        for j, n in enumerate(nodes):
            if np.allclose(v, n, atol=1e-9):
                return j
        nodes.append(v)
        return len(nodes) - 1

    blend = {}
    for p in lights:
        d = centroids[p]
        inside = np.all([e @ d >= -1e-12 for e in edges], axis=0)
        tri = coarse[int(np.argmax(inside))]
        weights = np.clip(np.linalg.solve(tri.T, d), 0.0, None)
        blend[int(p)] = ([node(v) for v in tri], weights / weights.sum())
    around = []
    for v in nodes:
        near = [int(p) for p in lights if np.min(np.linalg.norm(fine[p] - v, axis=1)) < 1e-6]
        around.append(near or [int(lights[np.argmax(centroids[lights] @ v)])])
    return around, blend


def blended(columns: np.ndarray, lights, omega_sr: np.ndarray, around, blend) -> np.ndarray:
    """The blend design's column of each light (``columns`` (H, W, n, 3) the masters):
    (H, W, len(lights), 3)."""
    per_irradiance = np.stack(
        [columns[:, :, a].sum(axis=2) / omega_sr[a].sum() for a in around], axis=2)
    out = np.empty(columns.shape[:2] + (len(lights), 3), dtype=np.float32)
    for j, p in enumerate(lights):
        idx, w = blend[int(p)]
        out[:, :, j] = omega_sr[p] * np.einsum("hwkc,k->hwc", per_irradiance[:, :, idx], w)
    return out


def measure(build_dir: Path, truth_dir: Path | None = None, log=print) -> list[dict]:
    """One row per stack and sun-path light: the designs' as-displayed errors."""
    from bake.compact_reader import CompactReader
    from bake.evaluate import Build
    from daylit.stackio import read_stack_exr

    build = Build(build_dir)
    m = build.manifest
    ref_dir = truth_dir or build_dir
    ref = Build(ref_dir).manifest
    lights = [int(p) for p in build.selection.selectable]
    omega = np.array([light["solid_angle_sr"] for light in m["dome"]["lights"]])
    _, env = radiance_env()
    dirs = patch_directions(build.dome_vertices)
    log(f"{len(lights)} sun-path lights; gendaylit skies ...")
    skies = {}
    for p in lights:
        sun = np.asarray(m["dome"]["lights"][p]["centroid"], float)
        sun /= np.linalg.norm(sun)
        dni, dhi = clear_sky_sun(sun, m["scene"]["elevation_m"])
        skies[p] = (gendaylit_vector(sun, dni, dhi, build.dome_vertices, env, dirs),
                    np.full(3, dni / omega[p]))
    blends = {f: coarse_dome_blend(m, lights, f) for f in BLEND_FACTORS}
    rows = []
    for owner, ref_owner in zip(m["atlases"] + m["views"], ref["atlases"] + ref["views"],
                                strict=True):
        for stack, sb in owner.get("sun_bounce", {}).items():
            name = f"{owner['id']}.{stack}"
            log(f"  {name} ...")
            ref_sb = ref_owner["sun_bounce"][stack]
            sky = read_stack_exr(ref_dir / ref_owner["stacks"][stack]["master"])
            valid = np.any(sky != 0.0, axis=(2, 3))
            sky_valid = [sky[..., c][valid].astype(np.float64) for c in range(3)]
            del sky
            master = read_stack_exr(build_dir / sb["master"])
            truth = master if truth_dir is None else read_stack_exr(ref_dir / ref_sb["master"])
            candidates = {}
            if truth_dir is not None:
                candidates["master"] = master[:, :, lights]
            for f in LOW_FACTORS:
                candidates[f"low/{f}"] = low_resolution(master[:, :, lights], valid, f)
            for f, (around, blend) in blends.items():
                candidates[f"blend/{f}"] = blended(master, lights, omega, around, blend)
            reader = CompactReader(build_dir, sb["compact"], (owner["height"], owner["width"]))
            for j, p in enumerate(lights):
                if j % DECODE_CHUNK == 0:  # one decoder run per chunk of lights
                    reader.forget_lights()
                    reader.lights(lights[j: j + DECODE_CHUNK])
                r, weight = skies[p]
                cols = {k: v[:, :, j][valid] for k, v in candidates.items()}
                cols["stored"] = reader.lights([p])[p][valid]
                errors = displayed_errors(sky_relit(sky_valid, r),
                                          truth[:, :, p][valid].astype(np.float64), cols, weight)
                rows.append({"stack": name, "light": p, **errors})
            reader.forget_lights()
            del candidates, master, truth, sky_valid
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("build", type=Path)
    ap.add_argument("--truth", type=Path, help="the same scene baked with more rays")
    ap.add_argument("--json", type=Path, help="write the offering and every row here")
    args = ap.parse_args()
    offer = offering(args.build)
    total = sum(s["coarse"] + s["refine"] for s in offer["sun_bounce"].values())
    print(f"the server offers {offer['downloads']['all'] / 1e6:.2f} MB of compact files; "
          f"the sun's bounce {total / 1e6:.2f} MB of them")
    for name, s in sorted(offer["sun_bounce"].items()):
        print(f"  {name:<24}coarse {s['coarse'] / 1e6:6.2f} MB  refinement "
              f"{s['refine'] / 1e6:6.2f} MB  ({s['files']} files)")
    rows = measure(args.build, args.truth, log=lambda s: print(s, file=sys.stderr))
    if args.json:
        args.json.write_text(json.dumps({"offering": offer, "rows": rows}, indent=1))
    names = [k for k in rows[0] if k not in ("stack", "light")]
    print(f"{'RMS max (median)':<14}" + "".join(f"{n:>18}" for n in names))
    for stack in dict.fromkeys(r["stack"] for r in rows):
        rs = [r for r in rows if r["stack"] == stack]
        cells = []
        for n in names:
            e = np.array([r[n]["rms"] for r in rs])
            cells.append(f"{e.max():>9.2%} ({np.median(e):.2%})")
        print(f"{stack:<14}" + "".join(f"{c:>18}" for c in cells))


if __name__ == "__main__":
    main()
