"""Deterministic for a seed, whatever the worker count; an interrupted bake resumes."""

from __future__ import annotations

import errno
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bake import writers
from bake.errors import BakeError
from bake.pipeline import bake
from daylit.stackio import read_stack_exr
from tests.sites import make_site

QUIET = {"progress": False, "log": lambda msg: None}


def _stacks(build: Path) -> dict:
    return {
        p.relative_to(build).as_posix(): read_stack_exr(p)
        for p in build.rglob("*.exr")
        if not p.name.endswith("depth.exr")
    }


def _scene(tmp_path: Path) -> Path:
    # Fine enough to need several chunks, small enough to bake in seconds.
    return make_site(
        tmp_path / "scene", lights=160, direct_rays=320, hull_texel_m=0.1, ground_texel_m=0.25
    )


def test_same_seed_same_result_with_one_or_two_workers(tmp_path):
    scene = _scene(tmp_path)
    bake(scene, tmp_path / "one", workers=1, **QUIET)
    bake(scene, tmp_path / "two", workers=2, **QUIET)
    one, two = _stacks(tmp_path / "one"), _stacks(tmp_path / "two")
    assert one.keys() == two.keys() and len(one) >= 5
    for name in one:
        assert np.array_equal(one[name], two[name]), name


def _bake_command(scene: Path, out: Path, *options: str) -> list[str]:
    return [sys.executable, "-m", "daylit.cli", "bake", str(scene), "-o", str(out),
            "--no-progress", *options]


def _ctrl_c_when(command: list[str], ready, wait_s: float):
    """Run ``command``, press Ctrl-C once ``ready()`` (or after ``wait_s``), and let it end.
    Returns (exit status, stderr, whether it was still running when interrupted)."""
    # Ctrl-C's default action in the child even if this run ignores SIGINT (a background job
    # of a non-interactive shell does, and the child would inherit it).
    process = subprocess.Popen(
        command, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not ready():
        time.sleep(0.05)
    running = process.poll() is None
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    return process.returncode, err, running


def test_interrupted_bake_resumes_and_matches(tmp_path):
    scene = _scene(tmp_path)
    bake(scene, tmp_path / "reference", workers=2, **QUIET)
    out = tmp_path / "out"
    partial = tmp_path / ".out.partial"
    command = _bake_command(scene, out, "--workers", "1")
    status, err, _ = _ctrl_c_when(
        command, lambda: list((partial / "chunks").glob("atlas-*.chunk")), wait_s=120
    )
    assert status == 130, err
    assert not out.exists()  # nothing half-written where the build goes
    done = len(list((partial / "chunks").glob("*.chunk")))
    assert done >= 2

    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"resuming: {done} chunks already baked" in result.stderr
    assert not partial.exists()
    reference, resumed = _stacks(tmp_path / "reference"), _stacks(out)
    for name in reference:
        assert np.array_equal(reference[name], resumed[name]), name


def test_ctrl_c_while_writing_stops_the_bake_and_the_next_run_finishes_it(tmp_path):
    """Interrupted in the write stage (atlases and views two at a time in threads, with
    their encoders), the bake exits 130 leaving no output, and the next run re-uses every
    traced chunk."""
    scene = _scene(tmp_path)
    out, partial = tmp_path / "out", tmp_path / ".out.partial"
    command = _bake_command(scene, out)
    status, err, running = _ctrl_c_when(
        command, lambda: list((partial / "build" / "exr").glob("*.exr")), wait_s=240
    )
    assert running, "the bake ended before its write stage could be interrupted"
    assert status == 130, err
    assert "interrupted while writing" in err and "run the same command again" in err
    assert not out.exists()
    chunks = len(list((partial / "chunks").glob("*.chunk")))

    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"resuming: {chunks} chunks already baked" in result.stderr
    assert "every chunk re-used from the earlier run" in result.stderr  # not "0.0 M rays"
    assert (out / "manifest.json").is_file() and not partial.exists()


def test_a_full_disk_ends_the_bake_with_what_to_do_and_keeps_the_chunks(tmp_path, monkeypatch):
    """Out of space while writing the masters: a BakeError that says to free space and run
    again, no output, every traced chunk kept; the next run re-uses them all."""
    scene = _scene(tmp_path)
    out, partial = tmp_path / "out", tmp_path / ".out.partial"

    def full_disk(path, *args, **kwargs):
        raise OSError(errno.ENOSPC, f"no space left on device writing {path}")

    # Every master (an atlas's, a view's, a sun-bounce stack's) is written from its store.
    monkeypatch.setattr(writers, "write_stack_exr_by_rows", full_disk)
    with pytest.raises(BakeError, match="no space left") as caught:
        bake(scene, out, **QUIET)
    assert "free space" in str(caught.value) and "run the same command again" in str(caught.value)
    assert str(partial) in str(caught.value)
    assert not out.exists()
    chunks = len(list((partial / "chunks").glob("*.chunk")))
    assert chunks >= 2

    monkeypatch.undo()
    messages = []
    bake(scene, out, progress=False, log=messages.append)
    assert any(f"resuming: {chunks} chunks already baked" in m for m in messages)
    assert any("every chunk re-used from the earlier run" in m for m in messages)
    assert (out / "manifest.json").is_file() and not partial.exists()

