"""A shadowing pair's rank search by matrix products (issue 20, "Writing and compressing at
the speed of tracing"): ``Spectrum.composites`` makes the rank-k composites of every test sky
of a block with one float32 product per channel (an einsum per sky before), and
``ratio_error`` judges the shadow ratio from them.

The answers are computed here in float64 from the definitions: the rank-k reconstruction
``M S Y_k Y_k^T S^-1 r'`` plus the selected lights ``M r_A`` exactly, and the ratio
``(d_k - delta_k) / d_k`` against the masters' where ``g sum r d`` is above ``RATIO_FLOOR``
of its mean."""

from __future__ import annotations

import numpy as np
import pytest

from bake import lowrank, testskies
from bake.compresssettings import Settings
from bake.lowrank import RATIO_FLOOR, Spectrum
from daylit.selection import Selection

N_LIGHTS = 12
NOISE = 1e-3  # beside the 4 patterns: the ratio's error falls within the bound past rank 4


def _case(seed: int, m: int):
    """A pair's normalized spectra (d, delta) of 500 texels, their skies and selection."""
    rng = np.random.default_rng(seed)
    T = 500
    # Four light patterns (grey, tinted: a stack of rank 4) and a little noise; delta a
    # wall's shadow (the lights it hides) on a third of the texels, by a texel's own depth.
    tint = np.array([1.0, 0.95, 0.9])
    patterns = rng.random((4, N_LIGHTS, 1)) * tint
    weights = rng.random((T, 4))
    d = np.einsum("tp,pnc->tnc", weights, patterns) + NOISE * rng.random((T, N_LIGHTS, 3))
    hidden = (rng.random(N_LIGHTS) < 0.4)[None, :, None]
    depth = np.zeros((T, 1, 1))
    depth[: T // 3] = 0.2 + 0.6 * rng.random((T // 3, 1, 1))
    delta = d * hidden * depth
    gain = (0.5 + rng.random(T)).astype(np.float32)
    A = rng.random((N_LIGHTS, N_LIGHTS))
    eigenvalues, Q = np.linalg.eigh(A @ A.T + N_LIGHTS * np.eye(N_LIGHTS))
    S = Q @ np.diag(np.sqrt(eigenvalues)) @ Q.T  # a prior's symmetric square root
    S_inv = np.linalg.inv(S)
    spec_d = Spectrum.of(d.astype(np.float32), gain, S)
    spec_delta = Spectrum.of(delta.astype(np.float32), gain, S)
    skies = [testskies.TestSky(f"sky {i}",
                               rng.random((N_LIGHTS, 3)) * rng.random(N_LIGHTS)[:, None])
             for i in range(7)]
    selection = Selection.of(np.full(N_LIGHTS, 0.3), m)
    return spec_d, spec_delta, skies, selection, S, S_inv


def _reference_composite(spec: Spectrum, k: int, S, S_inv, r, chosen) -> np.ndarray:
    """(T, 3) float64 ``M (S Y_k Y_k^T S^-1 r' + r_A)`` of the normalized texels."""
    M = spec.M.astype(np.float64)
    rest = r.copy()
    rest[chosen] = 0.0
    Yk = spec.Y[:, :k]
    projected = S @ (Yk @ (Yk.T @ (S_inv @ rest)))  # (n, 3)
    exact = np.zeros_like(r)
    exact[chosen] = r[chosen]
    return np.einsum("tnc,nc->tc", M, projected + exact)


@pytest.mark.parametrize("m", [0, 2])
def test_composites_are_the_rank_k_reconstruction(m):
    spec_d, _, skies, selection, S, S_inv = _case(1, m)
    for k in (1, 3, 7):
        K = spec_d.projection_width(k)
        rows = spec_d.rows(0, spec_d.T)
        P = spec_d.project_rows(S, K, rows)
        chosen = [selection(sky.r) for sky in skies]
        assert m == 0 or all(len(c) == m for c in chosen)
        out = spec_d.composites(P, k, S_inv, [sky.r for sky in skies], chosen, rows)
        assert out.shape == (len(skies), spec_d.T, 3) and out.dtype == np.float32
        for s, sky in enumerate(skies):
            reference = _reference_composite(spec_d, k, S, S_inv, sky.r, chosen[s])
            np.testing.assert_allclose(out[s], reference, rtol=2e-5,
                                       atol=2e-5 * np.abs(reference).max())


def _reference_ratio_error(spec_delta, spec_d, k, S, S_inv, skies, selection) -> float:
    worst = 0.0
    gain = spec_d.gain.astype(np.float64)[:, None]
    for sky in skies:
        chosen = selection(sky.r)
        M_d, M_delta = spec_d.M.astype(np.float64), spec_delta.M.astype(np.float64)
        d_true = np.einsum("tnc,nc->tc", M_d, sky.r)
        I_true = d_true - np.einsum("tnc,nc->tc", M_delta, sky.r)
        d_k = _reference_composite(spec_d, k, S, S_inv, sky.r, chosen)
        I_k = d_k - _reference_composite(spec_delta, k, S, S_inv, sky.r, chosen)
        lit = d_true * gain > RATIO_FLOOR * (d_true * gain).mean()
        error = np.abs(I_k / np.maximum(d_k, 1e-12) - I_true / np.maximum(d_true, 1e-12))
        worst = max(worst, float(error[lit].max(initial=0.0)))
    return worst


@pytest.mark.parametrize("m", [0, 2])
def test_ratio_error_and_rank_are_the_float64_ones(m, monkeypatch):
    """The worst ratio error at each rank within float32 rounding of the float64 one, also
    with the skies' composites split into batches of two (a small working block), and the
    rank search's answer the smallest rank within the bound by the float64 errors."""
    spec_d, spec_delta, skies, selection, S, S_inv = _case(2, m)
    settings = Settings()
    errors = {}
    for k in range(1, N_LIGHTS + 1):
        ours = lowrank.ratio_error(spec_delta, spec_d, k, S, S_inv, skies, selection, settings)
        errors[k] = _reference_ratio_error(spec_delta, spec_d, k, S, S_inv, skies, selection)
        assert ours == pytest.approx(errors[k], rel=1e-3, abs=1e-5), k
    monkeypatch.setattr(lowrank, "ROW_BLOCK_BYTES", 2 * 2 * 3 * 4 * spec_d.T)
    for k in (2, 5):
        ours = lowrank.ratio_error(spec_delta, spec_d, k, S, S_inv, skies, selection, settings)
        assert ours == pytest.approx(errors[k], rel=1e-3, abs=1e-5), k
    # The rank-4 case: over the bound below rank 4, far within it from there on.
    bound = lowrank.RATIO_TRUNCATION
    assert all(errors[k] > 2 * bound for k in (1, 2, 3)), errors
    assert all(errors[k] < bound / 10 for k in range(4, N_LIGHTS + 1)), errors
    found = lowrank.ratio_rank(spec_delta, spec_d, 1, S, S_inv, skies, selection, settings)
    assert found == 4
