"""The build's files checked against the manifest's SHA-256 before they are served as immutable.

A file requested as ``/build/PATH?v=<sha256 prefix>`` may be cached by browsers for a year
(``Cache-Control: immutable``): a file damaged on disk would then stay damaged in every browser
that fetched it, even after it is repaired. :class:`BuildIntegrity` hashes each listed file
once, when the server starts (:meth:`check_all`, in a thread, while the server already answers)
or at its first request, and again whenever its size or modification time changes; a file whose
bytes do not match is answered ``503 Service Unavailable`` (``no-store``) with one ERROR log line
naming it, until it is repaired (its new size or time makes it checked again).

Verdicts are kept per path with the ``(st_size, st_mtime_ns)`` they were made for; concurrent
requests for a file being hashed wait for the one hash.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
from pathlib import Path

log = logging.getLogger("daylit.integrity")

CHUNK_BYTES = 1 << 20


def sha256_file(path: Path) -> str:
    """The hex SHA-256 of a file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            digest.update(chunk)
    return digest.hexdigest()


class BuildIntegrity:
    """Verdicts on a build's files.

    Parameters
    ----------
    build_dir : Path
    expected : dict of str to str
        Manifest path -> hex SHA-256 (``manifest["files"]``), for the files it will check.
    """

    def __init__(self, build_dir: Path, expected: dict[str, str]):
        self.build_dir = Path(build_dir)
        self.expected = dict(expected)
        # path -> ((size, mtime_ns), intact)
        self._verdicts: dict[str, tuple[tuple[int, int], bool]] = {}
        self._pending: dict[str, asyncio.Future] = {}
        self.mismatches: set[str] = set()  # paths found damaged at their current stat

    @staticmethod
    def _key(stat: os.stat_result) -> tuple[int, int]:
        return (stat.st_size, stat.st_mtime_ns)

    def _judge(self, rel: str, path: Path) -> tuple[tuple[int, int], bool]:
        """Hash one file (blocking) and log a mismatch."""
        key = self._key(path.stat())
        actual = sha256_file(path)
        intact = actual == self.expected[rel]
        if intact:
            self.mismatches.discard(rel)
        else:
            self.mismatches.add(rel)
            log.error("build file %s does not match the manifest (sha256 %s…, the manifest says "
                      "%s…, %d bytes): it is answered 503 until it is repaired (re-bake or "
                      "copy the build again)", rel, actual[:16], self.expected[rel][:16], key[0])
        return key, intact

    async def intact(self, rel: str, path: Path) -> bool:
        """Whether the file ``rel`` (at ``path``) matches the manifest now; True for a path
        the manifest gives no checksum for."""
        if rel not in self.expected:
            return True
        key = self._key(path.stat())
        verdict = self._verdicts.get(rel)
        if verdict is not None and verdict[0] == key:
            return verdict[1]
        pending = self._pending.get(rel)
        if pending is None:
            pending = asyncio.ensure_future(asyncio.to_thread(self._judge, rel, path))
            self._pending[rel] = pending
            pending.add_done_callback(lambda _: self._pending.pop(rel, None))
        try:
            judged_key, ok = await asyncio.shield(pending)
        except OSError as exc:
            log.error("cannot read build file %s: %s", rel, exc)
            return False
        self._verdicts[rel] = (judged_key, ok)
        return ok if judged_key == key else await self.intact(rel, path)

    async def check_all(self) -> int:
        """Check every file once (at start); returns how many do not match (or are missing)."""
        bad = 0
        for rel in sorted(self.expected):
            path = self.build_dir / rel
            try:
                ok = await self.intact(rel, path)
            except FileNotFoundError:
                log.error("build file %s is missing (the manifest lists it)", rel)
                ok = False
            bad += not ok
        checked = len(self.expected)
        if bad:
            log.error("%d of %d build files do not match the manifest", bad, checked)
        else:
            log.info("all %d build files match the manifest's SHA-256", checked)
        return bad
