"""The relay message between the measuring process and fan-out workers (server.relay), the
worker's hub fed by it, and the settings that choose the processes."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from server import protocol
from server.config import ConfigError, load_settings
from server.lightstream import LIGHT, LightHub
from server.relay import Inbox, Outbox, RelayError, decode, encode


def hand_made(header: dict, *blobs: bytes) -> bytes:
    """The documented layout, written here without server.relay."""
    head = json.dumps(header).encode()
    return b"DLR1" + struct.pack("<I", len(head)) + head + b"".join(blobs)


def test_a_message_has_the_documented_layout():
    data = encode("light", 7, {"1": b"abc", "2": b"defgh"})
    header = {"kind": "light", "seq": 7, "blobs": [["1", 3], ["2", 5]]}
    m = decode(hand_made(header, b"abc", b"defgh"))
    assert (m.kind, m.seq, m.blobs) == ("light", 7, {"1": b"abc", "2": b"defgh"})
    assert data[:4] == b"DLR1"
    (n,) = struct.unpack_from("<I", data, 4)
    assert json.loads(data[8:8 + n]) == header and data[8 + n:] == b"abcdefgh"


@pytest.mark.parametrize("data", [
    b"", b"DLR0" + bytes(8), b"DLR1" + struct.pack("<I", 99) + b"{}",
    hand_made({"kind": "light"}), hand_made({"kind": "nope", "seq": 1, "blobs": []}),
    hand_made({"kind": "light", "seq": 1, "blobs": [["1", 10]]}, b"short"),
    hand_made({"kind": "light", "seq": 1, "blobs": [["1", 2]]}, b"toolong"),
    b"DLR1" + struct.pack("<I", 3) + b"{x}",
])
def test_malformed_messages_are_refused(data):
    with pytest.raises(RelayError):
        decode(data)


def linked_hubs() -> tuple[LightHub, LightHub, Inbox]:
    """A measuring hub whose relay messages go straight into a worker hub's inbox (stale
    after 3 s): (measuring hub, worker hub, inbox)."""
    measuring = LightHub(lambda streams, version=1: "{}")
    outbox = Outbox()
    outbox.attach(measuring)
    worker = LightHub(lambda streams, version=1: "{}")
    inbox = Inbox(worker, stale_after_s=3.0)
    outbox.listeners.append(lambda kind, message: inbox.apply(message))
    return measuring, worker, inbox


def test_a_worker_hub_sends_the_measuring_hubs_bytes():
    """The measuring hub encodes; the worker's hub gets the same bytes and sequence, and a
    malformed message in between changes nothing."""
    measuring, worker, inbox = linked_hubs()
    rgb = np.arange(120, dtype=np.float32).reshape(40, 3)
    seq = measuring.publish_light(rgb, np.zeros(40, bool), 12.5, 0)
    inbox.apply(b"garbage")
    assert worker.latest[LIGHT] == measuring.latest[LIGHT]
    assert worker.sequence[LIGHT] == seq
    m = protocol.decode(worker.latest[LIGHT][1][1])
    assert m.sequence == seq and np.array_equal(m.rgb, rgb)
    measuring.publish_frame(b"jpeg", 13.0, 0, mask_payload=b"mask")
    assert worker.latest_frame == measuring.latest_frame
    assert inbox.bad_messages == 1 and inbox.messages == 2 and not inbox.stale


def test_a_silent_link_resends_the_last_vector_marked_stale(monkeypatch):
    """Past the stale time the worker re-publishes its last vector with the STALE flag (bit 0
    of the uint16 at byte 6, docs/protocol.md), same sequence, every other byte the same;
    once; and the next vector from the measuring process is published as it came."""
    measuring, worker, inbox = linked_hubs()
    rgb = np.arange(120, dtype=np.float32).reshape(40, 3)
    seq = measuring.publish_light(rgb, np.zeros(40, bool), 12.5, protocol.Flags.SIMULATED)
    fresh = dict(worker.latest[LIGHT][1])
    assert not inbox.mark_stale_if_lost()  # not silent yet
    now = inbox.last_message_s
    monkeypatch.setattr("server.relay.time.monotonic", lambda: now + 3.5)
    assert inbox.mark_stale_if_lost()
    stale_seq, stale = worker.latest[LIGHT]
    assert stale_seq == seq and set(stale) == set(fresh)
    for version, message in stale.items():
        flags = struct.unpack_from("<H", message, 6)[0]
        assert flags == protocol.Flags.SIMULATED | 1
        assert message[:6] == fresh[version][:6] and message[8:] == fresh[version][8:]
        assert protocol.decode(message).flags & protocol.Flags.STALE
    assert not inbox.mark_stale_if_lost()  # once
    measuring.publish_light(rgb, np.zeros(40, bool), 13.0, protocol.Flags.SIMULATED)
    assert worker.latest[LIGHT] == measuring.latest[LIGHT]
    assert not protocol.decode(worker.latest[LIGHT][1][3]).flags & protocol.Flags.STALE


def test_status_tells_the_worker_which_streams_exist():
    worker = LightHub(lambda streams, version=1: "{}")
    inbox = Inbox(worker, stale_after_s=3.0)
    assert inbox.stale  # nothing yet
    inbox.apply(encode("status", 0, status={"source": "sim"},
                       hello={"source": "sim", "site_camera": {"size": [4, 3]},
                              "occlusion": None}))
    assert inbox.status == {"source": "sim"} and inbox.has_status.is_set()
    assert worker.site_camera_available and not worker.occlusion_available


@pytest.mark.parametrize("overrides, says", [
    ({"server.role": "fanout"}, "needs a broker"),
    ({"server.role": "measure", "server.broker": "redis://h:6379/0", "server.workers": 2},
     "runs no fan-out workers"),
    ({"server.broker": "http://h"}, "redis://HOST:PORT/DB or local:PATH"),
    ({"server.broker": "local:"}, "needs the path"),
    ({"server.role": "both"}, "all | measure | fanout"),
])
def test_serving_settings_are_checked(overrides, says):
    with pytest.raises(ConfigError, match=says.replace("|", r"\|")):
        load_settings(None, overrides)


def test_the_default_is_one_process():
    srv = load_settings().server
    assert (srv.workers, srv.broker, srv.role) == (1, "", "all")
