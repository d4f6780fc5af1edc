"""The low-rank choices made faster (issue 20) choose what the per-sky, per-layer tests chose."""

from types import SimpleNamespace

import numpy as np
import pytest

from bake import refinement


def _per_sky_and_layer(losses, f, skies, selection, settings, means=None) -> list[int]:
    """layers_to_refine as it was before issue 20's change: each layer tested on each sky."""
    refine = set()
    for s, sky in enumerate(skies):
        rest = sky.r.copy()
        rest[selection(sky.r)] = 0.0
        c = f.V.T @ rest
        mean = np.abs(np.einsum("tck,kc->tc", f.U, c)).mean() if means is None else means[s]
        for j in range(f.k):
            loss = losses[j] * c[j]
            if np.sqrt((loss**2).mean()) > 0.1 * settings.budget * mean:
                refine.add(j)
    return sorted(refine)


def _problem(seed: int, texels: int = 3000, lights: int = 40, k: int = 24, skies: int = 12):
    rng = np.random.default_rng(seed)
    f = SimpleNamespace(k=k, U=rng.normal(size=(texels, 3, k)).astype(np.float32),
                        V=rng.normal(size=(lights, k)))
    sky_list = [SimpleNamespace(r=rng.uniform(0.0, 1.0, (lights, 3))) for _ in range(skies)]
    scales = np.exp(3.0 * rng.normal(size=k))[:, None, None]  # layers from tiny to large losses
    losses = (1e-3 * scales * rng.normal(size=(k, texels, 3))).astype(np.float32)
    return losses, f, sky_list


def _brightest(r):
    return np.argsort(r.sum(axis=1))[-1:]


@pytest.mark.parametrize("budget", [0.003, 0.01, 0.03])
def test_the_same_layers_as_each_layer_tested_on_each_sky(budget):
    losses, f, skies = _problem(1)
    settings = SimpleNamespace(budget=budget)
    chosen = refinement.layers_to_refine(losses, f, skies, _brightest, settings)
    assert chosen == _per_sky_and_layer(losses, f, skies, _brightest, settings)
    assert 0 < len(chosen) < f.k  # the problem has layers on both sides
    means = list(np.random.default_rng(2).uniform(0.5, 2.0, len(skies)))
    assert refinement.layers_to_refine(losses, f, skies, _brightest, settings, means) == \
        _per_sky_and_layer(losses, f, skies, _brightest, settings, means)


def test_a_layer_right_at_the_threshold_is_decided_by_the_per_sky_test():
    """Means chosen so that a layer's RMS loss on each sky is its threshold to the last bits
    (either side): the fast sum cannot tell, the per-sky test decides, as before."""
    losses, f, skies = _problem(3, skies=6)
    settings = SimpleNamespace(budget=0.01)
    means = []
    for s, sky in enumerate(skies):
        rest = sky.r.copy()
        rest[_brightest(sky.r)] = 0.0
        c = f.V.T @ rest
        j = s % f.k
        rms = np.sqrt(((losses[j] * c[j]) ** 2).mean())
        means.append(rms / (0.1 * settings.budget) * (1.0 + (-1) ** s * 1e-15))
    assert refinement.layers_to_refine(losses, f, skies, _brightest, settings, means) == \
        _per_sky_and_layer(losses, f, skies, _brightest, settings, means)


def test_composite_means_and_their_bound():
    losses, f, skies = _problem(4)
    cs = np.stack([f.V.T @ sky.r for sky in skies])
    means, slack = refinement._composite_means(f.U, cs)
    for s, c in enumerate(cs):
        exact = np.abs(np.einsum("tck,kc->tc", f.U, c)).mean()
        assert abs(means[s] - exact) <= slack[s] * means[s]
    assert (slack < 1e-9).all()
