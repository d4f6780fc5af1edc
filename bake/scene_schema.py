"""The JSON Schema of ``scene.toml`` (docs/scene-format.md) and the words of its problems.

Every key a site description may hold, with its type, range, default and meaning: the one
source of the checks of bake.scene (validated with jsonschema, as every settings file and the
manifest, daylit.settingschema) and of the tables in docs/scene-format.md
(tools/settings_tables.py). What one key's schema cannot say stays in bake.scene: a time zone
that exists, a model file that exists and reads, names used once, a box or a model, a view's
field of view or intrinsics, a view that looks somewhere.

``x-default`` words a default that is not a value (``"folder name"``); a key without a default
that is not ``required`` is optional (``null`` to the loader).
"""

from __future__ import annotations

import difflib
import math
from typing import Any

import jsonschema

from bake.dome import MAX_LIGHTS, MIN_LIGHTS

# The smallest number of bounces within 1 % of the many-bounce answer on the demo at albedo
# 0.6 (docs/benchmarks.md, "Bounces").
DEFAULT_BOUNCES = 4
QUALITY_DEFAULTS = {
    "draft": {"direct_rays": 160, "bounce_rays": 24, "cache_spacing_m": 1.5,
              "texel_scale": 2.0, "view_scale": 0.5},
    "final": {"direct_rays": 960, "bounce_rays": 96, "cache_spacing_m": 0.6,
              "texel_scale": 1.0, "view_scale": 1.0},
}


def _num(default, description, lo=None, hi=None, integer=False, lo_open=False, **extra):
    prop: dict[str, Any] = {"type": "integer" if integer else "number",
                            "description": description, **extra}
    if default is not None:
        prop["default"] = default
    if lo is not None:
        prop["exclusiveMinimum" if lo_open else "minimum"] = lo
    if hi is not None:
        prop["maximum"] = hi
    return prop


def _vec(n, default, description, lo=None, hi=None, positive=False, **extra):
    item: dict[str, Any] = {"type": "number"}
    if positive:
        item["exclusiveMinimum"] = 0
    if lo is not None:
        item["minimum"] = lo
    if hi is not None:
        item["maximum"] = hi
    prop = {"type": "array", "items": item, "minItems": n, "maxItems": n,
            "description": description, **extra}
    if default is not None:
        prop["default"] = default
    return prop


def _str(default, description, choices=None, **extra):
    prop: dict[str, Any] = {"type": "string", "minLength": 1, "pattern": r"\S",
                            "description": description, **extra}
    if choices is not None:
        prop["enum"] = list(choices)
    if default is not None:
        prop["default"] = default
    return prop


def _table(properties: dict, required=(), description="") -> dict:
    out = {"type": "object", "additionalProperties": False, "properties": properties,
           "description": description}
    if required:
        out["required"] = list(required)
    return out


def _array_of(table: dict, description: str) -> dict:
    return {"type": "array", "items": table, "default": [], "description": description}


_PLACEMENT = {
    "translation_m": _vec(3, [0.0, 0.0, 0.0], "where the model's origin goes"),
    "yaw_deg": _num(0.0, "rotation about +Y, counter-clockwise seen from above", -360.0, 360.0),
    "scale": _num(1.0, "uniform scale", 0.0, lo_open=True),
}


def _quality_level(level: str) -> dict:
    d = QUALITY_DEFAULTS[level]
    return _table({
        "direct_rays": _num(d["direct_rays"], "visibility rays per point over the whole sky; "
                            "each light gets max(2, ceil(direct_rays / lights)) spread over "
                            "its patch", 8, 65536, integer=True),
        "bounce_rays": _num(d["bounce_rays"], "gather rays per point for one diffuse bounce",
                            0, 4096, integer=True),
        "cache_spacing_m": _num(d["cache_spacing_m"], "spacing of the bounce cache on "
                                "surfaces (ground far from the site: 3x)", 0.05, 50.0),
        "texel_scale": _num(d["texel_scale"], "multiplies every texel size", 0.1, 16.0),
        "view_scale": _num(d["view_scale"], "multiplies view resolutions", 0.05, 4.0),
    }, description=f"the {level} quality level")


