"""A stack's base layers encoded in UASTC once, for every ETC1S split that is tried.

A stack judged by its RMS error alone is tried with its ETC1S array starting at one layer,
then the next, ... (bake.stackkinds.compress_rms_stack): each try had encoded and decoded its
UASTC layers again, coarse and every candidate refinement, though only the ETC1S array
(one codebook for its layers) differs between tries. UASTC encodes each 4 x 4 block on its
own (no rate-distortion optimization here), so a layer decodes to the same bytes whatever
array it is encoded in and at whatever place (checked: tests/bake/test_etc1s_tries.py); the
final base array, coarse layers and chosen refinements at one level, decodes to them too.
:class:`UastcLayers` encodes each layer once, when a try first needs it, and keeps its
decoded bytes.

Shapes: decoded layers (layers, H, W, 4) uint8, as bake.ktx2decoder returns them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bake.ktx2decoder import decode
from bake.quantize import Quantized, refinement_png


class UastcLayers:
    """The coarse UASTC layers of a stack and their candidate refinements, encoded and
    decoded as tries need them (each layer once).

    ``base_q`` the base layers' quantized PNGs (bake.quantize), ``lost(j, coarse)`` what
    layer j's coarse encoding ``coarse`` (H, W, 4) uint8 lost (H, W, 3) float32,
    ``encode_array(pngs, out)`` the array encoder at the base array's level, ``tmp`` a
    scratch folder, ``refine_mask`` (H, W) where refinements are kept (None: everywhere)."""

    def __init__(self, base_q: list[Quantized], lost: Callable, encode_array: Callable,
                 tmp: Path, refine_mask: np.ndarray | None):
        self.base_q = base_q
        self.lost = lost
        self.encode_array = encode_array
        self.tmp = Path(tmp)
        self.refine_mask = refine_mask
        self._coarse: list[np.ndarray] = []  # decoded coarse layer j, (H, W, 4) uint8
        self._candidates: list[Quantized] = []
        self._restored: list[np.ndarray] = []  # decoded candidate refinement j

    def coarse(self, head: int) -> list[np.ndarray]:
        """The decoded coarse layers 0 .. head - 1 (each (H, W, 4) uint8)."""
        done = len(self._coarse)
        if head > done:
            out = self.tmp / f"coarse-{done}-{head}.ktx2"
            self.encode_array([q.path for q in self.base_q[done:head]], out)
            self._coarse.extend(decode([out])[0])
        return self._coarse[:head]

    def candidates(self, head: int) -> tuple[list[Quantized], list[np.ndarray]]:
        """Layers 0 .. head - 1's candidate refinements (an 8-bit image of what each one's
        coarse encoding lost, bake.quantize.refinement_png) and their decoded bytes."""
        done = len(self._candidates)
        if head > done:
            coarse = self.coarse(head)
            made = [refinement_png(self.lost(j, coarse[j]), self.tmp / f"refine{j:04d}.png",
                                   self.refine_mask) for j in range(done, head)]
            out = self.tmp / f"candidates-{done}-{head}.ktx2"
            self.encode_array([q.path for q in made], out)
            self._candidates.extend(made)
            self._restored.extend(decode([out])[0])
        return self._candidates[:head], self._restored[:head]
