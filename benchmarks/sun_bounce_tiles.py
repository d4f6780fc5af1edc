"""How well a basis per tile over the sun's path holds a sun-bounce stack as displayed.

Issue 15 item 8: what a server would offer of the sun's bounce with it; not a design of the
bake, a measurement.

The stack's columns for the sun-path patches (``B_p``, H x W x 3) are split into square
tiles of ``T`` x ``T`` texels; each tile's block is approximated by its best rank-``k``
product (a truncated SVD, the least-squares best), so that a texel keeps ``k`` coefficients
(``--joint``: shared by R, G, B; else ``k`` per channel) and a tile ``k`` values per patch
(and channel, ``--joint``). A client would fetch the coefficients once and one row per tile
for the sun's patch; the global basis (one tile) is the low-rank base measured in
docs/benchmarks.md ("The sun's bounce as displayed with the sun's direct term: still not low
rank").

Each column is judged as the bake judges a sun-bounce image (bake.sundisplay.DisplayCheck):
the RMS of the error ``E_sun / omega_p (B_hat_p - B_p)`` over the receiver texels and
channels, over the mean of what is displayed (the sky stack relit with the patch's display
sky, plus the sun's direct term, plus the bounce). Each column is scaled by its displayed
mean before the SVD, so that no column's error is sacrificed to a brighter one's. With
``--bits`` the coefficients are rounded to that many bits with one scale per tile and
coefficient (as V in int8, docs/compact-assets.md) and the rows to float16 first. No
texture codec: a lower bound of what a shipped encoding would add; with ``--codec`` (joint
only) the coefficients are also written as RGBA PNGs (four per texel each, 8 bits with one
scale per tile and coefficient), encoded in UASTC as the bake encodes its images
(bake.basisu), decoded as the client decodes them (bake.ktx2decoder) and judged so, and
their files' bytes are printed.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/sun_bounce_tiles.py BUILD [--owner lightmap]
        [--stack I] [--tiles 8,16,32] [--ranks 4,6,8,12,16,24] [--joint] [--bits 8]
        [--codec [--level N]]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake.compact_reader import INT8_TOP, column_scales  # noqa: E402
from bake.evaluate import Build  # noqa: E402
from bake.rowstore import as_stack  # noqa: E402
from bake.sundisplay import DisplayCheck, DisplaySkies  # noqa: E402
from daylit.manifest import ManifestError  # noqa: E402
from daylit.stackio import read_stack_exr  # noqa: E402


def displayed_columns(build_dir: Path, owner_id: str, stack: str):
    """(X, valid, lights): X (V, 3, P) float32 each sun-path light's column as displayed,
    ``E_sun / omega_p B_p`` at the V receiver texels over the mean displayed with it;
    ``valid`` (H, W) the receiver texels; ``lights`` the P sun-path lights."""
    build = Build(build_dir)
    m = build.manifest
    owner = next(o for o in m["atlases"] + m["views"] if o["id"] == owner_id)
    lights = [int(i) for i in build.selection.selectable]
    skies = DisplaySkies.of_dome(build.dome_vertices, build.solid_angles, lights,
                                 m["scene"]["elevation_m"])
    bounce = as_stack(read_stack_exr(build_dir / owner["sun_bounce"][stack]["master"]))
    sky = read_stack_exr(build_dir / owner["stacks"][stack]["master"])
    check = DisplayCheck(sky, skies, lights, bounce=bounce)
    del sky
    columns = bounce.columns(lights)  # (P, H, W, 3)
    X = np.empty((int(check.valid.sum()), 3, len(lights)), np.float32)
    for j, p in enumerate(lights):
        bounce_shown = columns[j][check.valid] * skies.weight[skies.row(p)]
        X[:, :, j] = bounce_shown / float((check.shown_but_bounce([p])[0] + bounce_shown).mean())
    check.remove()
    return X, check.valid, lights


def tile_errors(X: np.ndarray, groups: list[np.ndarray], ranks: list[int], joint: bool,
                bits: int | None) -> dict[int, np.ndarray]:
    """{k: (P,) each column's RMS error as displayed} with a rank-``k`` basis per tile, the
    tiles' texels ``groups`` (:func:`tile_groups`; the module's docstring)."""
    V, _, P = X.shape
    squared = {k: np.zeros(P) for k in ranks}
    for g in groups:
        # Rows: a texel (joint: its three channels side by side) or a texel's channel.
        M = (X[g].reshape(len(g), 3 * P) if joint else X[g].reshape(-1, P)).astype(np.float64)
        U, s, Vt = np.linalg.svd(M, full_matrices=False)
        for k in ranks:
            coefficients = U[:, :k] * s[:k]  # (rows, k): a texel's k values
            rows = Vt[:k]  # (k, columns): the tile's values for each patch
            if bits is not None:
                codes, scale = rounded(coefficients, bits)
                coefficients = codes * scale
                rows = rows.astype(np.float16).astype(np.float64)
            err = coefficients @ rows - M
            squared[k] += (err.reshape(len(g), 3, P) ** 2).sum(axis=(0, 1))
    return {k: np.sqrt(v / (V * 3)) for k, v in squared.items()}


def rounded(coefficients: np.ndarray, bits: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(codes, scales): ``coefficients`` (n, k) as signed ``bits``-bit codes, one scale per
    column; at 8 bits V's int8 rule (:func:`bake.compact_reader.column_scales`)."""
    scale = column_scales(coefficients) * (INT8_TOP / (2 ** (bits - 1) - 1))
    return np.rint(coefficients / scale), scale


