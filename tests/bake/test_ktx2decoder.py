"""One long-running Node decoder per writing thread (bake.ktx2decoder): the texels are the
one-shot transcoder's and the PNGs' (within UASTC's error), one process serves many decodes,
a file it refuses is a clear error that leaves it usable, one that dies is a clear error and
is replaced, and none is left running after a bake, failed or not."""

from __future__ import annotations

import os
import struct
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from bake import basisu, compress, ktx2decoder, quantize
from bake.errors import BakeError
from bake.pipeline import bake
from tests.sites import make_site

QUIET = {"progress": False, "log": lambda msg: None}


@pytest.fixture
def fresh():
    """No decoder left from an earlier test; every one started here recorded."""
    ktx2decoder.close_decoders()
    started = []
    real_init = ktx2decoder.Decoder.__init__

    def recording_init(self):
        real_init(self)
        started.append(self)

    ktx2decoder.Decoder.__init__ = recording_init
    try:
        yield started
    finally:
        ktx2decoder.Decoder.__init__ = real_init
        ktx2decoder.close_decoders()


def _pngs(folder: Path, count: int) -> tuple[list[Path], list[np.ndarray]]:
    rng = np.random.default_rng(7)
    images, paths = [], []
    for j in range(count):
        # Smooth gradients plus a little noise: what UASTC keeps within a few codes.
        y, x = np.mgrid[0:32, 0:48]
        image = np.stack([x * 5, y * 7, (x + y) * 3], axis=-1) + rng.integers(0, 4, (32, 48, 3))
        images.append(np.clip(image + 10 * j, 0, 255).astype(np.uint8))
        paths.append(folder / f"layer{j}.png")
        quantize.write_png(paths[-1], images[-1])
    return paths, images


