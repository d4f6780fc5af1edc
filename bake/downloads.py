"""What a web client downloads from a build, as it downloads it (docs/web.md).

Per stack it relights, a client fetches the base (and gain) textures and ``V`` once, and the
own images of the lights it selects as they become selected (docs/compact-assets.md); the
sun moves one patch in tens of minutes, so the longer a visit, the more light images. The
sun's bounce is one light's images per sun-bounce stack, of the sun's patch (docs/sun.md,
item 5), counted apart; where neighbouring patches share one image (since 2026-12-06,
``lights.image``), that image is fetched once. The manifest and the GLB count as the server
sends them: gzipped (server/routes.py).
"""

from __future__ import annotations

import gzip
from pathlib import Path

# A visit to the site: two hours of clear sky in a spring morning (equinox, 10:00-12:00
# local time); the kiosk runs from sunrise to sunset that day. Every 10 minutes.
VISIT = ("2025-03-20 10:00", "2025-03-20 12:00")
KIOSK_DAY = ("2025-03-20 00:00", "2025-03-21 00:00")
STEP = "10min"


def visit_and_day(manifest: dict) -> tuple[tuple[str, str], tuple[str, str]]:
    """The visit and the kiosk's day the figures are for: :data:`VISIT` and
    :data:`KIOSK_DAY`, or in a build whose sun-bounce images are made for some dates
    (``compression.sun_bounce_dates``) the same hours on the first of them."""
    dates = manifest.get("compression", {}).get("sun_bounce_dates")
    if not dates:
        return VISIT, KIOSK_DAY
    import datetime as dt

    first = dt.date.fromisoformat(dates[0])
    visit = tuple(f"{first} {t.split(' ')[1]}" for t in VISIT)
    return visit, (f"{first} 00:00", f"{first + dt.timedelta(days=1)} 00:00")


def stack_selected_lights(manifest: dict, compact: dict) -> int:
    """How many lights a client takes from a stack's own images: its entry's
    ``selected_lights`` (absent in builds made before 2026-11-24: the build's)."""
    return int(compact.get("selected_lights", manifest["compression"]["selected_lights"]))


def lights_selected_over(manifest: dict, start: str, end: str, step: str = STEP,
                         m: int | None = None) -> list[int]:
    """Every light a client selects under a clear sky at the site between ``start`` and
    ``end`` (local times, sampled every ``step`` while the sun is up), sorted; ``m`` selected
    lights per vector (default: the build's ``selected_lights``). The sun is in its patch:
    the light vector of a version-1 client (since 2026-11-24 no stack of a build selects
    lights, so a build's own count is zero: see ``m``)."""
    import pandas as pd

    from daylit import sky as skies
    from daylit.manifest import dome_vertices
    from daylit.selection import Selection

    site = manifest["scene"]
    vertices = dome_vertices(manifest)
    selection = Selection.of_manifest(manifest)
    if m is not None:
        selection = Selection(selection.weights_sr, m)
    if selection.m == 0:
        return []
    times = pd.date_range(start, end, freq=step, tz=site["timezone"])
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
    )
    chosen: set[int] = set()
    for a, e in zip(az, el, strict=True):
        if e > 0.0:
            r = skies.patch_mean_radiance(skies.clear_sky(a, e), vertices, samples_per_side=6)
            chosen |= {int(i) for i in selection(r)}
    return sorted(chosen)


def sun_patches_over(manifest: dict, start: str, end: str, step: str = STEP) -> list[int]:
    """The dome patches the sun is in between ``start`` and ``end`` (local times, sampled
    every ``step`` while it is up), in the order it enters them: the sun-bounce columns a
    client fetches (docs/sun.md, item 5)."""
    import pandas as pd

    from daylit import sky as skies
    from daylit.manifest import dome_vertices
    from daylit.spherical import PatchLookup

    site = manifest["scene"]
    times = pd.date_range(start, end, freq=step, tz=site["timezone"])
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
    )
    up = el > 0.0
    if not up.any():
        return []
    patches = PatchLookup(dome_vertices(manifest))(
        skies.direction_from_azimuth_elevation(az[up], el[up])
    )
    return list(dict.fromkeys(int(p) for p in patches))


