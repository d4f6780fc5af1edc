"""The bake's compression orchestration: prepares the site's test skies, prior and light
selection once, runs bake.compress (and bake.sunbounce) on each stack as the write stage
assembles it (from two threads), here or on a Dask cluster's workers (bake.compressjobs), and
keeps and prints the compression report.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bake import (
    basisu,
    compress,
    compressjobs,
    stackkinds,
    sunbounce,
    sundates,
    sundisplay,
    sunshare,
    testskies,
)
from bake.dome import Dome
from bake.downloads import download_bytes
from bake.errors import BakeError
from bake.rowstore import as_stack
from bake.scene import Site

SELECTION_RULE = (
    "top selected_lights of the selectable_lights (every light when absent) by "
    "max(r_i.R, r_i.G, r_i.B) * solid_angle_sr_i, ties to the lower index, zero scores never"
)


class Compressor:
    """Runs ``bake.compress`` on each stack as it is assembled and keeps the report. With a
    ``cluster`` (:class:`bake.cluster.Cluster`) the stacks are compressed on its workers
    (bake.compressjobs), which return the files' bytes; they are written into the staging
    folder here, the same bytes as a local bake's."""

    def __init__(self, site: Site, log, cluster=None, sun_bounce_dates=None):
        self.cluster = cluster
        # bake.sundates.SunBounceDates: only the patches the sun crosses then get sun-bounce
        # images (None: every sun-path patch).
        self.sun_bounce_dates = sun_bounce_dates
        c = site.settings.compression
        self.settings = compress.Settings(
            budget=c["budget"],
            max_rank=c["max_rank"],
            encoding=c["encoding"],
            selected_lights=c["selected_lights"],
            sun_bounce_budget=c["sun_bounce_budget"],
            sun_bounce_lights=c["sun_bounce_lights"] or None,  # 0: one image per patch
            sun_bounce_encoding=c["sun_bounce_encoding"],
            sun_bounce_sharing=c["sun_bounce_sharing"],
        )
        self.display_skies = None  # set by start()
        self.log = log
        self.rows: dict[str, dict] = {}  # stack name -> report row (written from two threads)
        self.stack_names: list[str] = []
        self.bar = None
        if cluster is None:  # fail before baking, not after, when the encoder is missing
            basisu.basisu_binary()  # (a cluster's workers are checked as it is reached)

    def start(self, site: Site, dome: Dome, stack_names: list[str], progress: bool) -> None:
        """Prepare the test skies, prior and light selection; show a progress bar over the
        stacks ``stack_names`` (``<atlas or view>.<stack>``, the report's order)."""
        self.stack_names = list(stack_names)
        scene = {
            "timezone": site.timezone,
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "elevation_m": site.elevation_m,
        }
        # The lights the sun can be in (and the brightest patches of the site's skies with
        # the sun in its patch): the sun-bounce stacks have columns for them.
        selectable = testskies.sun_path_selectable(scene, dome.vertices, dome.solid_angles_sr)
        # Every stack, the fixed views' too, is relit with the sky without the sun's disc
        # (protocol version 2; the kiosk draws the sun itself: web/src/kiosksun.js).
        self.skies, self.S, self.S_inv, self.selection = compress.prepare(
            scene, dome.vertices, dome.solid_angles_sr, self.settings.selected_lights,
            selectable=selectable, sun_in_patch=False,
        )
        # The clear skies each sun-bounce image is judged under as displayed.
        self.display_skies = sundisplay.DisplaySkies.of_dome(
            dome.vertices, dome.solid_angles_sr, self.selection.selectable, site.elevation_m
        )
        # Neighbouring sun-path patches sharing one sun-bounce image (docs/sun.md, "Shared
        # images"); None: one image per patch.
        self.shared = sunshare.SharedImages.of_dome(
            dome.kind, dome.frequency, self.selection.selectable,
            self.settings.sun_bounce_lights,
        )
        # The lights the sun-bounce stacks get images for: every sun-path light, or those of
        # the dates asked for (with their groups' other members).
        self.lights_with_sun_images = self.selection.selectable
        self.dates_patches = None  # with dates: the patches the sun crosses on them
        if self.sun_bounce_dates is not None:
            patches = self.sun_bounce_dates.patches(site, dome.vertices)
            self.lights_with_sun_images = sundates.lights_for_dates(
                self.selection.selectable, patches, self.shared)
            self.dates_patches = set(patches)
            first, last = self.sun_bounce_dates.as_list()
            crossed = self.dates_patches & set(self.selection.selectable.tolist())
            self.log(f"  the sun's bounce from {first} to {last}: the {len(crossed)} patches "
                     f"the sun crosses then get images ({len(self.lights_with_sun_images)} "
                     f"of the {len(self.selection.selectable)} sun-path lights judged, with "
                     "their sharing groups)")
        self.log(
            f"  {len(self.selection.selectable)} of {dome.count} lights can be selected "
            "(the sun's path and the brightest patches of the site's skies): only they get "
            "their own images, in the sun's bounce and the stacks that select lights"
        )
        self.bar = tqdm(
            total=len(self.stack_names),
            unit="stack",
            disable=not progress,
            desc="writing",
            file=sys.stderr,
            dynamic_ncols=True,
        )

    def run(self, images: dict, prefix: str, staging: Path) -> dict:
        """Compress the stacks ``images`` ({name: (H, W, n, 3) or a
        :class:`bake.rowstore.StackStore`}) of one atlas or fixed view;
        ``I`` and ``d`` together (shadow ratio). Returns {name: compact manifest entry}. Safe
        to call from several threads at once (each with its own stacks)."""
        try:
            if self.cluster is None:
                results = stackkinds.compress_stacks(
                    images, prefix, staging, self.skies, self.S, self.S_inv, self.selection,
                    self.settings,
                )
            else:
                # A worker gets the stacks whole (it has no access to this machine's disk).
                images = {name: as_stack(images.pop(name)).array() for name in sorted(images)}
                results, files = self.cluster.compress(
                    compressjobs.compress_stacks_job, images, prefix, self.skies, self.S,
                    self.S_inv, self.selection, self.settings, label=f"{prefix}'s stacks",
                )
                compressjobs.write_files(staging, files)
                for _, result in results:
                    result.files = [staging / p for p in result.files]
        except basisu.CompressionError as exc:
            raise BakeError(str(exc)) from None
        self.bar.update(len(results))  # tqdm locks its own updates
        out = {}
        stored = max(len(self.selection.selectable), 1)
        for name, result in results:
            # One key per stack: dict assignment is atomic under the GIL.
            self.rows[f"{prefix}.{name}"] = {
                "stack": f"{prefix}.{name}",
                "k": result.entry["k"],
                "error": result.entry["error"]["max"],
                "base_bytes": result.base_bytes,
                "light_bytes": result.light_bytes,
                "light_bytes_per_light": round(result.light_bytes / stored),
                "encode_s": round(result.encode_s, 2),
            }
            out[name] = result.entry
        return out

    def run_sun_bounce(
        self, image: np.ndarray, name: str, staging: Path, master: str | None = None,
        sky: np.ndarray | None = None, view: bool = False,
    ) -> dict | None:
        """Compress one sun-bounce stack ``name`` (``<atlas or view>.sun_bounce.<stack>``)
        into one image per light the sun can be in, each refined only where its coarse image
        shows against its sky stack ``sky`` (H, W, n, 3; None: every one refined)
        (:func:`bake.sunbounce.compress_sun_bounce`); its compact entry, or None when it is
        zero everywhere (then the master, ``master`` relative to ``staging``, by default
        ``exr/<name>.exr``, is dropped too). A fixed ``view``'s images are plain UASTC
        (:func:`bake.sunbounce.view_settings`)."""
        skies = self.display_skies if sky is not None else None
        settings = sunbounce.view_settings(self.settings) if view else self.settings
        try:
            if self.cluster is None:
                result = sunbounce.compress_sun_bounce(
                    image, name, staging, self.lights_with_sun_images, settings, sky, skies,
                    self.shared,
                )
            else:
                image = as_stack(image).array()
                sky = None if sky is None else as_stack(sky).array()
                result, files = self.cluster.compress(
                    compressjobs.sun_bounce_job, image, name, self.lights_with_sun_images,
                    settings, sky, skies, self.shared,
                    label=f"the sun-bounce stack {name}",
                )
                compressjobs.write_files(staging, files)
                if result is not None:
                    result.files = [staging / p for p in result.files]
        except basisu.CompressionError as exc:
            raise BakeError(str(exc)) from None
        self.bar.update(1)
        if result is None:
            (staging / (master or f"exr/{name}.exr")).unlink(missing_ok=True)
            return None
        images = result.entry["error"]["test_lights"]  # judged: one per image
        if self.dates_patches is not None:
            images = sundates.keep_patches(result, self.dates_patches, staging)
        error = result.entry["error"]
        self.rows[name] = {
            "stack": name,
            "k": result.entry["k"],
            # As displayed where judged so (the budget's measure), else against the column.
            "error": error.get("displayed", error)["max"],
            "base_bytes": 0,
            "light_bytes": result.light_bytes,
            "light_bytes_per_light": round(result.light_bytes / max(images, 1)),
            "encode_s": round(result.encode_s, 2),
        }
        return result.entry

    def close(self) -> None:
        self.bar.close()

    def manifest_entry(self) -> dict:
        return {
            "budget": self.settings.budget,
            "encoding": self.settings.encoding,
            "selected_lights": self.settings.selected_lights,
            "selectable_lights": self.selection.selectable.tolist(),
            "sun_bounce_dates": (None if self.sun_bounce_dates is None
                                 else self.sun_bounce_dates.as_list()),
            "selection": SELECTION_RULE,
            "test_skies": [s.name for s in self.skies],
            "report": self.report(),
        }

    def rename_rows(self, names: dict[str, str]) -> None:
        """Report the stacks ``names`` (``{name: new name}``) under their new names (a build's
        sun-bounce stacks made again under dated file names: bake.sunremake)."""
        for old_name, new_name in names.items():
            if old_name in self.rows:
                self.rows[new_name] = {**self.rows.pop(old_name), "stack": new_name}
        self.stack_names = [names.get(name, name) for name in self.stack_names]

    def report(self) -> list[dict]:
        """The report rows in the order of the stacks given to :meth:`start`."""
        return [self.rows[name] for name in self.stack_names if name in self.rows]

    def print_report(self, manifest: dict, staging: Path) -> None:
        budget = self.settings.budget
        self.log(
            f"compact assets ({self.settings.encoding}, budget {budget:.2%} RMS of the "
            f"mean, {self.settings.selected_lights} selected "
            f"light{'' if self.settings.selected_lights == 1 else 's'}):"
        )
        self.log(f"  {'stack':<22}{'k':>4}{'error':>9}{'base':>10}{'lights':>12}{'per light':>11}")
        for row in self.report():
            flag = "" if row["error"] <= budget else "  over budget"
            self.log(
                f"  {row['stack']:<22}{row['k']:>4}{row['error']:>9.2%}"
                f"{row['base_bytes'] / 1e6:>8.2f}MB{row['light_bytes'] / 1e6:>10.2f}MB"
                f"{row['light_bytes_per_light'] / 1e3:>9.1f}kB{flag}"
            )
        for atlas in manifest["atlases"]:
            ratio = atlas["stacks"].get("I", {}).get("compact", {}).get("error", {}).get("ratio")
            if ratio:  # a shadowing pair's ratio as decoded (bake.stackkinds), not enforced
                self.log(ratio_line(atlas, ratio, len(self.skies)))
        sizes = download_bytes(manifest, staging)

        def mb(key: str) -> str:
            return f"{sizes[key] / 1e6:.1f} MB"

        self.log(
            f"  a visitor's phone downloads {mb('phone')} to start, {mb('phone_visit')} over a "
            f"two-hour visit under a clear sky ({sizes['visit_lights']} lights' images per "
            f"stack{'' if sizes['visit_lights'] else ': none, the sky is relit without the sun'}"
            f"); hull-plane mode adds {(sizes['phone_hull'] - sizes['phone']) / 1e6:.1f} MB"
        )
        if manifest["views"]:
            self.log(
                f"  the kiosk downloads {mb('kiosk')} to start, {mb('kiosk_day')} from sunrise "
                f"to sunset ({sizes['day_lights']} lights)"
            )
        self.log(f"  all compact files (what the server offers): {mb('all')}")
        sun_rows = [row for row in self.report() if ".sun_bounce." in row["stack"]]
        if sun_rows:
            # The default shading's atlases (not the hull's, nor the fixed views': the kiosk's)
            shown = {f"{a['id']}." for a in manifest["atlases"] if a["id"] != "hull"}
            default = [r for r in sun_rows if r["stack"].startswith(tuple(shown))]
            per_light = sum(r["light_bytes_per_light"] for r in default)
            total = sum(r["light_bytes"] for r in sun_rows)
            masters = sum(
                e["bytes"] for e in manifest["files"] if ".sun_bounce." in e["path"]
                and e["path"].startswith("exr/")
            )
            dates = manifest["compression"].get("sun_bounce_dates")
            when = f" (on {dates[0]}, the first of its dates)" if dates else ""
            self.log(
                f"  the sun's bounce: one light's images per stack, fetched for the sun's "
                f"patch: {per_light / 1e3:.0f} kB per patch without the hull, "
                f"{mb('sun_bounce_visit')} over the visit{when} ({sizes['visit_sun_patches']} "
                f"patches, {sizes['visit_sun_images']} images per stack), "
                f"{mb('sun_bounce_day')} over a day ({sizes['day_sun_patches']}); "
                f"hull-plane mode adds {mb('sun_bounce_hull_visit')} over the visit; a phone "
                f"over the visit with it: {sizes['phone_visit_with_sun_bounce'] / 1e6:.2f} MB"
            )
            self.log(
                f"  the sun's bounce on the server: {total / 1e6:.2f} MB of light images, "
                f"{masters / 1e6:.1f} MB of EXR masters"
            )
            for unit in [*manifest["atlases"], *manifest.get("views", [])]:
                for stack, entry in (unit.get("sun_bounce") or {}).items():
                    shared = entry["compact"]["error"].get("displayed", {}).get("shared")
                    if shared:
                        self.log(shared_line(f"{unit['id']}.sun_bounce.{stack}", shared))


