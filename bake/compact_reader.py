"""Reads a compact stack back exactly as the client does: decodes its KTX2 textures and
evaluates ``g (U V^T r' + sum_{i in A(r)} r_i B_i)`` for a light vector ``r`` (n, 3).
Used by the bake's checks, the tests and ``daylit probe --compact``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bake.ktx2decoder import decode
from daylit.selection import Selection

# A compact stack's ``v.dtype`` and the numpy type its file holds: float32 always before
# manifest version 4 (2026-12-06), float16 in version 4, int8 with a scale per column since
# version 5 (2026-12-07; bake.compress.settle_v_dtype takes the next of these where one
# would put a stack over its budget).
V_DTYPES = {"float32-le": "<f4", "float16-le": "<f2", "int8": "i1"}
HALF_TOP_EXPONENT = 14  # a float16 V's largest |value| / scale is in [2^14, 2^15)
INT8_TOP = 127  # an int8 V's column is stored divided by its largest |value| / 127


def half_scale(V: np.ndarray) -> float:
    """The power of two ``scale`` a float16 V (n, k) is stored divided by: its largest
    magnitude then in [2^14, 2^15), below float16's largest finite value (65504), and its
    entries down to 2^-29 of it normal numbers, each rounded to 2^-11 of itself whatever the
    stack's units (the demo's V are at most 0.002-0.2: without a scale 4-25 % of its entries
    would be float16 subnormals, rounded to 3e-8 absolute). A power of two: dividing and
    multiplying by it is exact."""
    top = float(np.abs(V).max(initial=0.0))
    if not np.isfinite(top) or top == 0.0:
        return 1.0
    return float(2.0 ** (int(np.floor(np.log2(top))) - HALF_TOP_EXPONENT))


def column_scales(V: np.ndarray) -> np.ndarray:
    """The ``scales`` (k,) float32 an int8 V (n, k) is stored divided by, one per column
    (coefficient): its largest magnitude over 127 (1 for a zero column)."""
    top = np.abs(np.asarray(V, dtype=np.float32)).max(axis=0, initial=0.0)
    return np.where(top > 0.0, top / np.float32(INT8_TOP), np.float32(1.0)).astype(np.float32)


def _stored(V: np.ndarray, dtype: str) -> tuple[np.ndarray, dict]:
    """V (n, k) as its file holds it in ``dtype`` and the entry's ``dtype`` and scale(s)."""
    V = np.asarray(V, dtype=np.float32)
    if dtype == "int8":
        scales = column_scales(V)
        values = np.clip(np.rint(V / scales), -INT8_TOP, INT8_TOP).astype(np.int8)
        return values, {"dtype": dtype, "scales": [float(s) for s in scales]}
    if dtype == "float16-le":
        scale = half_scale(V)
        return (V / np.float32(scale)).astype(V_DTYPES[dtype]), {"dtype": dtype,
                                                                 "scale": scale}
    return V.astype(V_DTYPES[dtype]), {"dtype": dtype}


def _widened(values: np.ndarray, v: dict) -> np.ndarray:
    """A V file's ``values`` (n, k) as float32 read with its entry ``v``'s scale(s): exact
    products, so the same values as the client's (web/src/assets.js ``matrix``)."""
    if "scales" in v:
        return values.astype(np.float32) * np.asarray(v["scales"], dtype=np.float32)
    return values.astype(np.float32) * np.float32(v.get("scale", 1.0))


def stored_v(V: np.ndarray, dtype: str) -> np.ndarray:
    """V (n, k) float32 as it reads back from a file of type ``dtype`` (:func:`write_v`,
    :func:`read_v`)."""
    values, entry = _stored(V, dtype)
    return _widened(values, entry)


def write_v(path: Path, V: np.ndarray, dtype: str) -> dict:
    """Write V (n, k) to ``path`` in ``dtype`` (float16: divided by :func:`half_scale`;
    int8: each column divided by its :func:`column_scales`, rounded); returns the entry's
    ``dtype`` and, for float16, ``scale``, for int8 ``scales``."""
    values, entry = _stored(V, dtype)
    values.tofile(path)
    return entry