def sun_bounce_files(manifest: dict, atlases: list[dict], patches: list[int]) -> set[str]:
    """The sun-bounce files a client fetches for the sun in each of ``patches``: of every
    sun-bounce stack of ``atlases`` (atlas or view entries), the files of the light that
    holds patch ``p``'s image (``lights.image[p]``; absent: ``p`` itself), each level ``p``
    has (``len(scale[p])``). A set: an image shared by several patches is fetched once."""
    files: set[str] = set()
    for atlas in atlases:
        for stack in atlas.get("sun_bounce", {}).values():
            files |= table_files(stack["compact"]["lights"], patches)
    return files


def table_files(table: dict, patches) -> set[str]:
    """The files of a sun-bounce ``lights`` table that the sun in ``patches`` reads: for
    each patch with images, the levels it has (``len(scale[p])``) at the light that holds
    its image (:func:`bake.compact_reader.image_holders`)."""
    from bake.compact_reader import image_holders

    holders = image_holders(table)
    return {pattern.format(index=holders[p])
            for p in patches if table["scale"][p] is not None
            for pattern in table["ktx2"][: len(table["scale"][p])]}


def sun_bounce_bytes(manifest: dict, atlases: list[dict], patches: list[int]) -> int:
    """Bytes of the sun-bounce images a client fetches for the sun in each of ``patches``
    (:func:`sun_bounce_files`)."""
    sizes = {f["path"]: f["bytes"] for f in manifest["files"]}
    return sum(sizes[f] for f in sun_bounce_files(manifest, atlases, patches))


def sent_bytes(build_dir: Path, path: str, listed: int) -> int:
    """Bytes the server sends for a gzip-compressed file (the manifest, the GLB: JSON and GLB
    at gzip level 6, server/routes.py); ``listed`` (its size) when it is not on disk."""
    file = Path(build_dir) / path
    if not file.is_file():
        return listed
    return len(gzip.compress(file.read_bytes(), 6, mtime=0))