def tile_groups(valid: np.ndarray, tile: int) -> list[np.ndarray]:
    """The receiver texels (indices into the V valid ones, row-major) of each tile."""
    ys, xs = np.nonzero(valid)
    index = (ys // tile) * (-(-valid.shape[1] // tile)) + xs // tile
    order = np.argsort(index, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(index[order])) + 1)


def codec_errors(X: np.ndarray, valid: np.ndarray, groups: list[np.ndarray], k: int,
                 folder: Path, level: int | None = None) -> tuple[np.ndarray, int]:
    """((P,) each column's RMS error as displayed, bytes of the coefficient files) with a
    joint rank-``k`` basis per tile (the tiles' texels ``groups``: :func:`tile_groups`; the
    files laid out over ``valid``) whose coefficients go through UASTC (``--codec``); the
    files are written into ``folder``; ``level``: the UASTC level (None: the bake's)."""
    from bake.basisu import encode
    from bake.compresssettings import Settings
    from bake.ktx2decoder import decode

    V, _, P = X.shape
    coefficients = np.zeros((V, -(-k // 4) * 4))
    scales, rows = [], []
    for g in groups:
        U, s, Vt = np.linalg.svd(X[g].reshape(len(g), 3 * P).astype(np.float64),
                                 full_matrices=False)
        c = np.zeros((len(g), k))
        c[:, : min(k, len(s))] = (U * s)[:, :k]
        coefficients[g, :k], scale = rounded(c)
        scales.append(scale)
        r = np.zeros((k, 3 * P))
        r[: min(k, len(s))] = Vt[:k]
        rows.append(r.astype(np.float16).astype(np.float64))
    codes = (coefficients + 128.0).astype(np.uint8)  # 1..255: rounded() keeps within +-127
    H, W = valid.shape
    pngs = []
    for t in range(codes.shape[1] // 4):
        image = np.zeros((H, W, 4), np.uint8)
        image[valid] = codes[:, 4 * t : 4 * t + 4]
        path = folder / f"coefficients{t}.png"
        cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA))
        pngs.append(path)
    encode(pngs, folder, Settings(), array=False, level=level)
    files = [folder / f"coefficients{t}.ktx2" for t in range(len(pngs))]
    decoded = np.concatenate([d[0][valid] for d in decode(files)], axis=1)
    squared = np.zeros(P)
    for g, scale, r in zip(groups, scales, rows, strict=True):
        c = (decoded[g, :k].astype(np.float64) - 128.0) * scale
        err = c @ r - X[g].reshape(len(g), 3 * P)
        squared += (err.reshape(len(g), 3, P) ** 2).sum(axis=(0, 1))
    return np.sqrt(squared / (V * 3)), sum(f.stat().st_size for f in files)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--owner", default="lightmap", help="atlas or fixed view id")
    parser.add_argument("--stack", default="I")
    parser.add_argument("--tiles", default="8,16,32", help="tile sizes in texels")
    parser.add_argument("--ranks", default="4,6,8,12,16,24")
    parser.add_argument("--joint", action="store_true", help="R, G, B share coefficients")
    parser.add_argument("--bits", type=int, default=None, help="round the coefficients")
    parser.add_argument("--codec", action="store_true",
                        help="the coefficients through UASTC as well (joint)")
    parser.add_argument("--level", type=int, default=None,
                        help="UASTC level of --codec (default: the bake's)")
    args = parser.parse_args()
    if args.codec and not args.joint:
        parser.error("--codec needs --joint")
    try:
        X, valid, lights = displayed_columns(args.build, args.owner, args.stack)
    except ManifestError as exc:
        parser.error(str(exc))
    except (StopIteration, KeyError):
        parser.error(f"{args.build} has no sun-bounce stack {args.owner}.sun_bounce."
                     f"{args.stack} (its atlases and views: see its manifest.json)")
    V, _, P = X.shape
    ranks = [int(k) for k in args.ranks.split(",")]
    print(f"{args.owner}.sun_bounce.{args.stack}: {V} receiver texels, {P} sun-path patches; "
          f"{'joint' if args.joint else 'per channel'}, "
          f"{'unrounded' if args.bits is None else f'{args.bits}-bit coefficients'}")
    print("tile | tiles | k | worst column | median | values per texel | values per patch")
    for tile in [int(t) for t in args.tiles.split(",")]:
        groups = tile_groups(valid, tile)
        tiles = len(groups)
        errors = tile_errors(X, groups, ranks, args.joint, args.bits)
        for k in ranks:
            e = errors[k]
            per_texel = k if args.joint else 3 * k
            per_patch = tiles * k * (3 if args.joint else 1)
            print(f"{tile} | {tiles} | {k} | {100 * e.max():.2f} % | {100 * np.median(e):.2f} % "
                  f"| {per_texel} | {per_patch:,}", flush=True)
            if args.codec:
                with tempfile.TemporaryDirectory() as folder:
                    e, size = codec_errors(X, valid, groups, k, Path(folder), args.level)
                print(f"  through UASTC: {100 * e.max():.2f} % | {100 * np.median(e):.2f} % "
                      f"| {size:,} B of coefficients", flush=True)


if __name__ == "__main__":
    main()
