"""HTTPS: ``daylit serve --tls-cert --tls-key`` serves the page, the build and the light stream
over TLS to a client that trusts a certificate made here by OpenSSL (not by the code under
test), and refuses a missing, unreadable, non-PEM or mismatched certificate or key before it
binds its port."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import ssl
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest
from aiohttp import WSMsgType

from daylit.cli import main
from server import protocol
from tests.server.helpers import interrupt_and_wait
from tests.server.test_cli import ROOT, free_port

OPENSSL = shutil.which("openssl")
needs_openssl = pytest.mark.skipif(OPENSSL is None, reason="the system's openssl command "
                                   "makes the test certificate (Debian: apt install openssl)")


def make_certificate(folder: Path, name: str = "server") -> tuple[Path, Path]:
    """A self-signed P-256 certificate for localhost and 127.0.0.1, and its key (PEM), made
    by the system's ``openssl req``."""
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / f"{name}.crt", folder / f"{name}.key"
    subprocess.run([OPENSSL, "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:prime256v1", "-nodes", "-days", "2", "-subj",
                    "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    return cert, key


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> dict[str, Path]:
    if OPENSSL is None:
        pytest.skip("no openssl command")
    folder = tmp_path_factory.mktemp("tls")
    cert, key = make_certificate(folder, "server")
    other_cert, other_key = make_certificate(folder, "other")
    return {"cert": cert, "key": key, "other_key": other_key, "folder": folder}


@needs_openssl
@pytest.mark.parametrize("case, words", [
    ("missing cert", "no such file (the certificate)"),
    ("missing key", "no such file (the private key)"),
    ("folder as cert", "not a file (the certificate)"),
    ("not pem", "not a PEM file (the certificate"),
    ("mismatched", "is not the private key of the certificate"),
    ("cert alone", "[server] tls_cert needs tls_key too"),
    ("key as cert", "not a certificate and its private key"),
])
def test_bad_certificates_are_clear_errors_before_binding(case, words, certs, build_dir,
                                                          tmp_path, capsys):
    cert, key = str(certs["cert"]), str(certs["key"])
    junk = tmp_path / "junk.pem"
    junk.write_text("hello\n")
    args = {
        "missing cert": ["--tls-cert", str(tmp_path / "nope.crt"), "--tls-key", key],
        "missing key": ["--tls-cert", cert, "--tls-key", str(tmp_path / "nope.key")],
        "folder as cert": ["--tls-cert", str(tmp_path), "--tls-key", key],
        "not pem": ["--tls-cert", str(junk), "--tls-key", key],
        "mismatched": ["--tls-cert", cert, "--tls-key", str(certs["other_key"])],
        "cert alone": ["--tls-cert", cert],
        "key as cert": ["--tls-cert", key, "--tls-key", key],
    }[case]
    with socket.socket() as busy:  # the port is taken: the certificate is checked first
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["serve", str(build_dir), "--host", "127.0.0.1", "--port", str(port),
                     *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert words in err and "already in use" not in err, err


@needs_openssl
def test_https_and_wss_with_a_certificate_the_client_trusts(certs, build_dir):
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "daylit.cli", "serve", str(build_dir), "--host", "127.0.0.1",
         "--port", str(port), "--tls-cert", str(certs["cert"]), "--tls-key", str(certs["key"]),
         "--set", "sim.size_px=96", "--set", "sky.rate_hz=10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("open " in x for x in lines):
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        assert f"open https://127.0.0.1:{port}/" in "".join(lines)
        asyncio.run(_talk_tls(port, certs["cert"]))
    finally:
        interrupt_and_wait(proc, 20)
    assert proc.returncode == 0


async def _talk_tls(port: int, ca: Path) -> None:
    trusted = ssl.create_default_context(cafile=str(ca))
    base = f"https://localhost:{port}"
    async with aiohttp.ClientSession() as session:
        async with session.get(f"{base}/build/manifest.json", ssl=trusted) as resp:
            assert resp.status == 200
            assert (await resp.json())["format"] == "daylit-build"
        async with session.get(f"{base}/", ssl=trusted) as resp:
            assert resp.status == 200 and resp.headers["Content-Type"].startswith("text/html")
        ws = await session.ws_connect(f"wss://localhost:{port}/ws/light?protocol=3",
                                      ssl=trusted)
        hello = json.loads((await ws.receive(timeout=30)).data)
        assert hello["type"] == "hello" and hello["streams"] == ["light"]
        msg = await ws.receive(timeout=60)
        assert msg.type == WSMsgType.BINARY
        assert protocol.decode(msg.data).type == protocol.MessageType.LIGHT
        await ws.close()
        # A client that does not trust the certificate is refused by its own TLS check...
        with pytest.raises(aiohttp.ClientConnectorCertificateError):
            await session.get(f"{base}/build/manifest.json", ssl=ssl.create_default_context())
        # ... and plain HTTP on the TLS port gets no page.
        with pytest.raises(aiohttp.ClientError):
            async with session.get(f"http://localhost:{port}/build/manifest.json",
                                   timeout=aiohttp.ClientTimeout(total=10)) as resp:
                await resp.read()