def read_v(build_dir: Path, v: dict) -> np.ndarray:
    """A stack's V (n, k) float32 from its manifest entry ``v`` (``path``, ``shape``,
    ``dtype``, ``scale`` or ``scales``): the file's values widened exactly, times ``scale``
    (default 1; a power of two, so exact) or each column's ``scales``."""
    n, k = v["shape"]
    dtype = V_DTYPES[v.get("dtype", "float32-le")]
    values = np.fromfile(Path(build_dir) / v["path"], dtype=dtype).reshape(n, k)
    return _widened(values, v)


def image_holders(table: dict) -> list:
    """A ``lights`` table's light whose files hold each light's image: ``image`` where a
    sun-bounce light may share another's (since 2026-12-06: bake.sunshare.SharedImages; it
    is read with its own scale and offset), else each light its own."""
    return table.get("image") or list(range(len(table["scale"])))


class CompactReader:
    """Evaluates a stack from its compact files exactly as the client does (for checks,
    tests and ``daylit probe --compact``). Decoded textures are cached.

    An entry with ``k = 0`` has no base (no ``ktx2``, ``layers``, ``v``): the lights' own
    images alone, as the sun-bounce stacks are stored
    (:func:`bake.sunbounce.compress_sun_bounce`; read a column with :meth:`lights`)."""

    def __init__(self, build_dir: Path, entry: dict, shape: tuple[int, int],
                 decoder=None):
        """``decoder``: how the light images' files are decoded (:func:`decode`'s
        signature, the default; bake.sunwritten gives one that decodes each file once)."""
        self.dir = Path(build_dir)
        self.entry = entry
        self.shape = shape
        self._decode = decoder
        if "v" in entry:
            self.V = read_v(self.dir, entry["v"])
        else:
            self.V = np.zeros((len(entry["lights"]["scale"]), 0))
        self._base = None
        self._gain = None
        self._lights: dict[int, np.ndarray] = {}
        self._raw = None  # a reader made from decoded bytes (:meth:`decoded`): its base's
        self._at = None  # (mask, base layers at it (k, T, 3), gain at it) of composite(at=)

    def gain(self) -> np.ndarray | float:
        """(H, W, 3) float32 decoded gain (coarse plus refinement), or 1 without one."""
        if "gain" not in self.entry:
            return 1.0
        if self._gain is None:
            table = self.entry["gain"]
            raw = decode([self.dir / table["ktx2"]])[0][..., :3].astype(np.float32) / 255.0
            self._gain = sum(
                texel * np.float32(layer["scale"]) + np.float32(layer["offset"])
                for texel, layer in zip(raw, table["layers"], strict=True)
            )
        return self._gain

    def base(self) -> np.ndarray:
        """(k, H, W, 3) float32 decoded base layers, refinements added to their layers."""
        if self._base is None and self._raw is not None:
            self._base = layer_sum(self.entry["layers"], *self._raw)
        if self._base is None and "ktx2" not in self.entry:
            self._base = np.zeros((0,) + self.shape + (3,), dtype=np.float32)
        if self._base is None:
            files = [self.dir / self.entry["ktx2"]]
            if "etc1s" in self.entry:  # its layers follow the UASTC array's in ``layers``
                files.append(self.dir / self.entry["etc1s"]["ktx2"])
            raw = np.concatenate(decode(files))  # (layers, H, W, 4) uint8
            n, k = self.entry["v"]["shape"]
            self._base = layer_sum(self.entry["layers"], raw, k)
        return self._base

    @classmethod
    def decoded(cls, build_dir: Path, entry: dict, shape: tuple[int, int], V: np.ndarray,
                raw: list[np.ndarray]) -> CompactReader:
        """A reader of a stack whose base is not written (bake.compress tries its ETC1S
        splits in memory): ``V`` (n, k) float32 as it would be read back (float16-rounded
        where it is written so: bake.compress.stored_v), ``raw`` its base
        layers' decoded bytes in the order of ``entry["layers"]`` (each (H, W, 4) uint8);
        the lights and the gain are read from ``build_dir`` as usual. The same composite,
        to the bit, as a reader of the files that decode to those bytes."""
        reader = cls(build_dir, {key: value for key, value in entry.items() if key != "v"},
                     shape)
        reader.V = V
        reader._raw = (raw, V.shape[1])
        return reader

    def lights(self, indices) -> dict[int, np.ndarray]:
        """(H, W, 3) float32 decoded image of each light in ``indices``."""
        missing = [i for i in indices if i not in self._lights]
        if not missing:
            return {i: self._lights[i] for i in indices}
        table = self.entry["lights"]
        # Light i has len(scale[i]) levels, the first of the ``ktx2`` patterns (a sun-bounce
        # image may have no refinement: bake.sunbounce).
        levels = {i: len(table["scale"][i]) for i in missing}
        holder = image_holders(table)
        files = [self.dir / pattern.format(index=holder[i]) for i in missing
                 for pattern in table["ktx2"][: levels[i]]]
        decoded = iter((self._decode or decode)(files))
        for i in missing:
            value = np.zeros(self.shape + (3,), dtype=np.float32)
            for level in range(levels[i]):
                raw = next(decoded)[0, :, :, :3].astype(np.float32) / 255.0
                value += raw * np.float32(table["scale"][i][level]) + np.float32(
                    table["offset"][i][level]
                )
            self._lights[i] = value
        return {i: self._lights[i] for i in indices}

    def selection(self, selection: Selection) -> Selection:
        """``selection`` with this stack's own number of selected lights (its entry's
        ``selected_lights``, absent in builds made before 2026-11-24: the build's)."""
        m = self.entry.get("selected_lights", selection.m)
        return selection if m == selection.m else Selection(selection.weights_sr, m)

    def forget_lights(self) -> None:
        """Drop the decoded light images (memory)."""
        self._lights.clear()

    def composite(self, r: np.ndarray, selection: Selection,
                  at: np.ndarray | None = None) -> np.ndarray:
        """``g (sum_l U_l (V^T r')_l + sum_{i in A(r)} r_i B_i)``: (H, W, 3) float32; with
        ``at`` (H, W) bool, at those texels only (T, 3): the same values, bit for bit, as
        the whole composite's ``[at]`` (the same sum over the layers at each texel), from
        the base layers' values there, kept for the next call with that mask; the whole base
        is then let go of (made again if asked for). The bake's checks read a stack's valid
        texels only (about three fifths of the demo's lightmap; docs/benchmarks.md, "The
        ratio rule's moves at the lit values")."""
        r = np.asarray(r, dtype=np.float64)
        chosen = self.selection(selection)(r)
        rest = r.copy()
        rest[chosen] = 0.0
        c = self.V.T @ rest  # (k, 3)
        if at is None:
            out = np.einsum("khwc,kc->hwc", self.base(), c.astype(np.float32))
            gain = self.gain()
        else:
            base, gain = self._values_at(at)
            out = np.einsum("ktc,kc->tc", base, c.astype(np.float32))
        for i, light in self.lights(chosen).items():
            out += (light if at is None else light[at]) * r[i].astype(np.float32)
        return out * gain

    def _values_at(self, at: np.ndarray):
        """The base layers (k, T, 3) and the gain (T, 3, or 1) at the ``at`` texels."""
        if self._at is None or not np.array_equal(self._at[0], at):
            gain = self.gain()
            self._at = None
            self._at = (np.array(at, dtype=bool), self.base()[:, at],
                        gain if np.isscalar(gain) else gain[at])
            if self._raw is not None or "ktx2" in self.entry:
                self._base = None  # decoded again if asked for
        return self._at[1], self._at[2]


def layer_sum(layers: list[dict], raw, k: int) -> np.ndarray:
    """(k, H, W, 3) float32 base layers from the decoded bytes ``raw`` of the ``layers``
    (an entry's ``layers``: (layers, H, W, 4) uint8, or a list of (H, W, 4)), each layer's
    value added to its coefficient's (refinements to their coarse layers), in their order.

    A layer at a time: the layers as float32 at once (coarse and refinements, up to twice k)
    were twice the base again (docs/benchmarks.md, "The write stage's memory"); the same
    values."""
    base = np.zeros((k,) + raw[0].shape[:2] + (3,), dtype=np.float32)
    for layer, texel in zip(layers, raw, strict=True):
        value = texel[..., :3].astype(np.float32) / 255.0
        value = value * np.float32(layer["scale"]) + np.float32(layer["offset"])
        base[layer["coefficient"]] += value
    return base
