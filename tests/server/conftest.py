"""Shared fixtures for the light server's tests: a minimal, schema-valid build directory, and a
small baked site for the scene estimate's tests."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from bake.dome import Dome
from daylit.manifest import validate


def make_build(root: Path, lights: int = 40, scene_id: str = "testsite") -> Path:
    """Write ``root/manifest.json`` (dome of ``lights``) and a tiny dummy ``site.glb``."""
    root.mkdir(parents=True, exist_ok=True)
    glb = b"glTF" + (2).to_bytes(4, "little") + (12).to_bytes(4, "little")
    (root / "site.glb").write_bytes(glb)
    manifest = {
        "format": "daylit-build",
        "version": 1,
        "scene": {
            "id": scene_id,
            "name": "Test site",
            "latitude_deg": 34.4686,
            "longitude_deg": 135.8194,
            "elevation_m": 100.0,
            "timezone": "Asia/Tokyo",
            "north_deg": 0.0,
        },
        "frame": {"units": "m", "up": "+Y", "east": "+X", "north": "-Z"},
        "dome": Dome.for_light_count(lights).to_manifest(),
        "ground": {"albedo": [0.3, 0.3, 0.3], "center_m": [0.0, 0.0], "size_m": [50.0, 50.0]},
        "model": {"path": "site.glb"},
        "atlases": [],
        "views": [],
        "files": [
            {
                "path": "site.glb",
                "bytes": len(glb),
                "sha256": hashlib.sha256(glb).hexdigest(),
            }
        ],
        "bake": {
            "tool": "tests",
            "quality": "draft",
            "seed": 0,
            "samples_per_patch": 1,
            "bounce_rays": 0,
            "created_utc": "2026-01-01T00:00:00Z",
            "duration_s": 0.0,
        },
    }
    validate(manifest)
    (root / "manifest.json").write_text(json.dumps(manifest), "utf-8")
    return root


@pytest.fixture
def build_dir(tmp_path) -> Path:
    """A valid build directory with a 40-light dome."""
    return make_build(tmp_path / "build")


@pytest.fixture(scope="session")
def dome160() -> np.ndarray:
    return Dome.for_light_count(160).vertices


@pytest.fixture(scope="session")
def scene_build(tmp_path_factory) -> Path:
    """A real building (8 x 5 x 6 m, albedo 0.55/0.45/0.35) and wall, a small virtual box out
    of the way, a kiosk view from the north; 40 lights at draft quality (seconds). For the
    scene estimate's server tests (test_scene_source, test_fusion)."""
    from bake.pipeline import bake
    from tests.sites import scene_estimate_site

    root = tmp_path_factory.mktemp("scene")
    scene = scene_estimate_site(root / "scene")
    bake(scene, root / "build", progress=False, log=lambda msg: None)
    return root / "build"
