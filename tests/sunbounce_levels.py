"""A copy of a build whose sun-bounce stacks are compressed again with another
``compression.sun_bounce_budget`` (``bake.sunbounce.compress_sun_bounce``, the baker's own
function), its manifest listing the new entries and files: a build where some lights keep a
refinement and some do not, for the tests of the bake (tests/bake/test_sun_bounce.py) and of
the client (tests/web/test_web_sun.py); and which of its images are ETC1S (:func:`is_etc1s`)."""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import replace
from pathlib import Path


def recompress_sun_bounce(build_dir: Path, copy: Path, budget: float,
                          second_level: int | None = None, shared=None,
                          encoding: str | None = None, sharing: str | None = None) -> Path:
    """Copy ``build_dir`` to ``copy`` and compress its atlases' and views' sun-bounce stacks
    again, judged with ``budget`` (and ``Settings.sun_bounce_level`` ``second_level``, by
    default the baker's), their lights grouped by ``shared`` (a
    ``bake.sunshare.SharedImages``; None: one image per light), with
    ``Settings.sun_bounce_encoding`` ``encoding`` and ``Settings.sun_bounce_sharing``
    ``sharing`` (defaults the baker's; the views' images plain UASTC, as the baker's:
    ``bake.sunbounce.view_settings``); returns ``copy``."""
    from bake.compresssettings import Settings
    from bake.evaluate import Build
    from bake.sunbounce import compress_sun_bounce, view_settings
    from bake.sundisplay import DisplaySkies
    from daylit.stackio import read_stack_exr

    shutil.copytree(build_dir, copy)
    for old in (copy / "ktx2").glob("*.sun_bounce.*"):
        old.unlink()
    build = Build(copy)
    manifest = build.manifest
    lights = build.selection.selectable
    skies = DisplaySkies.of_dome(build.dome_vertices, build.solid_angles, lights,
                                 manifest["scene"]["elevation_m"])
    settings = replace(Settings(), sun_bounce_budget=budget)
    if second_level is not None:
        settings = replace(settings, sun_bounce_level=second_level)
    if encoding is not None:
        settings = replace(settings, sun_bounce_encoding=encoding)
    if sharing is not None:
        settings = replace(settings, sun_bounce_sharing=sharing)
    for owners, owner_settings in ((manifest["atlases"], settings),
                                   (manifest["views"], view_settings(settings))):
        for owner in owners:
            for stack, entry in owner.get("sun_bounce", {}).items():
                result = compress_sun_bounce(
                    read_stack_exr(copy / entry["master"]),
                    f"{owner['id']}.sun_bounce.{stack}", copy, lights, owner_settings,
                    read_stack_exr(copy / owner["stacks"][stack]["master"]), skies, shared,
                )
                entry["compact"] = result.entry
    files = [f for f in manifest["files"] if ".sun_bounce." not in f["path"]
             or not f["path"].startswith("ktx2/")]
    for path in sorted((copy / "ktx2").glob("*.sun_bounce.*")):
        data = path.read_bytes()
        files.append({"path": path.relative_to(copy).as_posix(), "bytes": len(data),
                      "sha256": hashlib.sha256(data).hexdigest()})
    manifest["files"] = files
    (copy / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return copy


def is_etc1s(path: Path) -> bool:
    """Whether a KTX2 file holds ETC1S data: its header's supercompressionScheme (bytes
    44-47, little-endian) is 1, BasisLZ, which only ETC1S uses (KTX 2.0 specification,
    section 3.9; UASTC files are 0 or 2, Zstandard)."""
    header = path.read_bytes()[:48]
    return int.from_bytes(header[44:48], "little") == 1
