"""The build's ``manifest.json``: assembled from the site, the dome, the written atlases and
views and the compression report, every file listed with its size and SHA-256, validated
against the schema (daylit/schemas) and written atomically.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from daylit import manifest as manifest_io


def build_manifest(site, dome, nodes, atlases, views, compressor, bake_info) -> dict:
    return {
        "format": "daylit-build",
        # 2 since a stack's base layers may be split into a UASTC and an ETC1S array
        # (compact.etc1s), which a version-1 client would not sum; 3 since neighbouring
        # sun-path patches share one sun-bounce image (lights.image), which a version-2
        # client would ask for under each patch's own name; 4 since a stack's V may be
        # float16 (compact.v.dtype), which a version-3 client would read as float32; 5 since
        # it may be int8 with a scale per column, which a version-4 client refuses
        # (docs/manifest.md).
        "version": 5,
        "scene": {
            "id": site.scene_id,
            "name": site.name,
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "elevation_m": site.elevation_m,
            "timezone": site.timezone,
            "north_deg": site.north_deg,
        },
        "frame": {"units": "m", "up": "+Y", "east": "+X", "north": "-Z"},
        "dome": dome.to_manifest(),
        "ground": {
            "albedo": [float(a) for a in site.ground.albedo],
            "center_m": list(site.ground.center_m),
            "size_m": list(site.ground.size_m),
        },
        "model": {"path": "site.glb", "nodes": nodes},
        "atlases": atlases,
        "views": views,
        "files": [],
        "compression": compressor.manifest_entry(),
        "bake": bake_info,
    }


def write_manifest(build_dir: Path, manifest: dict) -> None:
    """List every file of ``build_dir`` with size and SHA-256, validate, write manifest.json."""
    files = sorted(p for p in build_dir.rglob("*") if p.is_file() and p.name != "manifest.json")
    manifest["files"] = [manifest_io.file_entry(build_dir, p) for p in files]
    save_manifest(build_dir, manifest)


def save_manifest(build_dir: Path, manifest: dict) -> None:
    """Validate ``manifest`` (its files listed) and write it as manifest.json in one rename."""
    manifest_io.validate(manifest)
    tmp = build_dir / "manifest.json.tmp"
    # Compact separators: phones download this (indenting it would add a third).
    tmp.write_text(json.dumps(manifest, separators=(",", ":")) + "\n", encoding="utf-8")
    os.replace(tmp, build_dir / "manifest.json")
