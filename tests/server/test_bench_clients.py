"""bench_stream.py's two client kinds (benchmarks/stream_clients.py) read the same stream.

aiohttp's client and picows' on the same light server (the real hub and its direct frame
writes) must record the same messages: the sequence numbers the server published, in order,
and the same message sizes, so the benchmark's comparison of the two measures speed only.
"""

import asyncio

import numpy as np
import pytest

from benchmarks.stream_clients import Receipts, make_clients
from server import protocol
from server.app import HUB, create_app
from tests.server.helpers import ManualSource, settings_for, wait_for

pytest.importorskip("picows")

CLIENTS = 12  # of each kind
VECTORS = 25


@pytest.mark.parametrize("version", [2, 3])
async def test_aiohttp_and_picows_clients_record_the_same_sequences(
        aiohttp_client, build_dir, tmp_path, version):
    app = create_app(build_dir, settings_for(tmp_path), sky_source=ManualSource())
    client = await aiohttp_client(app)
    url = str(client.make_url(f"/ws/light?protocol={version}"))
    kinds = {}
    for lib in ("aiohttp", "picows"):
        receipts = Receipts(CLIENTS, keep_sequences=True)
        receipts.measuring = True
        conns = make_clients(lib, url, receipts)
        await conns.open(CLIENTS)
        kinds[lib] = receipts, conns
    await wait_for(lambda: len(app[HUB].clients) == 2 * CLIENTS)

    n = 40
    rng = np.random.default_rng(7)
    sent = []
    for k in range(VECTORS):
        rgb = rng.uniform(0, 100, (n, 3)).astype(np.float32)
        sent.append(app[HUB].publish_light(rgb, np.zeros(n, bool), 1000.0 + k, 0))
        # The stream is newest-only: wait until everyone has this one before the next.
        await wait_for(lambda: all(len(s) == len(sent) for r, _ in kinds.values()
                                   for s in r.sequences))
        if k % 5 == 0:
            await asyncio.sleep(0.05)  # the senders idle: the next goes by direct write

    size = protocol.light_message_bytes(n, version)
    for lib, (receipts, _) in kinds.items():
        assert receipts.sequences == [sent] * CLIENTS, lib
        assert [len(x) for x in receipts.latencies_s] == [VECTORS] * CLIENTS, lib
        assert receipts.sizes == {size}, lib
    assert kinds["picows"][1].fragments == 0
    for _, conns in kinds.values():
        await conns.close()
