"""The newest item only: a one-place mailbox between a source that must never wait and a
slower consumer (measuring, JPEG-encoding and estimating frames all run behind a camera)."""

from __future__ import annotations

import asyncio
from typing import Generic, TypeVar

T = TypeVar("T")


class Newest(Generic[T]):
    """``put`` replaces whatever still waits (so a slow consumer skips to the newest); ``take``
    waits for the next item."""

    def __init__(self) -> None:
        self._item: T | None = None
        self._event = asyncio.Event()

    def put(self, item: T) -> bool:
        """Leave ``item`` for the consumer; True when it replaced one not yet taken."""
        replaced = self._item is not None
        self._item = item
        self._event.set()
        return replaced

    async def take(self) -> T:
        """The newest item, once one has been put since the last take."""
        while True:
            await self._event.wait()
            self._event.clear()
            item, self._item = self._item, None
            if item is not None:
                return item
