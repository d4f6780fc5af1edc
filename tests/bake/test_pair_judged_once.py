"""A shadowing pair's checks decode each test sky's composites once (issue 20, "Writing and
compressing at the speed of tracing"): ``bake.stackkinds.compress_ratio_pair`` judges ``d``,
``I = d - delta`` and the shadow ratio from one composite of ``d`` and one of ``delta`` per
sky (until 2026-12-06 ``d``'s was computed three times a sky and ``delta``'s twice), and what
it records is what the masters give.

The answers are the masters' own composites, ``sum_i r_i B_i`` summed here in float64 from
the synthetic ground of tests/bake/test_pair_gain.py, against a fresh reader of the files."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from bake import stackkinds
from bake.compact_reader import CompactReader
from bake.dome import Dome
from tests.bake.test_pair_gain import SIZE, _masters, compress_ground_pair, prepared_skies


@pytest.fixture(scope="module")
def judged(tmp_path_factory):
    dome = Dome.for_light_count(40)
    I, d, _ = _masters(dome)
    out = tmp_path_factory.mktemp("pair")
    prepared = prepared_skies(dome)
    skies, _, _, selection = prepared
    calls = collections.Counter()  # (reader, sky) -> composites computed
    composite = CompactReader.composite

    def counted(self, r, selection, **kwargs):
        calls[id(self), np.asarray(r).tobytes()] += 1
        return composite(self, r, selection, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(CompactReader, "composite", counted)
        delta_stack, d_stack = compress_ground_pair(I, d, out, prepared)
    return dict(I=I, d=d, out=out, skies=skies, selection=selection, calls=calls,
                entries={"d": d_stack.entry, "delta": delta_stack.entry})


def test_each_skys_composites_are_computed_once(judged):
    """Every reader computed each test sky's composite once: the pair's two readers, one
    composite of each per sky (V stayed int8 here, so settle_v_dtype judged nothing
    again). On the code before, ``d``'s reader computed three per sky."""
    assert all(e["v"]["dtype"] == "int8" for e in judged["entries"].values())
    calls = judged["calls"]
    assert len(calls) == 2 * len(judged["skies"])
    assert max(calls.values()) == 1, collections.Counter(calls.values())


def test_the_recorded_errors_are_the_masters(judged):
    """The errors recorded for ``d`` and ``I`` (RMS over the mean on every test sky) and the
    shadow ratio's worst texel where ``sum r d`` is above ``RATIO_FLOOR`` of its mean: those
    of a fresh reader of the files against the masters' composites summed here."""
    I, d, selection = judged["I"], judged["d"], judged["selection"]
    valid = np.any(d != 0, axis=(2, 3)) | np.any(I != 0, axis=(2, 3))
    readers = {name: CompactReader(judged["out"], entry, (SIZE, SIZE))
               for name, entry in judged["entries"].items()}
    worst_ratio = 0.0
    for sky in judged["skies"]:
        r = sky.r.astype(np.float64)
        d_true = np.einsum("hwnc,nc->hwc", d.astype(np.float64), r)[valid]
        I_true = np.einsum("hwnc,nc->hwc", I.astype(np.float64), r)[valid]
        D = readers["d"].composite(sky.r, selection)[valid]
        I_decoded = D - readers["delta"].composite(sky.r, selection)[valid]
        for name, decoded, true in (("d", D, d_true), ("delta", I_decoded, I_true)):
            error = np.sqrt(((decoded - true) ** 2).mean()) / true.mean()
            recorded = judged["entries"][name]["error"]["encoded"][sky.name]
            assert recorded == pytest.approx(error, rel=1e-3, abs=2e-6), (name, sky.name)
        lit = d_true > stackkinds.RATIO_FLOOR * d_true.mean()
        error = np.abs(I_decoded / np.maximum(D, 1e-12) - I_true / np.maximum(d_true, 1e-12))
        worst_ratio = max(worst_ratio, float(error[lit].max(initial=0.0)))
    ratio = judged["entries"]["delta"]["error"]["ratio"]
    assert ratio["max"] == pytest.approx(worst_ratio, rel=1e-3, abs=2e-6)
    assert "ratio" not in judged["entries"]["d"]["error"]
