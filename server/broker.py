"""The Redis link between a measuring process and fan-out workers on other machines.

``--broker redis://HOST:PORT/DB``: the measuring process PUBLISHes each relay message
(:mod:`server.relay`, the encoded protocol bytes and their sequence number) on the channel
``daylit:<scene id>`` and SETs it as the newest of its kind (``daylit:<scene id>:<kind>``,
expiring after :data:`LATEST_TTL_S`); a fan-out worker SUBSCRIBEs to the channel and, each time
it (re)subscribes, GETs the newest of each kind, so it has the current vector at once.
Several sites may share one Redis: the scene id keeps them apart.

Redis going away does not stop either side: the publisher keeps only the newest message of
each kind while it cannot publish and retries (:data:`RETRY_S`), the subscriber
reconnects on the same schedule; each logs once per 10 s meanwhile. Only at start is an
unreachable broker an error (:class:`BrokerError`), so a wrong address is seen at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from urllib.parse import urlsplit, urlunsplit

import redis.asyncio as aioredis
from redis.exceptions import RedisError

from server.backoff import Backoff
from server.relay import KINDS, Inbox, Outbox
from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.broker")

LATEST_TTL_S = 60
CONNECT_TIMEOUT_S = 3.0
RETRY_S = (0.05, 2.0)  # back-off of both sides while Redis is away: first and longest wait
HEALTH_CHECK_S = 5  # a subscriber idle this long pings Redis (a dead link is found)
LINK_ERRORS = (RedisError, OSError, asyncio.TimeoutError)


class BrokerError(RuntimeError):
    """The broker cannot be reached at start (the message says what to do)."""


def redacted(url: str) -> str:
    """``url`` without its password (for logs and ``/api/status``)."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)[1]
    user = parts.username or ""
    return urlunsplit(parts._replace(netloc=f"{user}:***@{netloc}"))


def channel(scene_id: str) -> str:
    return f"daylit:{scene_id}"


def connect(url: str) -> aioredis.Redis:
    return aioredis.Redis.from_url(url, socket_connect_timeout=CONNECT_TIMEOUT_S,
                                   socket_keepalive=True, health_check_interval=HEALTH_CHECK_S)


async def check(url: str) -> None:
    """PING the broker once; :class:`BrokerError` (saying what to do) if it does not answer."""
    client = connect(url)
    try:
        await asyncio.wait_for(client.ping(), CONNECT_TIMEOUT_S + 1.0)
    except (*LINK_ERRORS, ValueError) as exc:
        raise BrokerError(
            f"cannot reach the broker {redacted(url)}: {exc or type(exc).__name__}. Start "
            "Redis there (Debian: apt-get install redis-server; systemctl start "
            "redis-server), or give the right --broker redis://HOST:PORT/DB") from None
    finally:
        await client.aclose()


class RedisPublisher:
    """The measuring side: publishes what the :class:`server.relay.Outbox` is given."""

    def __init__(self, url: str, scene_id: str, outbox: Outbox):
        self.url = url
        self.channel = channel(scene_id)
        self.outbox = outbox
        self.pending: dict[str, bytes] = {}  # newest unpublished message of each kind
        self._wake = asyncio.Event()
        self.connected = False
        self.published = 0
        self.failures = 0
        self._warnings = ThrottledWarnings(log, 10.0)
        self._client: aioredis.Redis | None = None
        outbox.listeners.append(self._queue)

    async def start(self) -> None:
        await check(self.url)
        self._client = connect(self.url)
        self.connected = True

    def _queue(self, kind: str, message: bytes) -> None:
        self.pending[kind] = message
        self._wake.set()

    async def run(self) -> None:
        backoff = Backoff(*RETRY_S)
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self.pending:
                kind = next(iter(self.pending))
                message = self.pending.pop(kind)
                try:
                    async with self._client.pipeline(transaction=False) as pipe:
                        pipe.publish(self.channel, message)
                        pipe.set(f"{self.channel}:{kind}", message, ex=LATEST_TTL_S)
                        await pipe.execute()
                except LINK_ERRORS as exc:
                    self.pending.setdefault(kind, message)  # unless a newer one came
                    self.failures += 1
                    if self.connected:
                        log.warning("lost the broker %s: %s; keeping the newest message of "
                                    "each kind and retrying", redacted(self.url), exc)
                    else:
                        self._warnings.warn("down", f"the broker {redacted(self.url)} is "
                                            f"still unreachable: {exc}")
                    self.connected = False
                    await backoff.wait()
                    continue
                if not self.connected:
                    log.info("broker %s reachable again", redacted(self.url))
                self.connected = True
                backoff.reset()
                self.published += 1

    async def close(self) -> None:
        if self._client is not None:
            with contextlib.suppress(*LINK_ERRORS):
                await self._client.aclose()

    def status(self) -> dict:
        return {"broker": redacted(self.url), "channel": self.channel,
                "connected": self.connected, "published": self.published,
                "publish_failures": self.failures, "pending": len(self.pending)}


class RedisSubscriber:
    """The worker side: the channel into an :class:`server.relay.Inbox`, reconnecting."""

    def __init__(self, url: str, scene_id: str):
        self.url = url
        self.channel = channel(scene_id)
        self._warnings = ThrottledWarnings(log, 10.0)

    async def check(self) -> None:
        await check(self.url)

    async def run(self, inbox: Inbox) -> None:
        backoff = Backoff(*RETRY_S)
        while True:
            client = connect(self.url)
            pubsub = client.pubsub()
            try:
                await pubsub.subscribe(self.channel)
                for kind in KINDS:  # what was published before this subscription
                    latest = await client.get(f"{self.channel}:{kind}")
                    if latest is not None:
                        inbox.apply(latest)
                if not inbox.connected:
                    log.info("subscribed to %s on the broker %s", self.channel,
                             redacted(self.url))
                inbox.connected = True
                inbox.connects += 1
                backoff.reset()
                while True:
                    msg = await pubsub.get_message(ignore_subscribe_messages=True,
                                                   timeout=1.0)
                    if msg is not None and msg["type"] == "message":
                        inbox.apply(msg["data"])
            except LINK_ERRORS as exc:
                inbox.last_error = f"broker {redacted(self.url)}: {exc}"
                if inbox.connected:
                    log.warning("lost the broker %s: %s; reconnecting", redacted(self.url), exc)
                else:
                    self._warnings.warn("down", f"the broker {redacted(self.url)} is still "
                                        f"unreachable: {exc}")
                inbox.connected = False
            finally:
                with contextlib.suppress(*LINK_ERRORS):
                    await pubsub.aclose()
                    await client.aclose()
            await backoff.wait()
