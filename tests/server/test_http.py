"""Static serving: types, cache headers, gzip, and no way out of any root."""

import asyncio
import gzip
import hashlib
import json

import pytest

from bake.buildmanifest import write_manifest
from server.app import create_app
from tests.server.helpers import ManualSource, settings_for


@pytest.fixture
async def client(aiohttp_client, build_dir, tmp_path):
    (build_dir / "exr").mkdir()
    (build_dir / "atlas.ktx2").write_bytes(b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(64))
    (build_dir / "exr" / "ground.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(64))
    (build_dir / "v.bin").write_bytes(bytes(range(16)))
    write_manifest(build_dir, json.loads((build_dir / "manifest.json").read_text()))
    (build_dir / "unlisted.bin").write_bytes(bytes(8))  # on disk, not in the manifest
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET\n")
    (build_dir / "leak.txt").symlink_to(secret)
    (build_dir / "leakdir").symlink_to(tmp_path)
    settings = settings_for(tmp_path)
    web = tmp_path / "web"
    (web / "leak.txt").symlink_to(secret)
    (web / ".git").mkdir()
    (web / ".git" / "config").write_text("[core]\n")
    app = create_app(build_dir, settings, sky_source=ManualSource())
    return await aiohttp_client(app)


async def test_build_files_have_their_types(client):
    for path, ctype in [
        ("/build/site.glb", "model/gltf-binary"),
        ("/build/atlas.ktx2", "image/ktx2"),
        ("/build/v.bin", "application/octet-stream"),
        ("/build/manifest.json", "application/json"),
    ]:
        resp = await client.get(path)
        assert resp.status == 200, path
        assert resp.headers["Content-Type"] == ctype, path
        assert resp.headers["X-Content-Type-Options"] == "nosniff"


async def test_build_serves_only_what_the_manifest_lists_for_clients(client):
    master = await client.get("/build/exr/ground.exr")
    assert master.status == 403 and "serve_masters" in await master.text()
    assert (await client.get("/build/unlisted.bin")).status == 404


async def test_masters_are_served_when_the_operator_says_so(aiohttp_client, build_dir, tmp_path):
    (build_dir / "exr").mkdir()
    (build_dir / "exr" / "ground.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(64))
    write_manifest(build_dir, json.loads((build_dir / "manifest.json").read_text()))
    settings = settings_for(tmp_path, access__serve_masters=True)
    client = await aiohttp_client(create_app(build_dir, settings, sky_source=ManualSource()))
    resp = await client.get("/build/exr/ground.exr")
    assert resp.status == 200 and resp.headers["Content-Type"] == "image/x-exr"
    assert await resp.read() == (build_dir / "exr" / "ground.exr").read_bytes()


async def test_cache_headers(client, build_dir):
    manifest = await client.get("/build/manifest.json")
    assert manifest.headers["Cache-Control"] == "no-cache"
    sha = hashlib.sha256((build_dir / "site.glb").read_bytes()).hexdigest()
    versioned = await client.get(f"/build/site.glb?v={sha[:16]}")
    assert versioned.headers["Cache-Control"] == "public, max-age=31536000, immutable"
    wrong = await client.get("/build/site.glb?v=0123456789abcdef")
    assert wrong.headers["Cache-Control"] == "no-cache"
    plain = await client.get("/build/site.glb")
    assert plain.headers["Cache-Control"] == "no-cache" and "ETag" in plain.headers
    again = await client.get("/build/site.glb", headers={"If-None-Match": plain.headers["ETag"]})
    assert again.status == 304
    html = await client.get("/")
    assert html.headers["Content-Type"] == "text/html; charset=utf-8"
    assert html.headers["Cache-Control"] == "no-cache"
    assert "daylit" in await html.text()
    three = await client.get("/vendor/three/build/three.module.js")
    assert three.status == 200
    assert three.headers["Content-Type"] == "text/javascript; charset=utf-8"
    assert three.headers["Cache-Control"] == "public, max-age=86400"


async def test_json_is_gzipped_for_clients_that_accept_it(client, build_dir):
    resp = await client.get("/build/manifest.json", headers={"Accept-Encoding": "gzip"},
                            auto_decompress=False)
    assert resp.headers["Content-Encoding"] == "gzip"
    body = await resp.read()
    assert json.loads(gzip.decompress(body)) == json.loads((build_dir / "manifest.json")
                                                           .read_text())
    assert len(body) < (build_dir / "manifest.json").stat().st_size / 2
    etag = resp.headers["ETag"]
    again = await client.get("/build/manifest.json", headers={"Accept-Encoding": "gzip",
                                                              "If-None-Match": etag})
    assert again.status == 304
    plain = await client.get("/build/manifest.json", headers={"Accept-Encoding": "identity"},
                             auto_decompress=False)
    assert "Content-Encoding" not in plain.headers
    status = await client.get("/api/status", headers={"Accept-Encoding": "gzip"},
                              auto_decompress=False)
    assert status.headers["Content-Encoding"] == "gzip"


async def test_three_addons_and_the_basis_transcoder_are_served(client):
    loader = await client.get("/vendor/three/examples/jsm/loaders/KTX2Loader.js")
    assert loader.status == 200
    wasm = await client.get("/vendor/three/examples/jsm/libs/basis/basis_transcoder.wasm")
    assert wasm.status == 200 and wasm.headers["Content-Type"] == "application/wasm"
    js = await client.get("/vendor/three/examples/jsm/libs/basis/basis_transcoder.js")
    assert js.status == 200


async def raw_get(port: int, target: str) -> tuple[int, bytes]:
    """Send the request line exactly as written (no client-side normalisation)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {target} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n".encode())
    await writer.drain()
    data = await asyncio.wait_for(reader.read(), 10)
    writer.close()
    return int(data.split(b" ", 2)[1]), data


@pytest.mark.parametrize(
    "target",
    [
        "/build/../secret.txt",
        "/build/%2e%2e/secret.txt",
        "/build/%2E%2E%2Fsecret.txt",
        "/build/..%2fsecret.txt",
        "/build//etc/passwd",
        "/build/%2Fetc%2Fpasswd",
        "/build/leak.txt",
        "/build/leakdir/secret.txt",
        "/leak.txt",
        "/../secret.txt",
        "/%2e%2e/secret.txt",
        "/.git/config",
        "/src/..%5c..%5csecret.txt",
        "/vendor/three/../../../secret.txt",
        "/vendor/three/%2e%2e/%2e%2e/%2e%2e/secret.txt",
        "/build/site.glb%00.txt",
    ],
)
async def test_paths_cannot_escape_their_root(client, target):
    status, data = await raw_get(client.port, target)
    assert status in (400, 403, 404), (target, status)
    assert b"TOP SECRET" not in data and b"root:" not in data and b"[core]" not in data


async def test_sky_image_is_unavailable_before_the_first_frame(client):
    resp = await client.get("/api/sky.jpg")
    assert resp.status == 503 and resp.headers["Retry-After"] == "1"


async def test_answers_keep_a_kiosk_token_out_of_referers(client):
    for path in ("/", "/build/manifest.json", "/src/main.js"):
        resp = await client.get(path)
        assert resp.headers["Referrer-Policy"] == "same-origin", path
