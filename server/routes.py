"""HTTP routes: the web client, three.js, the build, and the operator endpoints.

============================  ==========================================================
``GET /``, ``/{path}``        the ``web/`` folder (``index.html`` for a folder)
``GET /vendor/three/{path}``  the installed ``three`` package (``build/``, ``examples/jsm/``,
                              including the Basis transcoder in ``examples/jsm/libs/basis/``)
``GET /build/{path}``         the build's manifest and the files it lists for clients
``GET /api/status``           JSON status for operators (:mod:`server.access`)
``GET /api/sky.jpg``          the newest sky frame, small (operators)
``GET /ws/light``             the light stream (:mod:`server.lightstream`)
============================  ==========================================================

No request can leave its root: paths with ``..``, absolute paths, hidden names (``.git``), NUL
or backslashes are refused, and every path is resolved (following symlinks) and must still lie
inside the root.

Caching: ``manifest.json`` and HTML are ``no-cache`` (always revalidated); files the manifest
lists with a checksum are ``immutable`` for a year when requested with ``?v=<sha256 prefix>``
(the client adds it from the manifest, so a re-bake changes the URL), else revalidated; three.js
is cached for a day. JSON, JavaScript, HTML, CSS, the GLB and wasm are sent gzip-compressed to
clients that accept it.
"""

from __future__ import annotations

import asyncio
import gzip
import hashlib
from pathlib import Path, PurePosixPath

from aiohttp import web

from server.access import AccessPolicy, install_access
from server.connections import install_refused_request_log
from server.integrity import BuildIntegrity

CONTENT_TYPES = {
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".ktx2": "image/ktx2",
    ".exr": "image/x-exr",
    ".bin": "application/octet-stream",
    ".json": "application/json",
    ".map": "application/json",
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".glsl": "text/plain; charset=utf-8",
    ".vert": "text/plain; charset=utf-8",
    ".frag": "text/plain; charset=utf-8",
    ".txt": "text/plain; charset=utf-8",
    ".md": "text/markdown; charset=utf-8",
    ".wasm": "application/wasm",
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".webp": "image/webp",
    ".svg": "image/svg+xml",
    ".ico": "image/x-icon",
}
# Text, and two binaries that shrink: the GLB (126 kB to 30 kB for the demo) and the Basis
# transcoder's wasm (527 to 245 kB). KTX2 (Zstandard inside), V (float32) and PNG do not.
COMPRESSIBLE = {".json", ".map", ".html", ".js", ".mjs", ".css", ".gltf", ".svg", ".txt", ".md",
                ".glb", ".wasm"}
MAX_COMPRESSED_FILE_BYTES = 32 << 20
NO_CACHE = "no-cache"
IMMUTABLE = "public, max-age=31536000, immutable"
ONE_DAY = "public, max-age=86400"


def safe_path(root: Path, tail: str) -> Path | None:
    """The file ``tail`` names inside ``root``, or None if it is missing or would escape."""
    if not tail:
        return root.resolve()
    if "\x00" in tail or "\\" in tail or tail.startswith("/"):
        return None
    parts = PurePosixPath(tail).parts
    if any(p in ("..", ".") or p.startswith(".") for p in parts):
        return None
    try:
        resolved = (root / tail).resolve(strict=True)
    except (OSError, RuntimeError):
        return None
    if not resolved.is_relative_to(root.resolve()):
        return None  # a symlink pointing outside
    return resolved


