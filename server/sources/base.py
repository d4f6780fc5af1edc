"""The interface every frame source follows."""

from __future__ import annotations

from collections.abc import Callable

from server.measure import Frame
from server.protocol import Flags

Deliver = Callable[[Frame], None]


class Source:
    """A source of frames.

    Attributes
    ----------
    name : str
        How it is shown in logs and ``/api/status`` (e.g. ``camera:0``).
    flags : Flags
        Stream flags every vector measured from it carries (SIMULATED, REPLAY).
    connected : bool
        False while a live source is reconnecting.
    """

    name = "source"
    flags = Flags.NONE
    connected = True

    async def run(self, deliver: Deliver) -> None:
        raise NotImplementedError

    def status(self) -> dict:
        """Extra fields for ``/api/status``."""
        return {}
