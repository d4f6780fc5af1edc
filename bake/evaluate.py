"""Evaluating a build: irradiance at a point under a sky, from the baked basis.

This is what ``daylit probe`` prints, what the tests compare with physics, and what the
benchmarks use. Given a world point on a receiver and its normal, it finds the receiver
(a hull or ground/wall plane, else a lightmap surface), interpolates the basis stacks
bilinearly at that texel and takes the weighted sum with the sky's light vector:

    E(x) = sum_i r_i B_i(x)      (per RGB channel)

For shadowing planes it returns the irradiance with (``I``) and without (``d``) the virtual
objects; for a lightmap surface only ``I`` exists.

Every answer can come from the EXR masters (``source="master"``) or from the compact GPU
textures (``source="compact"``: low-rank base and selected lights' images, decoded with the
browser's Basis transcoder, exactly as the client sums them), so the two can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daylit import manifest as manifest_io
from daylit import sky as skies
from daylit.stackio import read_stack_exr

PLANE_TOLERANCE_M = 0.05
ATLAS_ORDER = ("ground", "hull", "lightmap")  # where Build.locate looks, in this order


class ProbeError(ValueError):
    """The point is not on any receiver, or the sky cannot be understood."""


@dataclass
class Sample:
    """Where a point landed: atlas, receiver name and continuous texel coordinates."""

    atlas: str
    receiver: str
    kind: str
    x: float  # texel coordinates: texel centres at integer + 0.5
    y: float
    distance_m: float


def parse_sky(spec: str) -> skies.Sky:
    """A named sky: ``uniform[:L]``, ``overcast[:Lz]`` or ``clear:AZIMUTH_DEG,ELEVATION_DEG``."""
    name, _, args = spec.partition(":")
    try:
        values = [float(v) for v in args.split(",")] if args else []
    except ValueError:
        raise ProbeError(f"sky {spec!r}: arguments must be numbers") from None
    if name == "uniform" and len(values) <= 1:
        L = values[0] if values else 1.0
        return skies.UniformSky(L=(L, L, L))
    if name == "overcast" and len(values) <= 1:
        return skies.overcast_sky(values[0] if values else 30.0)
    if name == "clear" and len(values) == 2:
        if not -5.0 <= values[1] <= 90.0:
            raise ProbeError(f"sky {spec!r}: sun elevation must be within [-5, 90] degrees")
        return skies.clear_sky(values[0], values[1])
    raise ProbeError(
        f"unknown sky {spec!r}: use uniform[:L], overcast[:Lz] or clear:AZIMUTH_DEG,ELEVATION_DEG"
    )


class Build:
    """A baked site, read from its directory. Stacks are loaded on first use and kept."""

    def __init__(self, build_dir: Path | str):
        self.dir = Path(build_dir)
        self.manifest = manifest_io.load(self.dir)
        self.dome_vertices = manifest_io.dome_vertices(self.manifest)
        self.atlases = {a["id"]: a for a in self.manifest["atlases"]}
        self._stacks: dict = {}
        self._compact: dict = {}
        self._surfaces = None
        self._sun_casters = None
        self._composites: dict = {}
        self.solid_angles = np.array(
            [light["solid_angle_sr"] for light in self.manifest["dome"]["lights"]]
        )
        from daylit.selection import Selection

        # Which lights the compact data takes from their own images, as the client selects.
        self.selection = Selection.of_manifest(self.manifest)

    @property
    def light_count(self) -> int:
        return self.manifest["dome"]["count"]

    def _entry(self, atlas: str) -> dict:
        return self.atlases.get(atlas) or {v["id"]: v for v in self.manifest["views"]}[atlas]

    def stack(self, atlas: str, name: str) -> np.ndarray:
        """The master stack (H, W, n, 3) of an atlas (or view) ``atlas``."""
        key = (atlas, name)
        if key not in self._stacks:
            self._stacks[key] = read_stack_exr(
                self.dir / self._entry(atlas)["stacks"][name]["master"]
            )
        return self._stacks[key]

    def sun_bounce_stack(self, atlas: str, name: str) -> np.ndarray:
        """The master sun-bounce stack (H, W, n, 3) of an atlas (``atlas["sun_bounce"]``)."""
        key = (atlas, "sun_bounce", name)
        if key not in self._stacks:
            self._stacks[key] = read_stack_exr(
                self.dir / self.atlases[atlas]["sun_bounce"][name]["master"]
            )
        return self._stacks[key]

    def sun_bounce_compact(self, atlas: str, name: str):
        """The compact reader of a sun-bounce stack (one image per light, no base)."""
        from bake.compact_reader import CompactReader

        key = (atlas, "sun_bounce", name)
        if key not in self._compact:
            entry = self.atlases[atlas]
            self._compact[key] = CompactReader(
                self.dir, entry["sun_bounce"][name]["compact"], (entry["height"], entry["width"])
            )
        return self._compact[key]

    def compact(self, atlas: str, name: str):
        """The compact reader of a stack (see ``bake.compact_reader.CompactReader``)."""
        from bake.compact_reader import CompactReader

        key = (atlas, name)
        if key not in self._compact:
            entry = self._entry(atlas)
            if "compact" not in entry["stacks"][name]:
                raise ProbeError(f"{self.dir}: stack {atlas}.{name} has no compact textures")
            self._compact[key] = CompactReader(
                self.dir, entry["stacks"][name]["compact"], (entry["height"], entry["width"])
            )
        return self._compact[key]

    def composite(self, atlas: str, name: str, sky, source: str = "master") -> np.ndarray:
        """``sum_i r_i B_i`` over a whole atlas or view, (H, W, 3), from masters or compact."""
        r = self.light_vector(sky)
        if source == "master":
            return np.einsum("hwnc,nc->hwc", self.stack(atlas, name), r)
        if source == "compact":
            composite = self.compact(atlas, name).composite(r, self.selection)
            if self.compact(atlas, name).entry.get("encodes") == "d - I":
                # Shadowing atlases carry the virtual objects' effect: I = d - (d - I).
                return self.composite(atlas, "d", r, source) - composite
            return composite
        raise ProbeError(f"unknown source {source!r}: use master or compact")

    def _composite_of(self, atlas: str, name: str, r: np.ndarray, source: str) -> np.ndarray:
        """:meth:`composite`, kept for the last light vector (many points, one sky)."""
        key = (atlas, name, source, r.tobytes())
        if key not in self._composites:
            if any(k[3] != key[3] for k in self._composites):
                self._composites.clear()
            self._composites[key] = self.composite(atlas, name, r, source)
        return self._composites[key]

    def light_vector(self, sky) -> np.ndarray:
        """(n, 3) patch radiances of a named sky, a :class:`daylit.sky.Sky` or an array."""
        if isinstance(sky, str):
            sky = parse_sky(sky)
        if isinstance(sky, skies.Sky):
            return skies.patch_mean_radiance(sky, self.dome_vertices)
        r = np.asarray(sky, dtype=np.float64)
        if r.ndim == 1:
            r = np.repeat(r[:, None], 3, axis=1)
        if r.shape != (self.light_count, 3):
            raise ProbeError(f"a light vector needs shape ({self.light_count}, 3), got {r.shape}")
        return r

    # ---------------------------------------------------------------------------------------
    @property
    def sun_casters(self):
        """The virtual models and real proxies of ``site.glb`` as the sun's shadow casters
        (:class:`bake.sunlight.SunCasters`), read on first use."""
        if self._sun_casters is None:
            from bake.sunlight import SunCasters

            self._sun_casters = SunCasters.from_site_glb(self.dir / self.manifest["model"]["path"])
        return self._sun_casters

    def sun_irradiance(
        self, points, normals, sun_direction, normal_irradiance_rgb, without: str = "real"
    ) -> dict:
        """The sun's direct irradiance at receiver points, the oracle of the client's sun.

        ``points``, ``normals``: (m, 3), site frame, metres; ``sun_direction``: (3,) toward
        the sun; ``normal_irradiance_rgb``: (3,) or a number, W/m^2. Returns
        ``{"with", "without"}``: (m, 3) W/m^2, with every caster and with the real proxies only
        (``without="none"``: no caster, as a hull plane's ``d``), and ``"visible_with"``,
        ``"visible_without"``, ``"cos"``: (m,). See :mod:`bake.sunlight`.
        """
        return self.sun_casters.irradiance(
            points, normals, sun_direction, normal_irradiance_rgb, without=without
        )

    def sun_patch(self, sun_direction) -> int | None:
        """The dome patch holding the direction toward the sun, or None below the horizon."""
        from daylit.spherical import PatchLookup

        s = np.asarray(sun_direction, dtype=np.float64)
        s = s / np.linalg.norm(s)
        if s[1] <= 0.0:
            return None
        return int(PatchLookup(self.dome_vertices)(s[None, :])[0])

    def sun_bounce(
        self, points, normals, sun_direction, normal_irradiance_rgb, source: str = "master",
        atlases=ATLAS_ORDER,
    ) -> dict:
        """The sun's bounce at receiver points: sunlight reflected once off the ground, the
        walls and the models onto them (docs/sun.md, item 5), W/m^2.

        The sun in patch ``p`` of the dome is spread over its patch for this (the bounce is
        smooth over neighbouring patches): ``E_sun / solid_angle_p`` times column ``p`` of the
        atlas's sun-bounce stacks, interpolated bilinearly at each point's texel, from the
        EXR masters (``source="master"``) or light ``p``'s own compact image as the client
        decodes it (``"compact"``). ``points``, ``normals``: (m, 3) on receivers (:meth:`locate`);
        ``sun_direction``: (3,) toward the sun; ``normal_irradiance_rgb``: (3,) or a number.

        Returns ``{"with": (m, 3), "without": (m, 3), "patch": p or None, "samples"}``: with
        every object present (``I``) and without the virtual objects (``d``: the real
        proxies alone on ground and walls, nothing but the open ground on hull planes);
        ``without`` is NaN where the receiver has no ``d`` (the models' own surfaces). Zero
        with the sun below the horizon. Raises :class:`ProbeError` for a build without
        sun-bounce stacks (baked before 2026-11-24, or without a bounce) and for a sun in a
        patch the sun never crosses at this site (its column was not baked). ``"compact"`` in
        a build made for some dates (``compression.sun_bounce_dates``) gives zero for a patch
        without images, as the client draws it.
        """
        points = np.atleast_2d(np.asarray(points, dtype=np.float64))
        normals = np.atleast_2d(np.asarray(normals, dtype=np.float64))
        samples = [self.locate(p, n, atlases) for p, n in zip(points, normals, strict=True)]
        m = len(points)
        out_with = np.zeros((m, 3))
        out_without = np.zeros((m, 3))
        for k, sample in enumerate(samples):
            if "d" not in self.atlases[sample.atlas]["stacks"]:
                out_without[k] = np.nan
        p = self.sun_patch(sun_direction)
        E = np.broadcast_to(np.asarray(normal_irradiance_rgb, dtype=np.float64), (3,))
        result = {"with": out_with, "without": out_without, "patch": p, "samples": samples}
        if p is None or not np.any(E):
            return result
        for sample in samples:
            if "sun_bounce" not in self.atlases[sample.atlas]:
                raise ProbeError(
                    f"{self.dir}: atlas {sample.atlas} has no sun-bounce stacks (a build made "
                    "before 2026-11-24, or baked without a bounce): bake it again"
                )
        if p not in set(self.selection.selectable.tolist()):
            raise ProbeError(
                f"the sun is in patch {p}, which it never crosses at this site: the build has "
                "no sun bounce for it (only compression.selectable_lights are baked)"
            )
        r = np.zeros((self.light_count, 3))
        r[p] = E / self.solid_angles[p]
        for k, sample in enumerate(samples):
            names = self.atlases[sample.atlas]["sun_bounce"]
            for stack, out in (("I", out_with), ("d", out_without)):
                if stack not in names:
                    continue
                if source == "master":
                    column = _bilinear(
                        self.sun_bounce_stack(sample.atlas, stack)[:, :, p], sample.x, sample.y
                    )
                    out[k] = column * r[p]
                elif source == "compact":
                    reader = self.sun_bounce_compact(sample.atlas, stack)
                    if reader.entry["lights"]["scale"][p] is None:
                        # A build made for some dates (compression.sun_bounce_dates) has no
                        # image for a patch the sun crosses only on others: the client
                        # draws no sun bounce there.
                        continue
                    # Light p's own image (both levels), as the client fetches it.
                    column = reader.lights([p])[p]
                    out[k] = _bilinear(column, sample.x, sample.y) * r[p]
                else:
                    raise ProbeError(f"unknown source {source!r}: use master or compact")
        return result

    def locate(self, point, normal, atlases=ATLAS_ORDER) -> Sample:
        """The receiver texel at a world point with a given normal.

        By default planes of the ``ground`` and ``hull`` atlases are tried first (they carry
        ``d``); then the lightmap surfaces. ``atlases`` narrows that order, e.g.
        ``("lightmap",)`` for a model's own surface where a hull plane lies 3 cm outside it
        (what the client draws in lightmap mode). Raises :class:`ProbeError` when nothing is
        within 5 cm.
        """
        point = np.asarray(point, dtype=float)
        normal = np.asarray(normal, dtype=float)
        normal = normal / np.linalg.norm(normal)
        best = None
        for atlas_id in (a for a in ("ground", "hull") if a in atlases):
            for r in self.atlases.get(atlas_id, {}).get("receivers", []):
                n = np.array(r["normal"])
                if n @ normal < 0.99:
                    continue
                rel = point - np.array(r["origin_m"])
                distance = abs(rel @ n)
                u = rel @ np.array(r["axis_u"]) / r["texel_m"]
                v = rel @ np.array(r["axis_v"]) / r["texel_m"]
                w, h = r["rect"][2], r["rect"][3]
                inside = 0.5 <= u <= w - 0.5 and 0.5 <= v <= h - 0.5
                if (
                    distance < PLANE_TOLERANCE_M
                    and inside
                    and (best is None or distance < best.distance_m)
                ):
                    best = Sample(
                        atlas_id,
                        r["name"],
                        r["kind"],
                        r["rect"][0] + u,
                        r["rect"][1] + v,
                        distance,
                    )
            if best is not None:
                return best
        if "lightmap" not in atlases:
            raise ProbeError(f"no {' or '.join(atlases)} receiver within {PLANE_TOLERANCE_M} m "
                             f"of {point.tolist()} facing {normal.tolist()}")
        return self._locate_surface(point, normal)

    def _locate_surface(self, point, normal) -> Sample:
        import trimesh

        from bake.gltf import read_site_glb

        if self._surfaces is None:
            nodes = read_site_glb(self.dir / self.manifest["model"]["path"])
            self._surfaces = [
                (name, trimesh.Trimesh(node["vertices"], node["faces"], process=False), node["uv"])
                for name, node in nodes.items()
                if node["extras"].get("atlas") == "lightmap"
            ]
        lightmap = self.atlases["lightmap"]
        best = None
        for name, mesh, uv in self._surfaces:
            closest, distance, face = trimesh.proximity.closest_point(mesh, point[None, :])
            if distance[0] > PLANE_TOLERANCE_M or mesh.face_normals[face[0]] @ normal < 0.9:
                continue
            if best is None or distance[0] < best[0]:
                bary = trimesh.triangles.points_to_barycentric(
                    mesh.triangles[face[0]][None], closest
                )[0]
                tex = bary @ uv[mesh.faces[face[0]]]
                best = (distance[0], name, tex[0] * lightmap["width"], tex[1] * lightmap["height"])
        if best is None:
            raise ProbeError(
                f"no receiver within {PLANE_TOLERANCE_M} m of {point.tolist()} "
                f"facing {normal.tolist()}"
            )
        distance, name, x, y = best
        return Sample("lightmap", name.split("/", 1)[1], "surface", x, y, distance)

    def basis_at(self, sample: Sample, stack: str) -> np.ndarray:
        """Bilinearly interpolated master basis values (n, 3) at a located sample."""
        return _bilinear(self.stack(sample.atlas, stack), sample.x, sample.y)

    def irradiance(self, point, normal, sky, source: str = "master",
                   atlases=ATLAS_ORDER) -> dict:
        """Irradiance (W/m^2, RGB) at a receiver point under a sky, from ``source``
        (``"master"``: the EXR masters; ``"compact"``: the GPU textures as the client uses them).

        Returns ``{"with": (3,), "without": (3,) or None, "sample": Sample}``: with the
        virtual objects present (``I``) and without them (``d``: real proxies only on ground
        and walls, nothing on hull planes); ``None`` where the receiver has no ``d``.
        """
        sample = self.locate(point, normal, atlases)
        r = self.light_vector(sky)
        stacks = self.atlases[sample.atlas]["stacks"]
        names = ["I", "d"] if "d" in stacks else ["I"]
        if source == "master":
            values = [np.einsum("nc,nc->c", self.basis_at(sample, s), r) for s in names]
        else:
            values = [
                _bilinear(self._composite_of(sample.atlas, s, r, source), sample.x, sample.y)
                for s in names
            ]
        return {
            "with": values[0],
            "without": values[1] if len(values) > 1 else None,
            "sample": sample,
        }


def _bilinear(image: np.ndarray, x: float, y: float) -> np.ndarray:
    """``image`` (H, W, ...) at texel coordinates (x, y), texel centres at integer + 0.5,
    clamped at the border like GL's CLAMP_TO_EDGE with LINEAR filtering."""
    h, w = image.shape[:2]
    x, y = x - 0.5, y - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0
    out = np.zeros(image.shape[2:], dtype=np.float64)
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            yy, xx = min(max(y0 + dy, 0), h - 1), min(max(x0 + dx, 0), w - 1)
            out += wy * wx * image[yy, xx]
    return out
