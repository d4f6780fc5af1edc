"""A coarse start for slow links: the first few base layers of each atlas stack in a small file
of their own, so that a phone draws its first relit frame from a few hundred kilobytes and
refines it when the full arrays have arrived (docs/compact-assets.md, "A coarse start").

A stack's base array (``compact.ktx2``: UASTC, Zstandard-supercompressed, one level, L
layers) holds the coarse parts of the leading coefficients first (layer j is coefficient j for
j < 8 or more: ``compact.layers``). The coarse file is that array cut to its first ``N``
layers: the same KTX2 header, data format and key/values with ``layerCount = N`` and the level's
bytes (``N`` x blocks x 16 bytes of UASTC, decompressed and compressed again with the
``zstd`` program) cut to those layers; no layer is encoded again, so its texels are exactly
those of the full array. Next to it, V cut to the coefficients those layers use
(``(n, kc)`` float32, row-major). The manifest entry::

    compact.coarse = {"ktx2": "coarse/ground.I.ktx2", "layers": N,
                      "v": {"path": "coarse/ground.I.V.bin", "shape": [n, kc], "dtype": ...}}

``N`` is the largest count whose compressed bytes stay within ``budget_bytes`` per stack
(at least one layer), and only layers of distinct coefficients are taken.

``daylit bake`` writes them itself, into its staging folder before the build is published
(:func:`add_coarse_entries`, called by bake.pipeline). For a build baked before 2026-11-25::

    python -m bake.coarse BUILD [--budget-kb 100]     # adds them to an existing build
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np

from bake.compact_reader import V_DTYPES

KTX2_ID = b"\xabKTX 20\xbb\r\n\x1a\n"
UASTC_BLOCK_BYTES = 16  # one 4 x 4 block
ZSTD_SCHEME = 2
DEFAULT_BUDGET_BYTES = 100_000
ZSTD_LEVEL = 19
COARSE_DIR = "coarse"


class CoarseError(RuntimeError):
    """A base array this module cannot cut (not one-level UASTC with Zstandard), or no zstd."""


def _zstd(args: list[str], data: bytes) -> bytes:
    exe = shutil.which("zstd")
    if exe is None:
        raise CoarseError("the `zstd` program is not installed (Debian: apt-get install zstd)")
    result = subprocess.run([exe, *args, "-c", "-q"], input=data, capture_output=True)
    if result.returncode != 0:
        raise CoarseError(f"zstd {' '.join(args)} failed: {result.stderr.decode()[-300:]}")
    return result.stdout


def read_ktx2_level(data: bytes, name: str = "KTX2") -> tuple[dict, bytes]:
    """The header fields and level 0's decompressed bytes of a one-level UASTC+Zstandard
    KTX2 (``layers`` x ceil(H/4) x ceil(W/4) x 16 bytes)."""
    if data[:12] != KTX2_ID:
        raise CoarseError(f"{name}: not a KTX2 file")
    vk_format, _, width, height, depth, layers, faces, levels, scheme = struct.unpack_from(
        "<9I", data, 12)
    sgd_length = struct.unpack_from("<Q", data, 72)[0]
    if vk_format != 0 or scheme != ZSTD_SCHEME or levels != 1 or faces != 1 or depth \
            or sgd_length:
        raise CoarseError(f"{name}: not a one-level UASTC array with Zstandard supercompression "
                          f"(vkFormat {vk_format}, scheme {scheme}, {levels} levels)")
    offset, length, raw_length = struct.unpack_from("<3Q", data, 80)
    raw = _zstd(["-d"], data[offset:offset + length])
    layer_bytes = -(-width // 4) * -(-height // 4) * UASTC_BLOCK_BYTES
    if len(raw) != raw_length or raw_length != max(layers, 1) * layer_bytes:
        raise CoarseError(f"{name}: level 0 holds {len(raw)} bytes, expected "
                          f"{max(layers, 1)} x {layer_bytes}")
    header = {"width": width, "height": height, "layers": max(layers, 1),
              "layer_bytes": layer_bytes, "level_offset": offset}
    return header, raw


def cut_layers(data: bytes, raw: bytes, header: dict, n_layers: int) -> bytes:
    """The KTX2 ``data`` with only its first ``n_layers`` layers (``raw``: its level 0,
    decompressed, from :func:`read_ktx2_level`)."""
    if not 1 <= n_layers <= header["layers"]:
        raise CoarseError(f"cannot keep {n_layers} of {header['layers']} layers")
    kept = raw[:n_layers * header["layer_bytes"]]
    packed = _zstd([f"-{ZSTD_LEVEL}"], kept)
    offset = header["level_offset"]
    head = bytearray(data[:offset])  # header, index, level index, DFD, key/values: kept
    struct.pack_into("<I", head, 32, n_layers)  # layerCount
    struct.pack_into("<3Q", head, 80, offset, len(packed), len(kept))
    return bytes(head) + packed


def coarse_count(layers: list[dict]) -> int:
    """How many leading layers are distinct coefficients (the coarse parts, before the first
    refinement)."""
    seen = set()
    for j, layer in enumerate(layers):
        if layer["coefficient"] in seen:
            return j
        seen.add(layer["coefficient"])
    return len(layers)


def write_coarse_stack(build_dir: Path, key: str, compact: dict,
                       budget_bytes: int = DEFAULT_BUDGET_BYTES) -> dict:
    """Write ``coarse/KEY.ktx2`` and ``coarse/KEY.V.bin`` for one stack; its manifest entry."""
    build_dir = Path(build_dir)
    data = (build_dir / compact["ktx2"]).read_bytes()
    header, raw = read_ktx2_level(data, compact["ktx2"])
    most = min(coarse_count(compact["layers"]), header["layers"])
    best = None
    for n in range(1, most + 1):
        cut = cut_layers(data, raw, header, n)
        if best is not None and len(cut) > budget_bytes:
            break
        best = (n, cut)
    n, cut = best
    out = build_dir / COARSE_DIR
    out.mkdir(exist_ok=True)
    (out / f"{key}.ktx2").write_bytes(cut)
    rows, k = compact["v"]["shape"]
    # The first kc columns of V, stored as the stack's V is (type and scale, or the first kc
    # columns' scales: the same values).
    kc = 1 + max(layer["coefficient"] for layer in compact["layers"][:n])
    stored = {key: value for key, value in compact["v"].items() if key in ("dtype", "scale")}
    if "scales" in compact["v"]:
        stored["scales"] = compact["v"]["scales"][:kc]
    dtype = V_DTYPES[stored.get("dtype", "float32-le")]
    V = np.fromfile(build_dir / compact["v"]["path"], dtype=dtype).reshape(rows, k)
    np.ascontiguousarray(V[:, :kc]).tofile(out / f"{key}.V.bin")
    return {"ktx2": f"{COARSE_DIR}/{key}.ktx2", "layers": n,
            "v": {"path": f"{COARSE_DIR}/{key}.V.bin", "shape": [rows, kc],
                  "dtype": "float32-le", **stored}}


def add_coarse_entries(build_dir: Path, atlases: list[dict],
                       budget_bytes: int = DEFAULT_BUDGET_BYTES) -> dict:
    """Write the coarse start of every stack of ``atlases`` (the manifest's atlas entries,
    their files in ``build_dir``) and set each stack's ``compact.coarse``. All or nothing: if
    one stack cannot be cut (:class:`CoarseError`), the files written are removed, no entry
    is changed and the error is raised. Returns ``{stack key: coarse entry}``."""
    build_dir = Path(build_dir)
    added = {}
    # A build's earlier coarse start (run again, another budget): its files are not removed.
    before = set((build_dir / COARSE_DIR).glob("*")) if (build_dir / COARSE_DIR).is_dir() else set()
    try:
        for atlas in atlases:
            for name, stack in atlas["stacks"].items():
                key = f"{atlas['id']}.{name}"
                added[key] = write_coarse_stack(build_dir, key, stack["compact"], budget_bytes)
    except BaseException:
        for entry in added.values():
            for path in (entry["ktx2"], entry["v"]["path"]):
                if build_dir / path not in before:
                    (build_dir / path).unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            (build_dir / COARSE_DIR).rmdir()  # only if empty: nothing of anyone else's
        raise
    for atlas in atlases:
        for name, stack in atlas["stacks"].items():
            stack["compact"]["coarse"] = added[f"{atlas['id']}.{name}"]
    return added


def add_coarse(build_dir: Path, budget_bytes: int = DEFAULT_BUDGET_BYTES) -> dict:
    """Add a coarse start to every atlas stack of an existing build and rewrite its manifest
    (files listed with their size and SHA-256). Returns ``{stack key: coarse entry}``."""
    from daylit import manifest as manifest_io

    build_dir = Path(build_dir)
    manifest = json.loads((build_dir / "manifest.json").read_text())
    added = add_coarse_entries(build_dir, manifest["atlases"], budget_bytes)
    # The other files are listed already (and may be gigabytes of masters): only the new ones.
    new_paths = {p for entry in added.values() for p in (entry["ktx2"], entry["v"]["path"])}
    files = [f for f in manifest["files"] if f["path"] not in new_paths]
    files += [manifest_io.file_entry(build_dir, build_dir / p) for p in new_paths]
    manifest["files"] = sorted(files, key=lambda f: f["path"])
    manifest_io.validate(manifest)
    tmp = build_dir / "manifest.json.tmp"
    tmp.write_text(json.dumps(manifest, separators=(",", ":")) + "\n", encoding="utf-8")
    tmp.replace(build_dir / "manifest.json")
    return added


def main() -> None:
    parser = argparse.ArgumentParser(
        prog="python -m bake.coarse",
        description="Add a coarse start for slow links to a build baked before 2026-11-25 "
        "(`daylit bake` now writes it itself): the first base layers of each atlas stack in "
        "coarse/, listed in manifest.json with size and SHA-256 (docs/compact-assets.md, "
        "\"A coarse start\"). Run it again to redo them, e.g. with another budget.")
    parser.add_argument("build", type=Path, help="the build folder (holding manifest.json)")
    parser.add_argument("--budget-kb", type=float, default=DEFAULT_BUDGET_BYTES / 1e3,
                        help="kilobytes (1000 bytes) of each stack's compressed coarse array; the "
                        "largest number of layers within it is kept (at least one layer)")
    args = parser.parse_args()
    if not (args.build / "manifest.json").is_file():
        parser.error(f"{args.build} holds no manifest.json: not a daylit build")
    try:
        added = add_coarse(args.build, int(args.budget_kb * 1e3))
    except CoarseError as e:
        parser.exit(1, f"python -m bake.coarse: {e}; the build is unchanged\n")
    for key, entry in added.items():
        size = (args.build / entry["ktx2"]).stat().st_size
        print(f"{key}: {entry['layers']} layers, {size / 1e3:.0f} kB; V {entry['v']['shape']}")


if __name__ == "__main__":
    main()