class StaticRoot:
    """Serves one folder with explicit types, cache headers and gzip for text."""

    def __init__(self, root: Path, name: str, default_cache: str = NO_CACHE,
                 checksums: dict[str, str] | None = None, offered: frozenset[str] | None = None,
                 integrity: BuildIntegrity | None = None):
        self.root = Path(root)
        self.name = name
        self.default_cache = default_cache
        self.checksums = checksums or {}
        self.offered = offered  # None: every file under the root; else only these paths
        self.integrity = integrity
        self._gz_cache: dict[Path, tuple[tuple[int, int], bytes, str]] = {}

    def cache_control(self, rel: str, request: web.Request) -> str:
        if rel.endswith((".html", "manifest.json")) or rel == "":
            return NO_CACHE
        digest = self.checksums.get(rel)
        if digest is not None:
            v = request.query.get("v", "")
            if len(v) >= 8 and digest.startswith(v.lower()):
                return IMMUTABLE
            return NO_CACHE
        return self.default_cache

    async def handle(self, request: web.Request) -> web.StreamResponse:
        tail = request.match_info.get("tail", "")
        path = safe_path(self.root, tail)
        if path is not None and path.is_dir():
            tail = (tail.rstrip("/") + "/index.html").lstrip("/")
            path = safe_path(self.root, tail)
        if path is None or not path.is_file():
            raise web.HTTPNotFound(text=f"not found: /{self.name}{tail}\n")
        rel = path.relative_to(self.root.resolve()).as_posix()
        if self.offered is not None and rel not in self.offered:
            if rel in self.checksums:  # listed, but not for clients: an EXR master
                raise web.HTTPForbidden(text=f"not offered to clients: /{self.name}{rel} (an EXR "
                                        "master; [access] serve_masters offers them)\n")
            raise web.HTTPNotFound(text=f"not found: /{self.name}{tail}\n")
        if self.integrity is not None and not await self.integrity.intact(rel, path):
            raise web.HTTPServiceUnavailable(
                text=f"/{self.name}{rel} is damaged on the server (its SHA-256 does not match "
                     "the manifest); the operator has been told\n",
                headers={"Cache-Control": "no-store", "Retry-After": "60"})
        suffix = path.suffix.lower()
        headers = {
            "Content-Type": CONTENT_TYPES.get(suffix, "application/octet-stream"),
            "Cache-Control": self.cache_control(rel, request),
            "X-Content-Type-Options": "nosniff",
        }
        accepts_gzip = "gzip" in request.headers.get("Accept-Encoding", "").lower()
        if suffix in COMPRESSIBLE and accepts_gzip:
            stat = path.stat()
            if stat.st_size <= MAX_COMPRESSED_FILE_BYTES:
                return await self._gzip_response(request, path, stat, headers)
        return web.FileResponse(path, headers=headers)

    async def _gzip_response(self, request, path: Path, stat, headers) -> web.StreamResponse:
        key = (stat.st_mtime_ns, stat.st_size)
        cached = self._gz_cache.get(path)
        if cached is None or cached[0] != key:
            raw = await asyncio.to_thread(path.read_bytes)
            body = await asyncio.to_thread(gzip.compress, raw, 6, mtime=0)
            etag = '"' + hashlib.sha256(raw).hexdigest()[:32] + '-gz"'
            cached = (key, body, etag)
            if len(self._gz_cache) > 256:
                self._gz_cache.clear()
            self._gz_cache[path] = cached
        _, body, etag = cached
        headers = dict(headers, ETag=etag, Vary="Accept-Encoding")
        if request.headers.get("If-None-Match") == etag:
            return web.Response(status=304, headers={k: v for k, v in headers.items()
                                                     if k != "Content-Type"})
        headers["Content-Encoding"] = "gzip"
        return web.Response(body=body, headers=headers)


def add_static_routes(app: web.Application, web_root: Path, three_root: Path, build_dir: Path,
                      checksums: dict[str, str], offered: frozenset[str] | None = None,
                      integrity: BuildIntegrity | None = None) -> None:
    """Register the three static roots (the catch-all web root last); ``/build/`` serves only
    ``offered`` (None: every file) and, with ``integrity``, only intact files."""
    build = StaticRoot(build_dir, "build/", NO_CACHE, checksums, offered, integrity)
    three = StaticRoot(three_root, "vendor/three/", ONE_DAY)
    site = StaticRoot(web_root, "", NO_CACHE)
    app.router.add_get("/build/{tail:.*}", build.handle, name="build")
    app.router.add_get("/vendor/three/{tail:.*}", three.handle, name="three")
    app.router.add_get("/{tail:.*}", site.handle, name="web")


def add_client_routes(app: web.Application, hub, status, sky_jpeg, web_root: Path,
                      three_root: Path, build_dir: Path, manifest: dict,
                      policy: AccessPolicy) -> None:
    """What every process that holds clients serves (one process, or a fan-out worker): the
    light stream of ``hub`` (a :class:`server.lightstream.LightHub`), ``/api/status`` and
    ``/api/sky.jpg`` (the given handlers), then the static roots; every request checked by
    ``policy`` (:mod:`server.access`), the build's files by their SHA-256
    (:mod:`server.integrity`, checked once at start); refused requests logged."""
    install_refused_request_log()
    install_access(app, policy)
    app.router.add_get("/ws/light", hub.handle, name="light")
    app.router.add_get("/api/status", status, name="status")
    app.router.add_get("/api/sky.jpg", sky_jpeg, name="sky")
    checksums = {f["path"]: f["sha256"] for f in manifest["files"]}
    offered = policy.client_files(manifest)
    integrity = BuildIntegrity(build_dir, {p: d for p, d in checksums.items() if p in offered})
    app[INTEGRITY] = integrity
    add_static_routes(app, web_root, three_root, build_dir, checksums, offered, integrity)
    app.on_startup.append(_check_build)


INTEGRITY = web.AppKey("integrity", BuildIntegrity)


async def _check_build(app: web.Application) -> None:
    """``on_startup``: check every offered build file once, while the server answers."""
    task = asyncio.ensure_future(app[INTEGRITY].check_all())
    app[CHECK_TASK] = task

    async def stop(_app) -> None:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    app.on_cleanup.append(stop)


CHECK_TASK = web.AppKey("integrity_check", asyncio.Task)
