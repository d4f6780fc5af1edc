"""The daylit serve command: help, clear errors, and a real run that prints the URL."""

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from daylit.cli import build_parser, main
from tests.server.helpers import interrupt_and_wait

ROOT = Path(__file__).resolve().parents[2]


def test_help_lists_serve_and_calibrate(capsys):
    text = build_parser().format_help()
    assert "serve" in text and "calibrate" in text
    try:
        main(["serve", "--help"])
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    assert "replay:PATH" in out and "camera:INDEX_OR_URL" in out and "--site-camera" in out


def test_bad_settings_and_builds_are_clear_errors(tmp_path, build_dir, capsys):
    assert main(["serve", str(tmp_path / "nobuild")]) == 2
    assert "no manifest" in capsys.readouterr().err
    assert main(["serve", str(build_dir), "--set", "sky.rate_hz=-1"]) == 2
    assert "[sky] rate_hz must be a number > 0" in capsys.readouterr().err
    assert main(["serve", str(build_dir), "--sky", "webcam"]) == 2
    assert "source 'webcam'" in capsys.readouterr().err


def test_busy_port_is_reported(build_dir, tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["serve", str(build_dir), "--host", "127.0.0.1", "--port", str(port),
                     "--set", f"server.web_root={str(tmp_path)!r}"])
    assert code == 1
    err = capsys.readouterr().err
    assert f"port {port}" in err and "already in use" in err and "--port" in err


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_prints_the_url_and_serves_until_interrupted(build_dir):
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "daylit.cli", "serve", str(build_dir), "--host", "127.0.0.1",
         "--port", str(port), "--set", "sim.size_px=96", "--set", "sky.rate_hz=10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if "open http://" in line:
                break
        assert f"open http://127.0.0.1:{port}/" in "".join(lines)
        status = None
        while time.monotonic() < deadline:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status") as resp:
                status = json.loads(resp.read())
            if status["sequence"] > 0:
                break
            time.sleep(0.2)
        assert status["source"] == "sim" and status["sequence"] > 0
    finally:
        interrupt_and_wait(proc, 20)
    assert proc.returncode == 0
    err = proc.stderr.read()
    assert "first frame from sim" in err and "stopping after" in err
