"""Who can see what (docs/server.md), against the real ``daylit serve``: the site camera and its
occlusion masks, ``/api/status`` and ``/api/sky.jpg`` only for an operator (the token, or this
machine when none is configured), Host names of other sites refused (DNS rebinding), and
``/build/`` without the EXR masters."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest
from aiohttp import WSMsgType

from server import protocol
from server.access import AccessPolicy, host_name
from server.cli import _lan_address
from tests.server.helpers import KioskSequence, interrupt_and_wait
from tests.server.test_cli import ROOT, free_port

TOKEN = "kiosk-3f9a1c07d2e84b6b"
PRIVATE = ["site-camera", "occlusion"]


@pytest.fixture(scope="module")
def kiosk_frames(demo_draft_build, tmp_path_factory) -> Path:
    """A replay of the demo's kiosk view with two people walking (server.occlusion's synthetic
    site), so the occlusion stream has masks to send."""
    kiosk = KioskSequence(demo_draft_build, frames=30, empty_frames=10)
    return kiosk.write(tmp_path_factory.mktemp("access") / "frames")


@contextlib.contextmanager
def serve(build: Path, *args: str, token: str | None = None, host: str = "127.0.0.1"):
    """``daylit serve BUILD ARGS`` on a free port (the operator token in the environment when
    given); yields the port once it prints its address."""
    port = free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("DAYLIT_OPERATOR_TOKEN", None)
    if token is not None:
        env["DAYLIT_OPERATOR_TOKEN"] = token
    proc = subprocess.Popen(
        [sys.executable, "-m", "daylit.cli", "serve", str(build), "--host", host, "--port",
         str(port), "--set", "sim.size_px=96", "--set", "sky.rate_hz=10", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        deadline = time.monotonic() + 90
        lines = []
        while time.monotonic() < deadline and not any("kiosk:" in x for x in lines):
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        serve.banner = "".join(lines)
        yield port
    finally:
        interrupt_and_wait(proc, 30)


async def get(url: str, headers: dict | None = None) -> tuple[int, bytes]:
    async with aiohttp.ClientSession() as session, \
            session.get(url, headers=headers or {}) as resp:
        return resp.status, await resp.read()


async def streams_granted(url: str, wanted=("light", *PRIVATE), frames: bool = False,
                          headers: dict | None = None) -> tuple[list[str], set[int]]:
    """The streams the hello grants to a subscription of ``wanted``, and (``frames``) the
    message types received until a site-camera frame and its mask came, or 20 messages."""
    async with aiohttp.ClientSession() as session:
        ws = await session.ws_connect(f"{url}&streams={','.join(wanted)}",
                                      headers=headers or {})
        hello = json.loads((await ws.receive(timeout=30)).data)
        kinds: set[int] = set()
        if frames:
            for _ in range(400):
                msg = await ws.receive(timeout=60)
                assert msg.type == WSMsgType.BINARY, msg
                kinds.add(protocol.decode(msg.data).type)
                if {protocol.MessageType.SITE_CAMERA, protocol.MessageType.OCCLUSION_MASK} \
                        <= kinds:
                    break
        await ws.close()
        return hello["streams"], kinds


async def wait_status_ok(url: str) -> tuple[int, bytes]:
    """GET ``url`` until it is not 503 (the sky image before the first frame)."""
    for _ in range(300):
        status, body = await get(url)
        if status != 503:
            return status, body
        await asyncio.sleep(0.2)
    return status, body


def test_with_a_token_only_its_bearers_see_the_site(demo_draft_build, kiosk_frames):
    with serve(demo_draft_build, "--site-camera", f"replay:{kiosk_frames}",
               token=TOKEN) as port:
        asyncio.run(_token_checks(f"127.0.0.1:{port}"))
    assert "?mode=kiosk&token=<the operator token>" in serve.banner
    assert TOKEN not in serve.banner  # never printed


async def _token_checks(where: str) -> None:
    base = f"http://{where}"
    for path in ("/api/status", "/api/sky.jpg"):
        status, body = await get(base + path)  # from this machine, but no token
        assert status == 403 and b"token" in body, (path, status)
        assert (await get(f"{base}{path}?token=wrong-{TOKEN}"))[0] == 403
        assert (await get(f"{base}{path}?token={TOKEN[:-1]}"))[0] == 403
        status, body = await wait_status_ok(f"{base}{path}?token={TOKEN}")
        assert status == 200, (path, body[:200])
        status, _ = await get(base + path, {"Authorization": f"Bearer {TOKEN}"})
        assert status in (200, 503 if path.endswith(".jpg") else 200)
    status, body = await get(f"{base}/api/status?token={TOKEN}")
    assert json.loads(body)["occlusion"] is not None
    # What every visitor needs stays open.
    assert (await get(base + "/"))[0] == 200
    assert (await get(base + "/build/manifest.json"))[0] == 200
    ws = f"ws://{where}/ws/light?protocol=3"
    granted, kinds = await streams_granted(ws, frames=True)
    assert granted == ["light"] and kinds == {protocol.MessageType.LIGHT}, kinds
    granted, _ = await streams_granted(f"{ws}&token=nope")
    assert granted == ["light"]
    granted, kinds = await streams_granted(f"{ws}&token={TOKEN}", frames=True)
    assert granted == ["light", "occlusion", "site-camera"]
    assert {protocol.MessageType.SITE_CAMERA, protocol.MessageType.OCCLUSION_MASK} <= kinds


def test_without_a_token_only_this_machine_sees_the_site(demo_draft_build, kiosk_frames):
    lan = _lan_address()
    with serve(demo_draft_build, "--site-camera", f"replay:{kiosk_frames}",
               host="0.0.0.0") as port:
        asyncio.run(_local_checks(port, lan))
    # What `make demo` prints (it serves on every interface, without TLS): the phone's way in.
    banner = serve.banner
    assert f"kiosk: http://localhost:{port}/?mode=kiosk on this machine only" in banner
    if lan is not None:
        assert f"on the site network: http://{lan}:{port}/" in banner
        assert "phones allow the camera and AR over HTTPS only" in banner


async def _local_checks(port: int, lan: str | None) -> None:
    base = f"http://127.0.0.1:{port}"
    assert (await wait_status_ok(base + "/api/sky.jpg"))[0] == 200
    assert (await get(base + "/api/status"))[0] == 200
    granted, kinds = await streams_granted(f"ws://127.0.0.1:{port}/ws/light?protocol=3",
                                           frames=True)
    assert granted == ["light", "occlusion", "site-camera"]
    # A reverse proxy on this machine forwards every visitor from 127.0.0.1: not an operator.
    forwarded = {"X-Forwarded-For": "203.0.113.9"}
    assert (await get(base + "/api/status", forwarded))[0] == 403
    assert (await get(base + "/api/sky.jpg", {"Forwarded": "for=203.0.113.9"}))[0] == 403
    granted, _ = await streams_granted(f"ws://127.0.0.1:{port}/ws/light?protocol=3",
                                       headers=forwarded)
    assert granted == ["light"]
    if lan is not None:  # from another address of this machine's network: not local
        assert (await get(f"http://{lan}:{port}/api/status"))[0] == 403
        assert (await get(f"http://{lan}:{port}/build/manifest.json"))[0] == 200
        granted, _ = await streams_granted(f"ws://{lan}:{port}/ws/light?protocol=3")
        assert granted == ["light"]


def test_other_hosts_are_refused_and_masters_are_not_served(build_dir):
    (build_dir / "exr").mkdir()
    (build_dir / "exr" / "lightmap.I.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(64))
    from bake.buildmanifest import write_manifest

    write_manifest(build_dir, json.loads((build_dir / "manifest.json").read_text()))
    with serve(build_dir, "--allow-host", "daylit.example.org",
               "--allow-host", "*.museum.example") as port:
        asyncio.run(_host_checks(port))


async def _host_checks(port: int) -> None:
    base = f"http://127.0.0.1:{port}"
    for path in ("/", "/build/manifest.json", "/api/status", "/ws/light"):
        status, body = await get(base + path, {"Host": f"attacker.example:{port}"})
        assert status == 421 and b"--allow-host" in body, (path, status)
    async with aiohttp.ClientSession() as session:
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await session.ws_connect(f"ws://127.0.0.1:{port}/ws/light",
                                     headers={"Host": "rebound.attacker.example",
                                              "Origin": "http://rebound.attacker.example"})
        assert refused.value.status == 421
    for host in (f"localhost:{port}", f"daylit.example.org:{port}", "kiosk.museum.example",
                 f"127.0.0.1:{port}", f"[::1]:{port}", "192.168.1.20"):
        assert (await get(base + "/build/manifest.json", {"Host": host}))[0] == 200, host
    assert (await get(base + "/build/site.glb"))[0] == 200
    status, body = await get(base + "/build/exr/lightmap.I.exr")
    assert status == 403 and b"serve_masters" in body


@pytest.mark.parametrize("header, name", [
    ("Example.ORG:8443", "example.org"), ("[::1]:8000", "::1"), ("10.0.0.7", "10.0.0.7"),
    ("kiosk.local.", "kiosk.local"), ("[fe80::1", ""),
])
def test_host_names_are_read_as_browsers_send_them(header, name):
    assert host_name(header) == name


def test_the_environment_token_overrides_the_file(tmp_path):
    from tests.server.helpers import settings_for

    settings = settings_for(tmp_path, access__operator_token="from-the-file-000000")
    assert AccessPolicy.from_settings(settings, {}).token == "from-the-file-000000"
    env = {"DAYLIT_OPERATOR_TOKEN": "from-the-env-11111111"}
    assert AccessPolicy.from_settings(settings, env).token == "from-the-env-11111111"
