"""The runtime light-selection rule A(r), shared with the client: which lights of a light
vector a client takes from their own images rather than from a stack's low-rank base.

Its one job is the rule (Sato Sec. 7): the ``m`` lights with the largest
``max_c(r_ic) * weight_i``, ties to the lower index, zero-score lights never, where a light's
weight is its solid angle if it can be selected (it has images) and 0 otherwise. The
JavaScript copy is ``selectLights`` / ``selectionWeights`` in web/src/lightmath.js; both are
checked against the hand-worked cases in tests/vectors/light_selection.json
(tests/daylit/test_selection.py and tests/web/test_lightmath_js.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def select_lights(r: np.ndarray, weights_sr: np.ndarray, m: int) -> np.ndarray:
    """The ``m`` brightest lights of ``r`` (n, 3): largest ``max_c(r_ic) * weights_sr_i``,
    ties to the lower index, zero-score lights never. ``weights_sr`` (n,) is each light's
    solid angle, or 0 for a light that cannot be selected (:class:`Selection`). The client
    does exactly this, on ``r`` as the light stream carries it: float32. Rounding here too
    makes near-ties (patches of one ring under an overcast sky) come out the same: the
    client's pick and this one differed in float64 by the last bits of a solid angle."""
    score = np.asarray(r, dtype=np.float32).max(axis=1).astype(np.float64) * weights_sr
    order = np.lexsort((np.arange(len(score)), -score))[:m]
    return np.sort(order[score[order] > 0.0])


@dataclass(frozen=True)
class Selection:
    """Which lights a client takes from their own images (Sato Sec. 7): the ``m`` brightest
    *selectable* lights of a vector. Only selectable lights have images, so a bake encodes
    and a server offers about half of them (the sky's other patches never carry the sun).

    ``weights_sr`` (n,): a selectable light's solid angle in sr, 0 for the others."""

    weights_sr: np.ndarray
    m: int

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """The selected lights of ``r`` (n, 3), in increasing index order."""
        return select_lights(r, self.weights_sr, self.m)

    @property
    def selectable(self) -> np.ndarray:
        """Indices of the lights that have images, increasing."""
        return np.flatnonzero(self.weights_sr > 0.0)

    @classmethod
    def of(cls, solid_angles: np.ndarray, m: int, selectable=None) -> Selection:
        """From the dome's solid angles (n,) and the selectable indices (default: all)."""
        weights = np.asarray(solid_angles, dtype=np.float64).copy()
        if selectable is not None:
            keep = np.zeros(len(weights), dtype=bool)
            keep[np.asarray(selectable, dtype=int)] = True
            weights[~keep] = 0.0
        return cls(weights, m)

    @classmethod
    def of_manifest(cls, manifest: dict) -> Selection:
        """A build's selection, as its client makes it: the dome's solid angles, the
        manifest's ``selected_lights`` and ``selectable_lights`` (absent in builds made
        before it: every light)."""
        solid_angles = [light["solid_angle_sr"] for light in manifest["dome"]["lights"]]
        compression = manifest["compression"]
        return cls.of(
            np.array(solid_angles), compression["selected_lights"],
            compression.get("selectable_lights"),
        )
