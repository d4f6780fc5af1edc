"""Shared fixtures: small bakes reused across test modules (baked once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def demo_draft_build(tmp_path_factory) -> Path:
    """The demo site baked at draft quality with Kakuta's 40-light dome."""
    from bake.pipeline import bake

    out = tmp_path_factory.mktemp("demo") / "build"
    bake(
        REPO / "scenes" / "demo",
        out,
        lights=40,
        quality="draft",
        progress=False,
        log=lambda msg: None,
    )
    return out


# The sun's test site: a virtual wall (8 m wide along x, 5 m high, 1 m thick, centred at the
# origin) and a real proxy "shed" (3 x 5 x 1 m) 12 m east of it, on a 60 m ground.
SUN_WALL_SIZE_M = (8.0, 5.0, 1.0)
SUN_SHED = dict(name="shed", box_m=(3.0, 5.0, 1.0), translation_m=(12.0, 0.0, 0.0))


@pytest.fixture(scope="session")
def sun_site_build(tmp_path_factory) -> Path:
    """A virtual wall and a real shed, baked at draft quality with 40 lights (about 20 s)."""
    from bake.pipeline import bake
    from tests.sites import box, make_site, real_box

    root = tmp_path_factory.mktemp("sun")
    wall = box(list(SUN_WALL_SIZE_M), [0.0, 0.0, 0.0])
    scene = make_site(
        root / "scene",
        virtual=[("wall", wall, (0.5, 0.5, 0.5))],
        real=real_box(**SUN_SHED),
        ground_m=60.0,
    )
    bake(scene, root / "build", progress=False, log=lambda msg: None)
    return root / "build"
