"""The write stage runs atlases and views two at a time (bake.pipeline._run_units)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from bake import basisu, compress, quantize
from bake.errors import BakeError
from bake.pipeline import _run_units


def test_entries_come_back_in_the_order_given_whatever_finishes_first():
    started = []

    def unit(name, seconds):
        def run():
            started.append((name, threading.current_thread().name))
            time.sleep(seconds)
            return name

        return run

    entries = _run_units([unit("hull", 0.3), unit("ground", 0.0), unit("kiosk", 0.0)], 2)
    assert entries == ["hull", "ground", "kiosk"]
    # The slow first unit did not hold up the others: they ran on the other thread meanwhile.
    assert len({thread for _, thread in started}) == 2


def _tiny_png(path):
    quantize.write_png(path, np.full((8, 8, 3), 128, np.uint8))
    return path


def test_a_failure_stops_the_other_units_encoders_and_is_raised_once_they_stopped(tmp_path):
    png = _tiny_png(tmp_path / "layer.png")
    other_started, finished = threading.Event(), threading.Event()
    refused = []

    def fails():
        assert other_started.wait(5.0)  # fail while the other unit is at work
        raise BakeError("basisu failed (1): bad PNG")

    def encodes_until_stopped():
        other_started.set()
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            out = tmp_path / f"out{len(refused)}"
            out.mkdir(exist_ok=True)
            try:
                basisu.encode([png], out, compress.Settings(), array=False)
            except basisu.CompressionError as exc:
                refused.append(str(exc))
                break
        finished.set()
        return "other"

    with pytest.raises(BakeError, match="basisu failed"):
        _run_units([fails, encodes_until_stopped], 2)
    assert finished.is_set()  # nothing still writes into the staging folder after the error
    assert refused and refused[0].startswith("stopped")

    # The next write stage encodes again.
    def encodes():
        basisu.encode([png], tmp_path, compress.Settings(), array=False)
        return (tmp_path / "layer.ktx2").is_file()

    assert _run_units([encodes], 2) == [True]