def ratio_line(atlas: dict, ratio: dict, skies: int) -> str:
    """The bake's line on a shadowing atlas's shadow ratio as decoded (``ratio``, the
    ``error.ratio`` of its ``I`` entry: bake.stackkinds.RatioError). The 0.02 per texel is
    the real ground's bound (a virtual shadow on real video); the hull planes are the virtual
    objects' own surfaces (``d_reference`` "unoccluded"), judged by RMS as the lightmap is,
    so their line says which share of the checks is over it rather than sounding an alarm
    (docs/compact-assets.md, "The shadow ratio as decoded")."""
    checked = ratio.get("checked")
    share = (f" ({ratio['texels_over'] / checked:.2%} of {checked} texel checks)"
             if checked else "")
    line = (f"  {atlas['id']} shadow ratio as decoded: worst texel {ratio['max']:.4f} "
            f"({ratio['sky']}); over 0.02 on {ratio['skies_over']} of {skies} test skies, "
            f"{ratio['texels_over']} texels in all{share}")
    if atlas.get("d_reference") == "unoccluded":
        line += ("; these are the virtual objects' own surfaces (hull-plane mode), whose "
                 "shading is judged by RMS as the lightmap's: the 0.02 bound is the real "
                 "ground's")
    return line


def shared_line(stack: str, shared: dict) -> str:
    """The bake's line on what sharing sun-bounce images costs as displayed (``shared``:
    bake.sunwritten.ReadBack.shared_record), each sun-path patch against its own column: the images
    themselves are judged against their group's (docs/sun.md, "Shared images")."""
    over = (f", {shared['over_budget']} of {shared['lights']} patches over the budget"
            if "over_budget" in shared else "")
    return (f"  {stack}: each sun-path patch with its group's image and its own gain, as "
            f"displayed against "
            f"its own column: worst {shared['max']:.2%} (light {shared['worst_light']}), "
            f"median {shared['median']:.2%}{over}")
