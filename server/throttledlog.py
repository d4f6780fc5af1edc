"""Warnings that repeat (a bad frame in every frame of a broken camera) logged at most once per
interval for each reason, with how many were held back since the last line."""

from __future__ import annotations

import logging
import time


class ThrottledWarnings:
    """``warn(key, message)`` logs ``message`` unless a warning with the same ``key`` was
    logged less than ``interval_s`` ago; the next line that gets through says how many were
    held back."""

    def __init__(self, logger: logging.Logger, interval_s: float):
        self.logger = logger
        self.interval_s = interval_s
        self._last: dict[str, tuple[float, int]] = {}  # key -> (monotonic s, held back)

    def warn(self, key: str, message: str) -> None:
        now = time.monotonic()
        last, held = self._last.get(key, (-float("inf"), 0))
        if now - last >= self.interval_s:
            suffix = f" ({held} more like it since the last report)" if held else ""
            self.logger.warning("%s%s", message, suffix)
            self._last[key] = (now, 0)
        else:
            self._last[key] = (last, held + 1)