def _running_decoders() -> list[int]:
    """Pids of this process's children running tools/decode_ktx2.mjs."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if int(fields[1]) == os.getpid() and b"decode_ktx2.mjs" in cmdline:
            found.append(int(stat.parent.name))
    return found


def test_one_process_decodes_every_file_as_the_one_shot_tool_does(tmp_path, fresh):
    pngs, images = _pngs(tmp_path, 3)
    basisu.encode(pngs, tmp_path, compress.Settings(), array=False)
    basisu.encode(pngs, tmp_path / "array.ktx2", compress.Settings(), array=True)
    files = [tmp_path / "array.ktx2"] + [p.with_suffix(".ktx2") for p in pngs]
    first = ktx2decoder.decode(files)
    second = ktx2decoder.decode(files[::-1])
    assert len(fresh) == 1 and ktx2decoder._idle == fresh  # one process, back in the pool

    # The one-shot form of the tool (a process per call, files written): the same texels.
    outs = [tmp_path / f"{f.name}.bin" for f in files]
    pairs = [str(x) for f, o in zip(files, outs, strict=True) for x in (f, o)]
    subprocess.run(["node", str(ktx2decoder.TOOL), *pairs], check=True, cwd=basisu.REPO_ROOT)
    for out, a, b in zip(outs, first, second[::-1], strict=True):
        data = out.read_bytes()
        width, height, layers, _, _ = struct.unpack("<5I", data[:20])
        one_shot = np.frombuffer(data, np.uint8, offset=20).reshape(layers, height, width, 4)
        np.testing.assert_array_equal(a, one_shot)
        np.testing.assert_array_equal(b, one_shot)
    # And the texels are the PNGs' within UASTC's error (not the decoder's own answer).
    assert first[0].shape == (3, 32, 48, 4)
    for j, image in enumerate(images):
        for decoded in (first[0][j], first[1 + j][0]):
            error = np.abs(decoded[..., :3].astype(int) - image.astype(int))
            assert error.mean() < 3.0 and error.max() <= 40, (j, error.mean(), error.max())


def test_a_refused_file_is_a_clear_error_and_the_process_goes_on(tmp_path, fresh):
    pngs, _ = _pngs(tmp_path, 1)
    basisu.encode(pngs, tmp_path, compress.Settings(), array=False)
    with pytest.raises(basisu.CompressionError, match=r"decoding KTX2 failed: .*layer0\.png"):
        ktx2decoder.decode([pngs[0]])  # a PNG, not a KTX2 file
    with pytest.raises(basisu.CompressionError, match="no such file"):
        ktx2decoder.decode([tmp_path / "missing.ktx2"])
    assert ktx2decoder.decode([tmp_path / "layer0.ktx2"])[0].shape == (1, 32, 48, 4)
    assert len(fresh) == 1


def test_a_decoder_that_died_is_a_clear_error_and_is_replaced(tmp_path, fresh):
    pngs, _ = _pngs(tmp_path, 1)
    basisu.encode(pngs, tmp_path, compress.Settings(), array=False)
    ktx2file = tmp_path / "layer0.ktx2"
    ktx2decoder.decode([ktx2file])
    fresh[0].process.kill()
    fresh[0].process.wait()
    with pytest.raises(basisu.CompressionError, match=r"KTX2 decoder .* stopped .*npm ci"):
        ktx2decoder.decode([ktx2file])
    assert ktx2decoder.decode([ktx2file])[0].shape == (1, 32, 48, 4)
    assert len(fresh) == 2 and fresh[1].process.poll() is None


def test_threads_decoding_at_once_get_a_process_each_and_all_end_when_closed(tmp_path, fresh):
    pngs, _ = _pngs(tmp_path, 2)
    basisu.encode(pngs, tmp_path, compress.Settings(), array=False)
    files = [p.with_suffix(".ktx2") for p in pngs] * 4
    both_in = threading.Barrier(2)
    real = ktx2decoder.Decoder.decode

    def decode_after_both_started(self, path):
        both_in.wait(timeout=30)  # each thread holds its decoder until the other has one
        return real(self, path)

    ktx2decoder.Decoder.decode = decode_after_both_started
    try:
        threads = [threading.Thread(target=ktx2decoder.decode, args=([f],)) for f in files[:2]]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        ktx2decoder.Decoder.decode = real
    assert len(fresh) == 2
    for f in files:  # then one thread: the two idle processes are reused, none started
        ktx2decoder.decode([f])
    assert len(fresh) == 2 and len(_running_decoders()) == 2
    ktx2decoder.close_decoders()
    assert all(d.process.returncode is not None for d in fresh)
    assert _running_decoders() == []


def test_a_bake_reuses_its_decoders_and_leaves_none_running(tmp_path, fresh):
    requests = []
    real = ktx2decoder.Decoder.decode

    def counting(self, path):
        requests.append(path)
        return real(self, path)

    ktx2decoder.Decoder.decode = counting
    try:
        bake(make_site(tmp_path / "scene"), tmp_path / "build", **QUIET)
    finally:
        ktx2decoder.Decoder.decode = real
    # At most one process per writing thread (two), each serving many files.
    assert 1 <= len(fresh) <= 2, len(fresh)
    assert len(requests) >= 5 * len(fresh), (len(requests), len(fresh))
    assert all(d.process.returncode is not None for d in fresh)
    assert _running_decoders() == [] and ktx2decoder._idle == []


def test_a_failing_bake_leaves_no_decoder_running(tmp_path, fresh, monkeypatch):
    calls = []
    real = compress.decode

    def fails_after_a_decode(files):
        arrays = real(files)
        calls.append(len(files))
        if len(calls) == 2:
            raise BakeError("injected: a failure after a decode")
        return arrays

    monkeypatch.setattr(compress, "decode", fails_after_a_decode)
    with pytest.raises(BakeError, match="injected"):
        bake(make_site(tmp_path / "scene"), tmp_path / "build", **QUIET)
    assert fresh and all(d.process.returncode is not None for d in fresh)
    assert _running_decoders() == [] and ktx2decoder._idle == []
    assert not (tmp_path / "build").exists()  # nothing half-written in place
    # and the process can encode again (the stop the failure raised is lifted once the
    # write stage's units have stopped: a compression after it failed at once before)
    basisu.check_not_stopped()
