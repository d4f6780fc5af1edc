"""Waiting between retries: the delay doubles from a minimum to a maximum, and starts over
after a success.

One rule for every loop that reconnects or restarts (the supervisor of background tasks, the
fan-out worker's feed and broker links, the measuring process's broker publisher), so they
all back off alike and a change of rule is made once.
"""

from __future__ import annotations

import asyncio


class Backoff:
    """The delay before the next retry, in seconds: ``min_s``, doubling up to ``max_s``."""

    def __init__(self, min_s: float, max_s: float):
        if not 0 < min_s <= max_s:
            raise ValueError(f"back-off needs 0 < min_s <= max_s, got {min_s}, {max_s}")
        self.min_s = min_s
        self.max_s = max_s
        self.delay_s = min_s

    async def wait(self) -> None:
        """Sleep the current delay, then double it (up to ``max_s``)."""
        await asyncio.sleep(self.delay_s)
        self.delay_s = min(2.0 * self.delay_s, self.max_s)

    def reset(self) -> None:
        """After a success: the next retry waits ``min_s`` again."""
        self.delay_s = self.min_s
