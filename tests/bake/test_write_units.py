"""The write stage runs atlases and views two at a time (bake.pipeline._run_two_at_a_time)."""

from __future__ import annotations

import threading
import time

import pytest

from bake.pipeline import BakeError, _run_two_at_a_time


def test_entries_come_back_in_the_order_given_whatever_finishes_first():
    started = []

    def unit(name, seconds):
        def run():
            started.append((name, threading.current_thread().name))
            time.sleep(seconds)
            return name

        return run

    entries = _run_two_at_a_time([unit("hull", 0.3), unit("ground", 0.0), unit("kiosk", 0.0)])
    assert entries == ["hull", "ground", "kiosk"]
    # The slow first unit did not hold up the others: they ran on the other thread meanwhile.
    assert len({thread for _, thread in started}) == 2


def test_a_failure_is_raised_after_the_running_unit_has_stopped():
    finished = threading.Event()

    def fails():
        raise BakeError("basisu failed (1): bad PNG")

    def slow():
        time.sleep(0.3)
        finished.set()
        return "slow"

    with pytest.raises(BakeError, match="basisu failed"):
        _run_two_at_a_time([fails, slow, lambda: "later"])
    assert finished.is_set()  # nothing still writes into the staging folder after the error
