"""Decoding KTX2 with three.js's own Basis transcoder (the browser's code path, not the
encoder's) in long-running Node processes: ``node tools/decode_ktx2.mjs --serve`` loads the
transcoder once and answers decode requests over stdin/stdout, so a write stage pays that
load (about 0.45 s of CPU) once per writing thread instead of once per decode (84 launches on
the draft demo; docs/benchmarks.md, "One Node decoder per writing thread").

Processes are kept in a pool for this Python process: a call takes an idle one (or starts
one), so there are as many as threads decoding at once. :func:`close_decoders` ends them;
the write stage calls it when its units are done or have failed (bake.pipeline), a cluster
bake on every worker when it ends (bake.cluster), and it is registered with ``atexit``. A
decoder also ends by itself when its stdin closes, i.e. when this process dies.
"""

from __future__ import annotations

import atexit
import contextlib
import shutil
import struct
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np

from bake.basisu import REPO_ROOT, CompressionError, check_not_stopped

TOOL = REPO_ROOT / "tools" / "decode_ktx2.mjs"
_HEADER = struct.Struct("<5I")  # width, height, layers, levels, isUASTC
_ANSWER = struct.Struct("<2I")  # status (0 decoded, 1 failed), byte count
_CLOSE_WAIT_S = 10.0


class Decoder:
    """One ``node tools/decode_ktx2.mjs --serve`` process; not for two threads at once."""

    def __init__(self):
        node = shutil.which("node")
        if node is None:
            raise CompressionError(
                "Node.js is missing (`node` is not on the PATH), needed to check the KTX2 "
                f"files: install Node 20 or newer, then run `npm ci` in {REPO_ROOT}"
            )
        # Kept open for the process's life (its stderr), closed by close().
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115
        self._stderr_tail = ""
        # Node runs in the repository (to find three.js); the paths sent are absolute.
        try:
            self.process = subprocess.Popen(
                [node, str(TOOL), "--serve"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self._stderr,
                cwd=REPO_ROOT,
            )
        except OSError as exc:
            self._stderr.close()
            raise CompressionError(
                f"Node.js does not start ({exc}): install Node 20 or newer"
            ) from None

    def decode(self, path: Path) -> np.ndarray:
        """The RGBA8 texels of level 0 of every layer of the KTX2 file ``path``:
        ``(layers, H, W, 4)`` uint8, rows from the top. A file the transcoder refuses is a
        :class:`CompressionError` and the decoder stays usable."""
        request = str(Path(path).absolute()).encode("utf-8")
        try:
            self.process.stdin.write(struct.pack("<I", len(request)) + request)
            self.process.stdin.flush()
        except OSError:
            raise self._stopped() from None
        status, size = _ANSWER.unpack(self._read(_ANSWER.size))
        body = self._read(size)
        if status != 0:
            raise CompressionError(f"decoding KTX2 failed: {body.decode('utf-8', 'replace')}")
        width, height, layers, _, _ = _HEADER.unpack_from(body)
        return np.frombuffer(body, np.uint8, offset=_HEADER.size).reshape(
            layers, height, width, 4
        )

    def _read(self, size: int) -> bytes:
        data = self.process.stdout.read(size)
        if len(data) < size:
            raise self._stopped()
        return data

    def _stopped(self) -> CompressionError:
        """The error for a decoder that ended while in use (it is closed)."""
        self.close()
        return CompressionError(
            f"the KTX2 decoder (node {TOOL.relative_to(REPO_ROOT)} --serve) stopped with exit "
            f"code {self.process.returncode}: {self._stderr_tail or 'no message'}; check that "
            f"`node tools/decode_ktx2.mjs` runs in {REPO_ROOT} (`npm ci` installs three.js)"
        )

    def close(self) -> None:
        """End the process (stdin closed, killed if it does not end within 10 s) and reap it."""
        if self.process.poll() is None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
            try:
                self.process.wait(timeout=_CLOSE_WAIT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        for stream in (self.process.stdin, self.process.stdout):
            with contextlib.suppress(OSError):
                stream.close()
        if not self._stderr.closed:
            self._stderr.seek(0)
            self._stderr_tail = self._stderr.read()[-500:].decode("utf-8", "replace").strip()
            self._stderr.close()


_lock = threading.Lock()
_idle: list[Decoder] = []
_generation = 0  # raised by close_decoders: decoders busy then are closed when given back
_started: list[subprocess.Popen] = []  # every decoder process started here


def launches() -> int:
    """Decoder processes started by this Python process so far."""
    return len(_started)


def running() -> int:
    """Decoder processes of this Python process still running (none after a bake)."""
    return sum(p.poll() is None for p in _started)


def _take() -> tuple[Decoder, int]:
    with _lock:
        if _idle:
            return _idle.pop(), _generation
        generation = _generation
    decoder = Decoder()
    with _lock:
        _started.append(decoder.process)
    return decoder, generation


def _give_back(decoder: Decoder, generation: int) -> None:
    with _lock:
        if generation == _generation and decoder.process.poll() is None:
            _idle.append(decoder)
            return
    decoder.close()


def decode(files: list[Path]) -> list[np.ndarray]:
    """Decode KTX2 files with three.js's Basis transcoder under Node: a list of
    ``(layers, H, W, 4)`` uint8 arrays, one per file."""
    if not files:
        return []
    check_not_stopped()
    decoder, generation = _take()
    try:
        arrays = [decoder.decode(f) for f in files]
    except CompressionError:
        _give_back(decoder, generation)  # closed already if it died; usable if a file failed
        raise
    except BaseException:
        decoder.close()  # interrupted mid-answer: its stream is no longer in step
        raise
    _give_back(decoder, generation)
    return arrays


def close_decoders() -> None:
    """End every decoder process of this Python process (idle ones now, busy ones when the
    call using them returns)."""
    global _generation
    with _lock:
        idle = list(_idle)
        _idle.clear()
        _generation += 1
    for decoder in idle:
        decoder.close()


atexit.register(close_decoders)
