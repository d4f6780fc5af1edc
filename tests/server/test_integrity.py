"""The server serves a build file as immutable only while its bytes match the manifest's SHA-256
(checked at start, and again when the file's size or time changes): a file damaged after the
start is answered 503 ``no-store``, never cached for a year, and served again once repaired."""

from __future__ import annotations

import hashlib
import logging
import os

from server.app import create_app
from server.integrity import BuildIntegrity, sha256_file
from server.routes import INTEGRITY
from tests.server.helpers import ManualSource, settings_for, wait_for

IMMUTABLE = "public, max-age=31536000, immutable"


async def test_a_file_damaged_after_the_start_is_refused_until_repaired(
        aiohttp_client, build_dir, tmp_path, caplog):
    glb = build_dir / "site.glb"
    good = glb.read_bytes()
    sha = hashlib.sha256(good).hexdigest()
    app = create_app(build_dir, settings_for(tmp_path), sky_source=ManualSource())
    client = await aiohttp_client(app)
    integrity: BuildIntegrity = app[INTEGRITY]
    await wait_for(lambda: "site.glb" in integrity._verdicts)  # the check at start
    url = f"/build/site.glb?v={sha[:16]}"
    resp = await client.get(url)
    assert resp.status == 200 and resp.headers["Cache-Control"] == IMMUTABLE
    assert await resp.read() == good

    # The same length, one byte changed (the client's length check alone would miss it).
    damaged = bytearray(good)
    damaged[-1] ^= 0xFF
    glb.write_bytes(bytes(damaged))
    os.utime(glb, ns=(glb.stat().st_atime_ns, glb.stat().st_mtime_ns + 1_000_000))
    with caplog.at_level(logging.ERROR, logger="daylit.integrity"):
        for _ in range(2):  # one log line for the damage, however often it is asked for
            resp = await client.get(url)
            assert resp.status == 503
            assert resp.headers["Cache-Control"] == "no-store"
            assert "damaged" in await resp.text()
    errors = [r for r in caplog.records if r.name == "daylit.integrity"]
    assert len(errors) == 1 and "site.glb does not match the manifest" in errors[0].message

    glb.write_bytes(good)  # repaired
    os.utime(glb, ns=(glb.stat().st_atime_ns, glb.stat().st_mtime_ns + 2_000_000))
    resp = await client.get(url)
    assert resp.status == 200 and resp.headers["Cache-Control"] == IMMUTABLE
    assert await resp.read() == good


async def test_a_file_damaged_before_the_start_is_reported_at_start(
        aiohttp_client, build_dir, tmp_path, caplog):
    (build_dir / "site.glb").write_bytes(b"glTF" + bytes(8))  # the manifest says otherwise
    app = create_app(build_dir, settings_for(tmp_path), sky_source=ManualSource())
    with caplog.at_level(logging.INFO, logger="daylit.integrity"):
        await aiohttp_client(app)
        await wait_for(lambda: any("do not match" in r.message for r in caplog.records))
    assert app[INTEGRITY].mismatches == {"site.glb"}
    assert any("1 of 1 build files do not match" in r.message for r in caplog.records)


def test_sha256_file_agrees_with_hashlib(tmp_path):
    data = os.urandom(3 * (1 << 20) + 17)  # over several chunks
    path = tmp_path / "blob.bin"
    path.write_bytes(data)
    assert sha256_file(path) == hashlib.sha256(data).hexdigest()
