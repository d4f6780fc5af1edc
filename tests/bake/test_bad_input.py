"""Every mistake in a site description: a message naming the file and the key, exit status 2,
and nothing written (no output directory, not even its parent)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.sites import make_site

DAYLIT = [sys.executable, "-m", "daylit.cli"]


def _replace(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def _scene(tmp_path: Path) -> Path:
    return make_site(tmp_path / "scene")


def _edit(scene: Path, old: str, new: str) -> None:
    toml = scene / "scene.toml"
    toml.write_text(_replace(toml.read_text(), old, new))


CASES = [
    (
        "unknown key",
        lambda s: _edit(s, "[site]", '[site]\ncolour = "red"'),
        "site.colour",
        "unknown key",
    ),
    (
        "misspelt key",
        lambda s: _edit(s, "latitude_deg = 34.47", "latitude = 34.47"),
        "site.latitude",
        "unknown key (did you mean 'latitude_deg'?)",
    ),
    (
        "missing key",
        lambda s: _edit(s, "latitude_deg = 34.47", ""),
        "site.latitude_deg",
        "required but missing",
    ),
    (
        "missing model file",
        lambda s: (s / "models" / "box.obj").unlink(),
        "virtual[0].model",
        "not found",
    ),
    (
        "non-finite number",
        lambda s: _edit(s, "latitude_deg = 34.47", "latitude_deg = nan"),
        "site.latitude_deg",
        "finite",
    ),
    (
        "latitude out of range",
        lambda s: _edit(s, "latitude_deg = 34.47", "latitude_deg = 95.0"),
        "site.latitude_deg",
        "at most 90",
    ),
    (
        "degenerate mesh",
        lambda s: (s / "models" / "box.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"),
        "virtual[0].model",
        "degenerate",
    ),
    (
        "misspelt table",
        lambda s: _edit(s, "[ground]", "[grund]"),
        "grund",
        "unknown key (did you mean 'ground'?)",
    ),
    (
        "wrong type",
        lambda s: _edit(s, "lights = 40", 'lights = "many"'),
        "dome.lights",
        "must be a number",
    ),
    (
        "unknown time zone",
        lambda s: _edit(s, 'timezone = "Asia/Tokyo"', 'timezone = "Mars/Base"'),
        "site.timezone",
        "unknown time zone",
    ),
    ("broken toml", lambda s: _edit(s, "[site]", "[site"), "", "not valid TOML"),
    (
        "negative albedo",
        lambda s: _edit(s, "albedo = [0.2, 0.2, 0.2]", "albedo = [0.2, -1, 0.2]"),
        "ground.albedo[1]",
        "within [0.0, 1.0]",
    ),
    (
        "view looking at itself",
        lambda s: (s / "scene.toml").write_text(
            (s / "scene.toml").read_text() + '\n[[view]]\nname = "k"\nwidth = 64\nheight = 48\n'
            "fov_y_deg = 40\nposition_m = [1, 2, 3]\nlook_at_m = [1, 2, 3]\n"
        ),
        "view[0].look_at_m",
        "must differ",
    ),
]


@pytest.mark.parametrize(("label", "mistake", "key", "words"), CASES, ids=[c[0] for c in CASES])
def test_mistake_is_named_and_nothing_is_written(tmp_path, label, mistake, key, words):
    scene = _scene(tmp_path)
    mistake(scene)
    out = tmp_path / "out" / "build"
    result = subprocess.run(
        [*DAYLIT, "bake", str(scene), "-o", str(out)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2, result.stderr
    message = result.stderr.strip().splitlines()[-1]
    assert str(scene / "scene.toml") in message
    assert f": {key}:" in message if key else True
    assert words in message
    assert not (tmp_path / "out").exists()


def test_missing_scene_folder(tmp_path):
    result = subprocess.run(
        [*DAYLIT, "bake", str(tmp_path / "nowhere"), "-o", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "no such file" in result.stderr
    assert not (tmp_path / "out").exists()


def test_refuses_to_replace_a_folder_that_is_not_a_build(tmp_path):
    scene = _scene(tmp_path)
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.txt").write_text("do not delete")
    result = subprocess.run(
        [*DAYLIT, "bake", str(scene), "-o", str(precious)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "not a daylit build" in result.stderr
    assert (precious / "thesis.txt").read_text() == "do not delete"


def test_help_describes_every_option():
    result = subprocess.run([*DAYLIT, "bake", "--help"], capture_output=True, text=True)
    assert result.returncode == 0
    for option in ("--lights", "--quality", "--budget", "--workers", "-o"):
        assert option in result.stdout