SCHEMA: dict = _table({
    "site": _table({
        "name": _str(None, "shown to visitors and operators"),
        # Python's \w (jsonschema matches with re): letters and digits of any script, as
        # str.isalnum, which checks the folder name that is the default.
        "id": _str(None, "names the build and the stream", pattern=r"^[\w-]+$",
                   **{"x-default": "folder name", "x-allowed": "letters, digits, - and _",
                      "x-message": "may hold only letters, digits, - and _"}),
        "latitude_deg": _num(None, "WGS84 latitude (north positive)", -90.0, 90.0),
        "longitude_deg": _num(None, "WGS84 longitude (east positive)", -180.0, 180.0),
        "elevation_m": _num(0.0, "height above sea level (sun position)", -500.0, 9000.0),
        "timezone": _str(None, "IANA name, e.g. Asia/Tokyo"),
        "north_deg": _num(0.0, "azimuth of true north, clockwise from the scene's -Z axis seen "
                          "from above", -360.0, 360.0),
    }, required=("name", "latitude_deg", "longitude_deg", "timezone")),
    "dome": _table({
        "lights": _num(160, "number of sky patches; the nearest geodesic count is used: "
                       "icosahedral 40, 160, 360, 640, 1000, ... or octahedral 36, 64, 100, "
                       "144, 196, ..., 400, ... (--lights overrides)", MIN_LIGHTS, MAX_LIGHTS,
                       integer=True),
    }),
    "quality": _table({
        "default": _str("final", "the level used unless --quality says otherwise",
                        choices=tuple(QUALITY_DEFAULTS)),
        "bounces": _num(DEFAULT_BOUNCES, "diffuse bounces of light between surfaces (1: "
                        "reflected once); each more costs one sparse product over the bounce "
                        "cache (docs/benchmarks.md)", 1, 16, integer=True),
        "draft": _quality_level("draft"),
        "final": _quality_level("final"),
    }),
    "bake": _table({
        "seed": _num(1, "the same seed gives the same bake, whatever the number of workers",
                     0, 2**31 - 1, integer=True),
    }),
    "ground": _table({
        "center_m": _vec(2, [0.0, 0.0], "centre of the ground rectangle (x, z)"),
        "size_m": _vec(2, None, "its size along x and z; beyond it the bake assumes open "
                       "ground of the same albedo", positive=True),
        "albedo": _vec(3, None, "linear RGB reflectance", 0.0, 1.0),
    }, required=("size_m", "albedo")),
    "shadowing": _table({
        "texel_m": _num(0.5, "texel size of ground and wall planes", 0.01, 10.0),
        "hull_texel_m": _num(0.25, "texel size of hull planes", 0.01, 10.0),
        "hull_offset_m": _num(0.03, "how far hull planes sit outside the hull (against "
                              "z-fighting)", 0.0, 1.0),
        "min_sun_elevation_deg": _num(10.0, "ground and walls get planes wherever a virtual "
                                      "shadow can fall for suns and sky patches at least this "
                                      "high", 1.0, 89.0),
        "min_plane_area_m2": _num(0.25, "smaller hull facets get no plane", 0.0, 1e6),
        "max_planes_per_part": _num(24, "a part whose hull has more planes (a curved object) "
                                    "gets a coarser enclosing polytope", 4, 1000, integer=True),
        "max_atlas_size": _num(2048, "largest atlas edge, texels", 64, 8192, integer=True),
    }),
    "lightmap": _table({
        "texel_m": _num(0.2, "texel size of the models' own surfaces (grows by 25% steps if "
                        "the atlas would exceed max_atlas_size)", 0.005, 10.0),
    }),
    "compression": _table({
        "budget": _num(0.01, "RMS composite error over the mean on the test skies (--budget "
                       "overrides)", 1e-5, 0.5),
        "max_rank": _num(64, "largest k of a low-rank base", 1, 512, integer=True),
        "encoding": _str("uastc", "uastc, or etc1s (smaller, coarser)",
                         choices=("uastc", "etc1s")),
        "selected_lights": _num(0, "how many of the brightest lights a client takes from "
                                "their own images in every stack (the atlases' and the fixed "
                                "views'), which it relights with the sky without the sun's "
                                "disc (0: none, the base alone; before the sun was drawn "
                                "apart, 1: the sun's patch). Builds of 2026-11-24 made before "
                                "the views were fitted without the disc kept 1 for the views "
                                "(docs/compact-assets.md, \"The sun apart\")", 0, 64,
                                integer=True),
        "sun_bounce_budget": _num(0.01, "a sun-bounce image keeps its refinement only where "
                                  "its coarse level alone is off by more than this, as "
                                  "displayed: RMS over the mean of the sky without the sun's "
                                  "disc, the sun's direct term and its bounce, under a clear "
                                  "sky with the sun "
                                  "at the patch's centre (0: every image keeps it; "
                                  "docs/compact-assets.md, \"The sun's bounce\")", 0.0, 0.5),
        "sun_bounce_lights": _num(196, "on a dome of more lights than this, neighbouring "
                                  "sun patches share one sun-bounce image: those in one patch "
                                  "of the dome of about this many lights (their mean; a visit "
                                  "at 400 lights fetches 3 images per stack instead of 6). 0: "
                                  "one image per patch (docs/sun.md, \"Shared images\")", 0,
                                  20000, integer=True),
        "sun_bounce_encoding": _str("smallest", "smallest: the first of ETC1S and UASTC "
                                    "with rate-distortion optimization (lambda 3, then 1) that "
                                    "is smaller than the image's plain UASTC and within "
                                    "sun_bounce_budget as displayed, its RMS and at single "
                                    "texels, else plain UASTC (the kiosk's views: plain "
                                    "UASTC always); uastc: every sun-bounce image "
                                    "plain UASTC (more bytes; docs/compact-assets.md, \"The "
                                    "sun's bounce\")",
                                    choices=("uastc", "smallest")),
        "sun_bounce_sharing": _str("within_budget", "within_budget: a sun patch shares its "
                                   "group's sun-bounce image (sun_bounce_lights) only where "
                                   "that, at the patch's own gain, keeps it within 70 % of "
                                   "sun_bounce_budget as displayed, its RMS and at single "
                                   "texels, else it gets an image of "
                                   "its own; always: every patch of a group shares it, "
                                   "whatever it costs as displayed (fewer bytes; the bake "
                                   "reports the cost; docs/sun.md, \"Shared images\")",
                                   choices=("within_budget", "always")),
    }),
    "virtual": _array_of(_table({
        "name": _str(None, "unique"),
        "model": _str(None, ".glb, .gltf or .obj, relative to the site folder"),
        "parts": _str("nodes", "nodes: each glTF node is a part with its own convex hull of "
                      "shadowing planes; whole: one part", choices=("nodes", "whole")),
        "albedo": _vec(3, None, "linear RGB; required if a node has no material", 0.0, 1.0,
                       **{"x-default": "the materials' base colour"}),
        **_PLACEMENT,
    }, required=("name", "model")), "the reconstruction (at least one)"),
    "real": _array_of(_table({
        "name": _str(None, "unique"),
        "box_m": _vec(3, None, "size (x, y, z) of a box standing on the ground at "
                      "translation_m", positive=True),
        "model": _str(None, "a mesh file instead of a box (one of the two)"),
        "albedo": _vec(3, None, "linear RGB", 0.0, 1.0),
        "receiver": {"type": "boolean", "default": True, "description": "its faces carry "
                     "shadowing planes where virtual shadows reach"},
        **_PLACEMENT,
    }, required=("name", "albedo")), "proxies of what stands on the site today"),
    "view": _array_of(_table({
        "name": _str(None, "unique"),
        "width": _num(None, "image width, pixels", 16, 8192, integer=True),
        "height": _num(None, "image height, pixels", 16, 8192, integer=True),
        "position_m": _vec(3, None, "camera centre"),
        "look_at_m": _vec(3, None, "a point it looks at (the camera is level: no roll)"),
        "fov_y_deg": _num(None, "vertical field of view of an ideal pinhole camera (or "
                          "intrinsics)", 1.0, 170.0),
        "intrinsics": _table({
            "fx": _num(None, "focal length along x, pixels", 1.0),
            "fy": _num(None, "focal length along y, pixels", 1.0),
            "cx": _num(None, "principal point x, pixels (<= width)", 0.0),
            "cy": _num(None, "principal point y, pixels (<= height)", 0.0),
        }, required=("fx", "fy", "cx", "cy"),
            description="{ fx, fy, cx, cy } in pixels (OpenCV convention), instead of "
            "fov_y_deg"),
    }, required=("name", "width", "height", "position_m", "look_at_m")),
        "fixed, calibrated viewpoints (the kiosk camera, Sato's Camera A)"),
}, required=("site", "ground"))


