"""Faults at the light stream's edge (issue 19): requests refused by the HTTP layer in the
log, the client message size limit, and clients dropped by the heartbeat."""

from __future__ import annotations

import asyncio
import json
import logging
import socket

from aiohttp import WSMsgType

from server import protocol
from server.app import create_app
from tests.server.helpers import raw_websocket_that_never_reads, settings_for, wait_for


async def test_refused_requests_are_warnings_without_a_traceback(
        aiohttp_client, build_dir, tmp_path, caplog):
    from tests.server.helpers import ManualSource

    client = await aiohttp_client(create_app(build_dir, settings_for(tmp_path),
                                             sky_source=ManualSource()))
    caplog.set_level(logging.DEBUG)
    port = client.server.port
    for request in (b"GET /" + b"a" * 20000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",
                    b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + b"b" * 20000 + b"\r\n\r\n"):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(request)
        await writer.drain()
        answer = await asyncio.wait_for(reader.read(), 10)
        writer.close()
        status = int(answer.split(b" ", 2)[1])
        assert 400 <= status < 500, answer[:100]
    await asyncio.sleep(0.1)
    server_records = [r for r in caplog.records if r.name == "aiohttp.server"]
    assert server_records, "the refusals were not logged at all"
    assert all(r.levelno == logging.WARNING for r in server_records), \
        [(r.levelname, r.getMessage()) for r in server_records]
    assert all(r.exc_info is None and not r.exc_text for r in server_records)
    assert all("127.0.0.1" in r.getMessage() for r in server_records)


async def test_a_text_message_of_exactly_1024_bytes_is_accepted(aiohttp_client, build_dir,
                                                                tmp_path):
    from tests.server.helpers import ManualSource

    client = await aiohttp_client(create_app(build_dir, settings_for(tmp_path),
                                             sky_source=ManualSource()))
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    head = '{"type":"ping","id":7'  # padded with JSON whitespace to the limit
    text = head + " " * (protocol.MAX_CLIENT_MESSAGE_BYTES - len(head) - 1) + "}"
    assert len(text.encode()) == 1024
    await ws.send_str(text)
    pong = await ws.receive(timeout=10)
    assert pong.type == WSMsgType.TEXT and json.loads(pong.data) == {
        "type": "pong", "id": 7, "server_time_s": json.loads(pong.data)["server_time_s"]}
    await ws.send_str(head + " " + text[len(head):])  # 1,025 bytes: over the limit
    closed = await ws.receive(timeout=10)
    assert closed.type in (WSMsgType.CLOSE, WSMsgType.CLOSED)
    assert ws.close_code == 1009


async def test_a_client_dropped_by_the_heartbeat_is_logged(aiohttp_client, build_dir, tmp_path,
                                                           caplog):
    from tests.server.helpers import ManualSource

    settings = settings_for(tmp_path, server__heartbeat_s=0.4)
    client = await aiohttp_client(create_app(build_dir, settings, sky_source=ManualSource()))
    caplog.set_level(logging.INFO)
    sock: socket.socket = await raw_websocket_that_never_reads(client.server.port)
    try:
        await wait_for(lambda: any("heartbeat" in r.getMessage() for r in caplog.records), 20)
    finally:
        sock.close()
    line = next(r for r in caplog.records if "heartbeat" in r.getMessage())
    assert "127.0.0.1" in line.getMessage() and line.levelno == logging.WARNING
