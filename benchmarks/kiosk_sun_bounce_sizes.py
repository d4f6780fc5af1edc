"""What the fixed views' sun-bounce images (docs/sun.md, "The kiosk's sun bounce") add to a
build: to what the server offers and to what a kiosk downloads, beside the same build's other
figures (the baseline, from the same bake).

    python benchmarks/kiosk_sun_bounce_sizes.py BUILD [BUILD ...]

Prints, per build: every file a server offers (the compact files and the gzipped manifest,
``bake.downloads``), of which the atlases' and the views' sun-bounce images; the kiosk's
download to start and from sunrise to sunset (without the bounce), and the bounce images it
adds at sunrise's patch and over that day; bytes per sun-path light of the view's O and S.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def sizes(build_dir: Path) -> dict:
    from bake.downloads import download_bytes

    manifest = json.loads((build_dir / "manifest.json").read_text())
    got = download_bytes(manifest, build_dir)
    files = {f["path"]: f["bytes"] for f in manifest["files"]}

    def bounce_files(owners) -> int:
        total = 0
        for owner in owners:
            for entry in owner.get("sun_bounce", {}).values():
                table = entry["compact"]["lights"]
                for p, scale in enumerate(table["scale"]):
                    if scale is not None:
                        total += sum(files[t.format(index=p)] for t in table["ktx2"][:len(scale)])
        return total

    views = manifest["views"]
    lights = len(manifest["compression"]["selectable_lights"])
    per_light = {
        f"{v['id']}.{s}": round(
            sum(files[t.format(index=p)]
                for p, scale in enumerate(e["compact"]["lights"]["scale"]) if scale is not None
                for t in e["compact"]["lights"]["ktx2"][:len(scale)]) / max(lights, 1))
        for v in views for s, e in v.get("sun_bounce", {}).items()
    }
    return {
        "build": str(build_dir),
        "lights": manifest["dome"]["count"],
        "quality": manifest["bake"]["quality"],
        "views": [f"{v['id']} {v['width']}x{v['height']}" for v in views],
        "sun_path_lights": lights,
        "server_offers": got["all"],
        "atlases_sun_bounce": bounce_files(manifest["atlases"]),
        "views_sun_bounce": bounce_files(views),
        "kiosk_start": got["kiosk"],
        "kiosk_day": got["kiosk_day"],
        "kiosk_sun_bounce_start": got["kiosk_sun_bounce_start"],
        "kiosk_sun_bounce_day": got["kiosk_sun_bounce_day"],
        "day_sun_patches": got["day_sun_patches"],
        "view_bounce_bytes_per_light": per_light,
        "glb": files[manifest["model"]["path"]],
    }


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(json.dumps(sizes(Path(arg)), indent=1))
