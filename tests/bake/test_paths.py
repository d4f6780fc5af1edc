"""Paths as people type them: relative to the working directory, whatever the baker runs."""

from __future__ import annotations

from daylit import manifest as manifest_io
from daylit.cli import main
from tests.sites import make_site


def test_bake_with_a_relative_output_directory(tmp_path, monkeypatch):
    # The KTX2 check decodes under Node in the repository's directory: a relative -o used to
    # fail there, after the whole trace.
    make_site(tmp_path / "scenes" / "x")
    monkeypatch.chdir(tmp_path)
    status = main(["bake", "scenes/x", "-o", "relative/out", "--no-progress", "--workers", "1"])
    assert status == 0
    manifest = manifest_io.load(tmp_path / "relative" / "out", check_files=True)
    assert any(f["path"].endswith(".ktx2") for f in manifest["files"])
    assert not (tmp_path / "relative" / ".out.partial").exists()