def _kind(value: Any) -> str:
    return {dict: "a table", list: "a list", str: "a string", bool: "a boolean"}.get(
        type(value), type(value).__name__
    )


def _key(path) -> str:
    """``site.latitude_deg``, ``virtual[0].model``, ``ground.albedo[1]``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _words(error: jsonschema.ValidationError, schema: dict) -> tuple[tuple, str]:
    """(path, words) of one schema error, in the words docs/scene-format.md shows."""
    path, value = tuple(error.path), error.instance
    keyword, bound = error.validator, error.validator_value
    if keyword == "additionalProperties":
        known = sorted(error.schema["properties"])
        extra = sorted(set(value) - set(known))[0]
        close = difflib.get_close_matches(extra, known, n=1, cutoff=0.5)
        hint = f"did you mean {close[0]!r}?" if close else f"known keys here: {', '.join(known)}"
        return path + (extra,), f"unknown key ({hint})"
    if keyword == "required":
        missing = next(k for k in bound if k not in value)
        return path + (missing,), "is required but missing"
    if "x-message" in error.schema:
        return path, error.schema["x-message"]
    if keyword == "type":
        if bound == "object":
            return path, f"must be a table, got {_kind(value)}"
        if bound == "array" and error.schema.get("items", {}).get("type") == "object":
            return path, "must be an array of tables ([[...]])"
        if bound == "array":
            n = error.schema.get("minItems")
            return path, f"must be a list of {n} numbers, got {value!r}"
        if bound == "integer" and isinstance(value, int | float) and not isinstance(value, bool):
            return path, f"must be a whole number, got {value}"
        if bound in ("number", "integer"):
            return path, f"must be a number, got {_kind(value)}"
        if bound == "boolean":
            return path, f"must be true or false, got {value!r}"
        return path, f"must be a non-empty string, got {value!r}"
    if keyword in ("minItems", "maxItems"):
        return path, f"must be a list of {bound} numbers, got {value!r}"
    if keyword in ("minLength", "pattern"):
        return path, f"must be a non-empty string, got {value!r}"
    if keyword == "enum":
        return path, f"must be one of {', '.join(bound)}; got {value!r}"
    if path and isinstance(path[-1], int) and keyword in ("minimum", "maximum"):
        lo, hi = error.schema.get("minimum"), error.schema.get("maximum")
        return path, f"must be within [{lo}, {hi}], got {value}"
    if keyword == "exclusiveMinimum" and bound == 0 and path and isinstance(path[-1], int):
        return path, f"must be positive, got {value}"
    if keyword == "exclusiveMinimum":
        return path, f"must be greater than {bound}, got {value}"
    if keyword == "minimum":
        return path, f"must be at least {bound}, got {value}"
    if keyword == "maximum":
        return path, f"must be at most {bound}, got {value}"
    return path, error.message


def _non_finite(data: Any, path=()):
    """The path of the first number that is not finite (JSON Schema's bounds let NaN by)."""
    if isinstance(data, float) and not math.isfinite(data):
        return path
    items = data.items() if isinstance(data, dict) else (
        enumerate(data) if isinstance(data, list) else ())
    for k, v in items:
        found = _non_finite(v, (*path, k))
        if found is not None:
            return found
    return None


def first_problem(data: dict) -> tuple[str, str] | None:
    """``(key, words)`` of the first problem of a parsed scene.toml, or None.

    Unknown keys come first (they are almost always typos), then numbers that are not
    finite, then the rest in the order of the file's keys.
    """
    errors = list(jsonschema.Draft202012Validator(SCHEMA).iter_errors(data))
    unknown = [e for e in errors if e.validator == "additionalProperties"]
    if unknown:
        path, words = _words(min(unknown, key=lambda e: len(e.path)), SCHEMA)
        return _key(path), words
    bad = _non_finite(data)
    if bad is not None:
        return _key(bad), f"must be finite, got {_get(data, bad)}"
    if errors:
        error = min(errors, key=lambda e: _order(data, tuple(e.path)))
        path, words = _words(error, SCHEMA)
        return _key(path), words
    return None


def _get(data: Any, path: tuple) -> Any:
    for p in path:
        data = data[p]
    return data


def _order(data: dict, path: tuple) -> tuple:
    """A sort key placing errors in the file's order of sections and keys."""
    out = []
    here: Any = data
    for p in path:
        if isinstance(here, dict):
            keys = list(here)
            out.append(keys.index(p) if p in keys else len(keys))
        else:
            out.append(p)
        here = here[p]
    return tuple(out) + (-1,) * (6 - len(out))
