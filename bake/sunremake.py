"""``daylit sun-bounce``: a build's sun-bounce images made again, from its EXR masters, for
other dates (bake/sundates.py; docs/sun.md, "The sun's bounce for the dates served").

A bake made with ``--sun-bounce-dates`` (or for the whole year) keeps every sun-path column
in its sun-bounce masters, so the images for the next weeks can be made from them without
tracing again: each sun-bounce stack is compressed and judged as the bake does it
(:meth:`bake.compressor.Compressor.run_sun_bounce`), under the scene's own compression
settings. The new files get names of their own (``<stack>.<first>_<last>.L<i>.ktx2``), so
the old manifest and its files stay whole until the new manifest replaces it in one rename;
the old images are deleted after. A running server offers the files of the manifest it
started with: restart it.
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

from bake.blasthreads import one_blas_thread
from bake.buildmanifest import save_manifest
from bake.compressor import Compressor
from bake.dome import Dome
from bake.errors import BakeError
from bake.scene import load_site
from bake.sundates import SunBounceDates, check_sun_up, image_files
from daylit import manifest as manifest_io
from daylit.stackio import read_stack_exr


def sun_bounce_stacks(manifest: dict) -> list[tuple[dict, str, bool]]:
    """``(owner entry, stack, is a fixed view)`` of every sun-bounce stack of a build, in the
    bake's order (the atlases', then the views')."""
    return [(owner, stack, view)
            for owners, view in ((manifest["atlases"], False), (manifest["views"], True))
            for owner in owners for stack in owner.get("sun_bounce", {})]


def remake_sun_bounce(scene_dir, build_dir, dates: SunBounceDates, progress: bool = True,
                      log=None) -> dict:
    """Make the sun-bounce images of the build in ``build_dir`` again for ``dates``, from its
    masters and the site description in ``scene_dir`` (the one it was baked from), and
    replace the old ones. Returns the new manifest. Raises ``BakeError`` (or ``SceneError``,
    ``ManifestError``) with what to do; then the build is as it was."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    started = time.perf_counter()
    build_dir = Path(build_dir).absolute()
    manifest = manifest_io.load(build_dir)
    stacks = sun_bounce_stacks(manifest)
    if not stacks:
        raise BakeError(f"{build_dir} has no sun-bounce stacks: nothing to make")
    compression = manifest["compression"]
    site = load_site(scene_dir, lights=manifest["dome"]["count"], budget=compression["budget"])
    if site.scene_id != manifest["scene"]["id"]:
        raise BakeError(f"{build_dir} was baked from the site {manifest['scene']['id']!r}, "
                        f"not {site.scene_id!r}: give the scene it was baked from")
    dome = Dome.for_light_count(site.settings.lights)
    if (dome.kind, dome.frequency) != (manifest["dome"]["kind"], manifest["dome"]["frequency"]):
        raise BakeError(f"{build_dir}'s dome is not this scene's: give the scene it was baked "
                        "from")
    check_sun_up(site, dates)
    tag = _free_tag(manifest, "_".join(dates.as_list()))
    # The stacks' names as their new files are named (the report's rows too, until written).
    names = [f"{owner['id']}.sun_bounce.{stack}.{tag}" for owner, stack, _ in stacks]
    compressor = Compressor(site, log, None, dates)
    staging = build_dir.parent / f".{build_dir.name}.sun-bounce.partial"
    if staging.exists():
        shutil.rmtree(staging)
    (staging / "ktx2").mkdir(parents=True)
    try:
        with one_blas_thread():
            compressor.start(site, dome, names, progress=progress)
            if compressor.selection.selectable.tolist() != compression["selectable_lights"]:
                raise BakeError(f"{build_dir}'s sun-path lights are not this scene's: give "
                                "the scene it was baked from, or bake it again")
            made = {}
            for (owner, stack, view), name in zip(stacks, names, strict=True):
                entry = owner["sun_bounce"][stack]
                image = read_stack_exr(build_dir / entry["master"])
                sky_master = owner["stacks"].get(stack, {}).get("master")
                sky = read_stack_exr(build_dir / sky_master) if sky_master else None
                made[name] = compressor.run_sun_bounce(image, name, staging, sky=sky,
                                                       view=view)
                del image, sky
        compressor.close()
        # Reported (and written into the manifest's report) under the stacks' own names.
        compressor.rename_rows({name: name.removesuffix(f".{tag}") for name in names})
        manifest = _replace(build_dir, manifest, stacks, names, made, staging, compressor,
                            dates)
        compressor.print_report(manifest, build_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    first, last = dates.as_list()
    log(f"the sun's bounce from {first} to {last} made in {time.perf_counter() - started:.0f} "
        "s. Restart the server (daylit serve) to offer it.")
    return manifest


def _replace(build_dir: Path, manifest: dict, stacks, names, made: dict, staging: Path,
             compressor: Compressor, dates: SunBounceDates) -> dict:
    """Move the new images into the build, write the manifest that lists them (one rename),
    then delete the old ones."""
    old_files = set()
    for (owner, stack, _), name in zip(stacks, names, strict=True):
        compact = owner["sun_bounce"][stack]["compact"]
        old_files |= image_files(compact)
        if made[name] is None:  # (never: the masters hold the sun's path; refused above)
            raise BakeError(f"{name}: no image for {dates.as_list()}")
        owner["sun_bounce"][stack]["compact"] = made[name]
    new_files = set()
    for (owner, stack, _) in stacks:
        new_files |= image_files(owner["sun_bounce"][stack]["compact"])
    for path in sorted(new_files):
        (build_dir / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.move(staging / path, build_dir / path)
    kept = [f for f in manifest["files"] if f["path"] not in old_files]
    manifest["files"] = sorted(kept + [manifest_io.file_entry(build_dir, build_dir / p)
                                       for p in new_files], key=lambda f: f["path"])
    compression = manifest["compression"]
    compression["sun_bounce_dates"] = dates.as_list()
    rows = {row["stack"]: row for row in compressor.report()}
    compression["report"] = [rows.get(row["stack"], row) for row in compression["report"]]
    save_manifest(build_dir, manifest)
    for path in sorted(old_files - new_files):
        (build_dir / path).unlink(missing_ok=True)
    return manifest


def _free_tag(manifest: dict, tag: str) -> str:
    """``tag``, or ``tag-2``, ``tag-3``...: the first no listed file's name holds."""
    paths = [f["path"] for f in manifest["files"]]
    candidate, count = tag, 1
    while any(f".{candidate}." in p for p in paths):
        count += 1
        candidate = f"{tag}-{count}"
    return candidate
