"""Reading and checking a build's ``manifest.json`` (schema: ``daylit/schemas``).

The manifest is the contract between the baker, the light server and the web client; see
``docs/manifest.md``. The server learns the dome from here, never from the baker's code.
"""

from __future__ import annotations

import hashlib
import json
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np

MANIFEST_NAME = "manifest.json"
SCHEMA_NAME = "manifest.schema.json"


class ManifestError(ValueError):
    """A build directory whose manifest is missing, malformed or does not match its files."""


@cache
def schema() -> dict:
    """The manifest's JSON Schema (draft 2020-12), shipped inside the package."""
    text = resources.files("daylit").joinpath("schemas", SCHEMA_NAME).read_text("utf-8")
    return json.loads(text)


def validate(manifest: dict) -> None:
    """Raise :class:`ManifestError` unless ``manifest`` satisfies the schema and index rule."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(schema())
    errors = sorted(validator.iter_errors(manifest), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        where = "/".join(str(p) for p in e.absolute_path) or "(top level)"
        raise ManifestError(f"manifest {where}: {e.message}")
    lights = manifest["dome"]["lights"]
    if manifest["dome"]["count"] != len(lights):
        raise ManifestError("manifest dome/count does not match the number of lights")
    for position, light in enumerate(lights):
        if light["index"] != position:  # the one index rule
            raise ManifestError(f"manifest dome/lights/{position} has index {light['index']}")


def load(build_dir: Path | str, check_files: bool = False) -> dict:
    """Read and validate ``build_dir/manifest.json``.

    With ``check_files`` every listed file is checked for its size and SHA-256.
    """
    path = Path(build_dir) / MANIFEST_NAME
    if not path.is_file():
        raise ManifestError(
            f"{path}: no manifest; bake the site first (daylit bake scenes/<site> -o {build_dir})"
        )
    try:
        manifest = json.loads(path.read_text("utf-8"))
    except json.JSONDecodeError as exc:
        raise ManifestError(f"{path}: not valid JSON: {exc}") from None
    validate(manifest)
    if check_files:
        verify_files(Path(build_dir), manifest)
    return manifest


def dome_vertices(manifest: dict) -> np.ndarray:
    """(n, 3, 3) unit vertices of every light's triangle, in index order."""
    return np.array([light["vertices"] for light in manifest["dome"]["lights"]], dtype=np.float64)


def file_entry(root: Path, path: Path) -> dict:
    """``{"path", "bytes", "sha256"}`` of one file, its path relative to ``root``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return {
        "path": path.relative_to(root).as_posix(),
        "bytes": path.stat().st_size,
        "sha256": digest.hexdigest(),
    }


def verify_files(build_dir: Path, manifest: dict) -> None:
    """Raise :class:`ManifestError` if a listed file is missing or differs from its entry."""
    for entry in manifest["files"]:
        actual = build_dir / entry["path"]
        if not actual.is_file():
            raise ManifestError(f"{build_dir}: {entry['path']} is listed but missing")
        found = file_entry(build_dir, actual)
        if found["bytes"] != entry["bytes"] or found["sha256"] != entry["sha256"]:
            raise ManifestError(f"{build_dir}: {entry['path']} does not match its checksum")