def download_bytes(manifest: dict, build_dir: Path, visit_lights: int | None = None,
                   day_lights: int | None = None, visit_sun: list[int] | None = None,
                   day_sun: list[int] | None = None) -> dict:
    """Bytes a client fetches, by kind of client:

    - ``phone``: the manifest, the GLB (both gzipped, as the server sends them), the
      ground/wall and lightmap atlases (the default shading) with the images of each
      stack's selected lights (:func:`stack_selected_lights`, at their average size; none
      since 2026-11-24);
    - ``phone_visit``: the same over a two-hour visit (:data:`VISIT`, or those hours of
      the first date a build's sun-bounce images are made for: :func:`visit_and_day`): the
      images of every
      light selected meanwhile (``visit_lights`` of them per stack that selects any;
      computed if not given);
    - ``phone_hull``: ``phone`` plus the hull planes, fetched when hull-plane mode is chosen;
    - ``kiosk``: the manifest, the GLB (its sun's shadows) and the fixed views;
    - ``kiosk_day``: the kiosk from sunrise to sunset (:data:`KIOSK_DAY`, ``day_lights``
      per view stack that selects lights);
    - ``all``: every compact file (GLB, KTX2, V) and the manifest: what a server offers;
    - the sun's bounce, apart (not in the figures above): ``sun_bounce_start`` the images of
      the sun's patch at the visit's start, per sun-bounce stack of the default atlases
      (lightmap ``I``, ground ``I`` and ``d``); ``sun_bounce_visit`` those of every patch the
      sun is in over the visit (``visit_sun``: the patches, computed if not given);
      ``sun_bounce_day`` from sunrise to sunset (``day_sun``); ``sun_bounce_hull_visit`` what
      hull-plane mode adds over the visit. Zero for a build without sun-bounce stacks.
      ``visit_sun_images``: how many images per stack that is (fewer than the patches where
      neighbouring patches share one); ``phone_visit_with_sun_bounce``: ``phone_visit`` plus
      ``sun_bounce_visit``, the figure issue 15's 4 MB is about.
      ``kiosk_sun_bounce_start`` and ``kiosk_sun_bounce_day``: the same for the kiosk (the
      fixed views' ``O`` and ``S``, at sunrise's patch and from sunrise to sunset); zero for
      a build made before 2026-11-25.

    Also ``visit_lights``, ``day_lights``, ``visit_sun_patches`` and ``day_sun_patches``,
    the counts used."""
    sizes = {f["path"]: f["bytes"] for f in manifest["files"]}
    # The server sends JSON gzipped at level 6 (server/routes.py), the binaries as they are.
    manifest_bytes = len(gzip.compress((Path(build_dir) / "manifest.json").read_bytes(), 6))
    glb = sent_bytes(build_dir, manifest["model"]["path"], sizes[manifest["model"]["path"]])
    per_light = {row["stack"]: row["light_bytes_per_light"]
                 for row in manifest["compression"]["report"]}
    hull = [a for a in manifest["atlases"] if a["id"] == "hull"]
    default = [a for a in manifest["atlases"] if a["id"] != "hull"]

    def selecting(owners) -> int:
        """The largest number of selected lights among these owners' stacks."""
        return max((stack_selected_lights(manifest, s["compact"])
                    for o in owners for s in o["stacks"].values()), default=0)

    visit, day = visit_and_day(manifest)
    if visit_lights is None:
        m = selecting(default)
        visit_lights = len(lights_selected_over(manifest, *visit, m=m)) if m else 0
    if day_lights is None:
        m = selecting(manifest["views"])
        day_lights = len(lights_selected_over(manifest, *day, m=m)) if m else 0

    def owner_bytes(owners, lights: int | None) -> float:
        """The owners' base files, and per stack the images of ``lights`` lights (None:
        its selected lights; none for a stack that selects none)."""
        files, light_bytes = set(), 0.0  # a pair's shared gain texture counts once
        for owner in owners:
            for name, stack in owner["stacks"].items():
                compact = stack["compact"]
                files |= {compact["ktx2"], compact["v"]["path"]}
                if "etc1s" in compact:  # base layers past the first few, ETC1S
                    files.add(compact["etc1s"]["ktx2"])
                if compact.get("gain"):
                    files.add(compact["gain"]["ktx2"])
                m = stack_selected_lights(manifest, compact)
                count = m if lights is None else (lights if m else 0)
                light_bytes += count * per_light[f"{owner['id']}.{name}"]
        return sum(sizes[f] for f in files) + light_bytes

    phone = manifest_bytes + glb + owner_bytes(default, None)
    compact = sum(
        f["bytes"] for f in manifest["files"]
        if f["path"].startswith(("ktx2/", "v/")) or f["path"] == manifest["model"]["path"]
    )
    if any("sun_bounce" in o for o in manifest["atlases"] + manifest["views"]):
        if visit_sun is None:
            visit_sun = sun_patches_over(manifest, *visit)
        if day_sun is None:
            day_sun = sun_patches_over(manifest, *day)
    visit_sun, day_sun = visit_sun or [], day_sun or []
    visit_images = max((len(_holders(stack["compact"]["lights"], visit_sun))
                        for o in default for stack in o.get("sun_bounce", {}).values()),
                       default=0)
    phone_visit = round(manifest_bytes + glb + owner_bytes(default, visit_lights))
    sun_bounce_visit = sun_bounce_bytes(manifest, default, visit_sun)
    return {
        "phone": round(phone),
        "phone_visit": phone_visit,
        "phone_visit_with_sun_bounce": phone_visit + sun_bounce_visit,
        "phone_hull": round(phone + owner_bytes(hull, None)),
        "kiosk": round(manifest_bytes + glb + owner_bytes(manifest["views"], None)),
        "kiosk_day": round(manifest_bytes + glb + owner_bytes(manifest["views"], day_lights)),
        "all": compact + manifest_bytes,
        "visit_lights": visit_lights,
        "day_lights": day_lights,
        "sun_bounce_start": sun_bounce_bytes(manifest, default, visit_sun[:1]),
        "sun_bounce_visit": sun_bounce_visit,
        "sun_bounce_day": sun_bounce_bytes(manifest, default, day_sun),
        "sun_bounce_hull_visit": sun_bounce_bytes(manifest, hull, visit_sun),
        "kiosk_sun_bounce_start": sun_bounce_bytes(manifest, manifest["views"], day_sun[:1]),
        "kiosk_sun_bounce_day": sun_bounce_bytes(manifest, manifest["views"], day_sun),
        "visit_sun_patches": len(visit_sun),
        "visit_sun_images": visit_images,
        "day_sun_patches": len(day_sun),
    }


def _holders(table: dict, patches: list[int]) -> set[int]:
    """The lights whose files hold the images of ``patches`` in a sun-bounce ``lights``
    table (:func:`bake.compact_reader.image_holders`), for the patches that have one."""
    from bake.compact_reader import image_holders

    holders = image_holders(table)
    return {holders[p] for p in patches if table["scale"][p] is not None}
