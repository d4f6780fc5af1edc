"""The relight pass in headless Chromium equals the numpy reference.

For several light vectors (uniform, CIE overcast, clear, a random partly cloudy sky; without
the sun's disc, which the client draws apart, in the visit and at the kiosk) every
stack's render target is read back and compared with ``Build.composite`` on the compact data
(the same KTX2 files decoded by the same Basis transcoder, summed as docs/compact-assets.md
says) and, more loosely, with the EXR masters.

Tolerances, per texel and channel: against the compact reference
|gpu - ref| <= 2e-3 |ref| + 2e-3 mean|ref| (half float keeps 11 bits: 4.9e-4 relative, plus
float32 sums in another order; for I = D - X the relative part is of |D| + |X|, the two
rounded values it comes from); against the
masters the RMS error over the mean stays within 2 % (the compression budget is 1 % on its
test skies).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.web.harness import StubServer, decode_floats

pytestmark = [pytest.mark.browser]

COMPACT_REL = 2e-3
COMPACT_OF_MEAN = 2e-3
MASTER_RMS = 0.02


def skies(ref):
    from bake.evaluate import parse_sky
    from daylit.sky import patch_mean_radiance

    def vector(name):
        return patch_mean_radiance(parse_sky(name), ref.dome_vertices, include_sun=False)

    n = ref.light_count
    rng = np.random.default_rng(5)
    clear = vector("clear:200,30")
    overcast = ref.light_vector("overcast")
    cloudy = np.where((rng.random(n) < 0.45)[:, None], 1.6 * overcast, clear)
    cloudy *= rng.uniform(0.8, 1.2, size=(n, 1))
    return {
        "uniform": ref.light_vector("uniform:1"),
        "overcast": overcast,
        "clear": vector("clear:135,40"),
        "partly-cloudy": cloudy,
    }


def relight(page, r, seq):
    flat = np.asarray(r, dtype=np.float32).ravel().tolist()
    return page.page.evaluate("([r, s]) => window.daylit.debug.relight(r, s)", [flat, seq])


def read(page, key):
    return decode_floats(page.page.evaluate("(k) => window.daylit.debug.read(k)", key))[..., :3]


def check(name, gpu, want, master=None, magnitude=None):
    """``magnitude``: the size of the half-float values ``gpu`` was computed from (for
    I = D - X, |D| + |X|: each carries its own rounding)."""
    err = np.abs(gpu - want)
    magnitude = np.abs(want) if magnitude is None else magnitude
    bound = COMPACT_REL * magnitude + COMPACT_OF_MEAN * np.abs(want).mean()
    worst = float((err / bound).max())
    assert worst <= 1.0, f"{name}: {worst:.2f} x the tolerance, max error {err.max():.4g}"
    if master is not None:
        rms = float(np.sqrt(np.mean((gpu - master) ** 2)) / max(np.abs(master).mean(), 1e-9))
        assert rms <= MASTER_RMS, f"{name}: RMS {rms:.4f} of the mean against the masters"
        return worst, rms
    return worst, None


@pytest.mark.parametrize("mode", ["visit", "kiosk"])
def test_relight_targets_equal_the_numpy_reference(new_page, web_build, reference, mode):
    ref = reference
    entries = ref.manifest["atlases"] if mode == "visit" else ref.manifest["views"]
    report = {}
    with StubServer(web_build) as server:
        # shading=hull: the hull planes load at start, so every atlas is relit.
        page = new_page().open(f"{server.url}/?mode={mode}&test&shading=hull")
        for seq, (sky, r) in enumerate(skies(ref).items(), start=1):
            applied = relight(page, r, seq)
            assert applied["exact"] and applied["sequence"] == seq
            assert applied["selected"] == ref.selection(r).tolist()
            for entry in entries:
                aid = entry["id"]
                compact = {name: ref.compact(aid, name).composite(r, ref.selection)
                           for name in entry["stacks"]}
                for stack, spec in entry["stacks"].items():
                    gpu = read(page, f"{aid}.{stack}")
                    if spec["compact"].get("encodes") == "d - I":
                        # The target holds X = sum r (d - I); the picture uses I = D - X.
                        report[(sky, f"{aid}.X")] = check(f"{sky} {aid}.X", gpu, compact[stack])
                        D = read(page, f"{aid}.d")
                        report[(sky, f"{aid}.I")] = check(
                            f"{sky} {aid}.I", D - gpu, compact["d"] - compact[stack],
                            ref.composite(aid, "I", r, "master"), np.abs(D) + np.abs(gpu))
                    else:
                        report[(sky, f"{aid}.{stack}")] = check(
                            f"{sky} {aid}.{stack}", gpu, compact[stack],
                            ref.composite(aid, stack, r, "master"))
        assert not page.errors, page.errors
    worst = max(v[0] for v in report.values())
    rms = max(v[1] for v in report.values() if v[1] is not None)
    print(f"\n{mode}: worst {worst:.3f} of the compact tolerance, master RMS {rms:.4f}")
