"""What a build's shared sun-bounce images cost and save (issue 15, item 8; docs/sun.md,
"Shared images"): its sun-bounce stacks compressed again from its EXR masters with the
baker's own code and default settings, its lights grouped as the baker groups them, into a
copy of the build; then, per stack, the images written, the patches taken out of their
groups, each sun-path patch's error as displayed against its *own* column (the bake's
``error.displayed.shared``), and the downloads (``bake/downloads.py``).

    PYTHONPATH=. python benchmarks/sun_bounce_groups.py BUILD COPY [--encoding E] [--json OUT]

Run it from two checkouts on the same build to compare their grouping (the copy is made
with the code on ``PYTHONPATH``). ``COPY`` must not exist; it hard-links nothing (a whole
copy: the EXR masters are read, the sun-bounce images rewritten).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measure(build_dir: Path, copy: Path, encoding: str | None = None) -> dict:
    """The copy made and measured: ``{"stacks": [...], "downloads": {...}, "seconds"}``;
    ``encoding``: ``compression.sun_bounce_encoding`` (None: the baker's default)."""
    from bake import downloads
    from bake.compresssettings import Settings
    from bake.evaluate import Build
    from bake.sunshare import SharedImages
    from tests.sunbounce_levels import recompress_sun_bounce

    build = Build(build_dir)
    dome = build.manifest["dome"]
    shared = SharedImages.of_dome(dome["kind"], dome["frequency"],
                                  build.selection.selectable, Settings().sun_bounce_lights)
    started = time.perf_counter()
    recompress_sun_bounce(build_dir, copy, Settings().sun_bounce_budget, shared=shared,
                          encoding=encoding)
    seconds = time.perf_counter() - started
    manifest = json.loads((copy / "manifest.json").read_text())
    stacks = []
    for owner in manifest["atlases"] + manifest["views"]:
        for stack, entry in owner.get("sun_bounce", {}).items():
            compact = entry["compact"]
            displayed = compact["error"].get("displayed", {})
            stacks.append({"stack": f"{owner['id']}.{stack}",
                           "shared": compact.get("shared"),
                           "image_error": {k: displayed.get(k)
                                           for k in ("max", "median", "texel_p99", "cheaper")},
                           "own_column_error": displayed.get("shared")})
    return {"stacks": stacks, "downloads": downloads.download_bytes(manifest, copy),
            "seconds": round(seconds, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("build", type=Path, help="a build with its EXR masters")
    ap.add_argument("copy", type=Path, help="where the recompressed copy goes (new)")
    ap.add_argument("--encoding", choices=("uastc", "smallest"),
                    help="compression.sun_bounce_encoding (default: the baker's)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    if args.copy.exists():
        sys.exit(f"{args.copy} exists: give a new folder for the copy")
    out = measure(args.build, args.copy, args.encoding)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    print(f"sun-bounce stacks compressed again in {out['seconds']} s")
    print(f"{'stack':<20}{'images':>7}{'split':>6}{'gains':>14}"
          f"{'own column: worst':>19}{'median':>8}{'over':>6}{'texel p99: worst':>18}"
          f"{'median':>8}")
    for s in out["stacks"]:
        shared, own = s["shared"] or {}, s["own_column_error"] or {}
        texel = own.get("texel_p99") or s["image_error"].get("texel_p99") or {}
        gains = shared.get("gains")
        gain_text = f"{gains[0]:.2f}-{gains[1]:.2f}" if gains else "-"
        print(f"{s['stack']:<20}{shared.get('images', '-'):>7}{shared.get('split_out', '-'):>6}"
              f"{gain_text:>14}{own.get('max', float('nan')):>19.3%}"
              f"{own.get('median', float('nan')):>8.3%}{own.get('over_budget', '-'):>6}"
              f"{texel.get('max', float('nan')):>18.2%}{texel.get('median', float('nan')):>8.2%}")
    d = out["downloads"]
    for key in ("phone", "phone_visit_with_sun_bounce", "sun_bounce_visit", "sun_bounce_day",
                "all"):
        print(f"{key:<30}{d[key]:>12,} bytes")


if __name__ == "__main__":
    main()
