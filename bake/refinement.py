"""Which base layers of a stack get a refinement after coarse encoding (bake.compress).

A base layer's coarse encoding (UASTC or ETC1S at 8 bits over its range) loses ``e_j`` at each
texel; refining it (a second 8-bit image of the loss) restores most of that. Three rules:

- :func:`layers_to_refine`: every layer whose own loss passes a tenth of the budget on some
  test sky (the per-layer rule; the shadowing pairs' stacks use it);
- :func:`layers_to_refine_within`: the fewest layers that keep the *decoded* composite within
  a target on every test sky (the stacks judged by their RMS error alone);
- :class:`RatioRefinement`: the layers a shadowing pair's per-texel ratio needs.

Shapes as in :mod:`bake.lowrank`: ``U`` (T, 3, k), ``V`` (n, k), losses (k, T, 3) layer-major.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bake.lowrank import RATIO_UNREFINED, Factors, Spectrum, ratio_checks
from bake.rowstore import ROW_BLOCK_BYTES, RowFile


def layers_to_refine(losses, f, skies, selection, settings, means=None) -> list[int]:
    """Base layers whose coarse encoding loses more than a tenth of the budget on a sky,
    measured on the normalized values (relative to each texel's level): ``losses`` (k, T, 3)
    what each layer's coarse encoding lost at the valid texels, layer-major so that each
    layer's losses are one contiguous block (a (T, 3, k) slice per layer and sky strode
    through memory: docs/benchmarks.md, "One Node decoder per writing thread"); ``means`` the
    composite's mean on each sky to measure against (default: this stack's base composite).

    The same layers as each layer's test on each sky (:func:`_loses_too_much`), which passed
    over the losses once per layer and sky: a layer's RMS loss on a sky is ``sqrt(sum_c
    c_c^2 Q_c / 3T)``, ``Q`` (k, 3) its losses' sums of squares taken once; the skies' means
    come from matrix products. Within rounding of the threshold the per-sky test decides."""
    if not skies:
        return []
    texels = losses.shape[1]
    squares = np.empty((f.k, 3))
    for j in range(f.k):
        block = losses[j].astype(np.float64)
        squares[j] = np.einsum("tc,tc->c", block, block)
    rests = []
    for sky in skies:
        rest = sky.r.copy()
        rest[selection(sky.r)] = 0.0
        rests.append(rest)
    cs = np.stack([f.V.T @ rest for rest in rests])  # (skies, k, 3)
    given = means
    if given is None:
        means, slack = _composite_means(f.U, cs)
    else:
        means, slack = np.asarray(given, dtype=np.float64), np.zeros(len(skies))
    rms = np.sqrt(np.einsum("skc,kc->sk", cs**2, squares) / (3 * texels))  # (skies, k)
    thresholds = 0.1 * settings.budget * means
    # Rounding: two orders of float64 sums of millions of terms agree within 1e-12.
    doubt = np.abs(rms - thresholds[:, None]) <= (1e-9 + slack[:, None]) * thresholds[:, None]
    refine = rms > thresholds[:, None]
    for s, j in zip(*np.nonzero(doubt), strict=True):
        c = cs[s]
        mean = np.abs(np.einsum("tck,kc->tc", f.U, c)).mean() if given is None else given[s]
        refine[s, j] = _loses_too_much(losses[j], c[j], mean, settings)
    return sorted(int(j) for j in np.nonzero(refine.any(axis=0))[0])


def _loses_too_much(loss_j: np.ndarray, c_j: np.ndarray, mean: float, settings) -> bool:
    """A layer's test on one sky, as :func:`layers_to_refine` made it per sky and layer:
    its coarse loss ``loss_j`` (T, 3) under the sky's coefficients ``c_j`` (3,) above a
    tenth of the budget times the composite's ``mean``."""
    loss = loss_j * c_j
    return bool(np.sqrt((loss**2).mean()) > 0.1 * settings.budget * mean)


def _composite_means(U: np.ndarray, cs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean of ``|U c|`` over texels and channels for each sky's ``c`` of ``cs``
    (skies, k, 3), ``U`` (T, 3, k), from matrix products by blocks of rows (each within
    ``ROW_BLOCK_BYTES``: no texels x skies array); and each mean's bound on its difference
    from another order of summation, relative (within ``2 k eps`` of ``sum |U| |c|``)."""
    k = U.shape[2]
    sums = np.zeros(len(cs))
    bounds = np.zeros(len(cs))
    step = max(1, ROW_BLOCK_BYTES // (8 * max(k, len(cs))))
    for a in range(0, len(U), step):
        for channel in range(3):
            u = U[a : a + step, channel, :].astype(np.float64)  # (b, k)
            sums += np.abs(u @ cs[:, :, channel].T).sum(axis=0)
            bounds += (np.abs(u) @ np.abs(cs[:, :, channel]).T).sum(axis=0)
    count = 3 * U.shape[0]
    means = sums / count
    eps = np.finfo(np.float64).eps
    slack = 4 * (k + 2) * eps * (bounds / count) / np.maximum(means, 1e-300) + 1e-12
    return means, slack


# The new summed moves a layer tested for the shadow ratio keeps, at most (beside the sums
# themselves, skies x lit texels: the demo's hull pair's fit, a large site's do not).
KEPT_SUMS_BYTES = 2 * ROW_BLOCK_BYTES
# The skies' lit places, -X and D**2 a rule keeps for its moves, at most (made again per move
# past it: a large site's); the demo's hull needs about 100 MB for d's.
KEPT_TERMS_BYTES = 2 * ROW_BLOCK_BYTES


@dataclass
class RatioRefinement:
    """Which base layers of one stack of a shadowing pair need their refinement for the
    per-texel shadow ratio ``alpha = X / D`` (``X = sum r delta``, ``D = sum r d``).

    A coarse loss ``e_j`` of layer j moves ``alpha`` by ``c_j e_j / D`` in delta's layers and
    by ``-X c_j e_j / D^2`` in d's (``c = V^T r'``). Layers are left unrefined, smallest move
    first, while their summed move stays within ``tolerance`` at every texel where ``D`` is
    above ``RATIO_FLOOR`` of its mean, on every test sky. All values are gain-normalized
    (the pair's one gain cancels in the ratio).
    """

    role: str  # "d" or "delta"
    rests: list[np.ndarray]  # per sky: r without its selected lights (n, 3)
    lit: list[np.ndarray]  # per sky: (T, 3) where the ratio is checked
    d: list[np.ndarray]  # per sky: D at the lit texels (L,)
    delta: list[np.ndarray]  # per sky: X at the lit texels (L,)
    means: list[float]  # per sky: mean of D, what the RMS rule measures the pair against
    tolerance: float = RATIO_UNREFINED

    @classmethod
    def pair(cls, spec_d: Spectrum, spec_delta: Spectrum, skies, selection):
        """The two roles' :class:`RatioRefinement` (d's, delta's) for a pair's spectra."""
        rests, lit, d, delta, means = [], [], [], [], []
        for sky, d_true, delta_true, mask in ratio_checks(spec_d, spec_delta, skies):
            rest = sky.r.copy()
            rest[selection(sky.r)] = 0.0
            rests.append(rest)
            lit.append(mask)
            d.append(np.maximum(d_true[mask], 1e-12))
            delta.append(delta_true[mask])
            means.append(float(np.abs(d_true).mean()))
        return tuple(cls(role, rests, lit, d, delta, means) for role in ("d", "delta"))

    # Per sky, once: its lit values' places and the role's terms (:meth:`terms`), kept up
    # to ``KEPT_TERMS_BYTES`` in all, made again per move past that.
    _kept: dict = field(default_factory=dict, init=False, repr=False)
    _held: int = field(default=0, init=False, repr=False)

    def move(self, losses: np.ndarray, V: np.ndarray, j: int, s: int, terms=None
             ) -> np.ndarray:
        """Layer j's move of the ratio on sky ``s`` (L,): at the sky's lit values (``lit``)
        ordered by channel (R's, then G's, then B's, each in the texels' order), or, for a
        sky whose terms are not kept (past ``KEPT_TERMS_BYTES``), in the mask's order: the
        same order for every layer of a sky, so summed moves and their largest values are
        those of the lit values in any order. ``terms``: the sky's :meth:`terms`, if at hand
        (the values in their order).

        The values of ``(losses[j] * c_j)[lit] / D`` (delta's) and ``-X (losses[j] *
        c_j)[lit] / D**2`` (d's), ``c_j = V[:, j] @ r'`` in float32, bit for bit, made from
        the lit values only, with ``-X`` and ``D**2`` made once per sky: the product over the
        whole (T, 3) loss and its gather at the lit texels was most of the rule's time
        (docs/benchmarks.md, "The ratio rule's moves at the lit values")."""
        if terms is None and s not in self._kept and self._held + self._size(s) > (
                KEPT_TERMS_BYTES):
            # Past the kept terms (a large site's skies): as the rule made it before, over
            # the whole loss, in the mask's order (every move of this sky so: never kept).
            rest, lit, D, X = self.rests[s], self.lit[s], self.d[s], self.delta[s]
            change = (losses[j] * (V[:, j] @ rest).astype(np.float32))[lit]
            return change / D if self.role == "delta" else -X * change / D**2
        places, starts, numerator, denominator = self.terms(s) if terms is None else terms
        c = (V[:, j] @ self.rests[s]).astype(np.float32)  # (3,)
        loss = losses[j].reshape(-1)
        change = np.take(loss, places).astype(np.result_type(loss, c), copy=False)
        for channel in range(3):
            change[starts[channel] : starts[channel + 1]] *= c[channel]
        if numerator is None:
            return change / denominator
        return numerator * change / denominator

    def _size(self, s: int) -> int:
        """The bytes of sky ``s``'s :meth:`terms`."""
        values = len(self.d[s])
        return values * ((4 if self.lit[s].size < 2**31 else 8)
                         + np.asarray(self.d[s]).itemsize
                         + (np.asarray(self.delta[s]).itemsize if self.role == "d" else 0))

    def terms(self, s: int):
        """Sky ``s``'s lit values' flat places in a (T, 3) loss, ordered by channel; where
        each channel's start (4,); ``-X`` (d's, None for delta's) and ``D**2`` (d's) or
        ``D`` (delta's), in that order. Kept while the rule's kept terms are within
        ``KEPT_TERMS_BYTES`` (12 bytes per lit value for d's, 8 for delta's)."""
        kept = self._kept.get(s)
        if kept is not None:
            return kept
        lit = np.asarray(self.lit[s])
        channels = np.nonzero(lit)[1]  # each lit value's channel, in the mask's order
        order = np.concatenate([np.flatnonzero(channels == c) for c in range(3)])
        counts = lit.sum(axis=0)
        starts = np.concatenate([[0], np.cumsum(counts)])
        places = np.concatenate([np.flatnonzero(lit[:, c]) * 3 + c for c in range(3)])
        if lit.size < 2**31:
            places = places.astype(np.int32)
        D, X = np.asarray(self.d[s])[order], np.asarray(self.delta[s])[order]
        terms = ((places, starts, None, D) if self.role == "delta"
                 else (places, starts, -X, D**2))
        if self._held + self._size(s) <= KEPT_TERMS_BYTES:
            self._kept[s] = terms
            self._held += self._size(s)
        return terms

    def layers(self, losses: np.ndarray, f: Factors, keep_bytes: int = KEPT_SUMS_BYTES
               ) -> list[int]:
        """The layers to refine, given their coarse ``losses`` (k, T, 3).

        One layer's move on one sky is held at a time, besides the summed moves of the
        layers left unrefined: all k at once were k x skies x texels values, which raised
        the bake's peak memory (docs/benchmarks.md, "Figures behind choices in the code"),
        and a layer's moves on every sky are skies x texels (the same sums either way).

        Each move is made once for the layers' order (a sky's layers one after the other,
        its terms made once), and its largest value kept: until a
        layer is left unrefined, a layer is tested on its own moves, whose largest values
        those are (no move made again). A layer tested against the summed moves keeps its
        new sums, up to ``keep_bytes`` of them, for the skies where it is within the
        tolerance: if it is left unrefined they are the new sums (made again past
        ``keep_bytes``). The same values and tests as each move made for each use."""

        def largest(m) -> float:
            return float(np.abs(m).max(initial=0.0))

        skies = range(len(self.rests))
        worst, alone = [], []  # per layer: its largest move; whether each sky's is within
        each_sky = np.zeros((len(skies), f.k))  # a sky's terms made once for its layers
        for s in skies:
            terms = self.terms(s)
            each_sky[s] = [largest(self.move(losses, f.V, j, s, terms)) for j in range(f.k)]
        for j in range(f.k):
            each = [float(m) for m in each_sky[:, j]]
            worst.append(max(each, default=0.0))
            alone.append(all(m <= self.tolerance for m in each))
        total = None
        refine = []
        for j in np.argsort(worst, kind="stable"):
            if total is None:
                if alone[j]:
                    total = [self.move(losses, f.V, j, s) for s in skies]
                else:
                    refine.append(int(j))
                continue
            sums, held, fits = [], 0, True
            for s in skies:
                new = total[s] + self.move(losses, f.V, j, s)
                if not largest(new) <= self.tolerance:  # (a NaN fails, as it did)
                    fits = False
                    break
                if held + new.nbytes <= keep_bytes and len(sums) == s:
                    sums.append(new)
                    held += new.nbytes
                del new
            if not fits:
                refine.append(int(j))
                continue
            for s in skies:
                total[s] = sums[s] if s < len(sums) else total[s] + self.move(losses, f.V, j, s)
            del sums
        return sorted(refine)


class BaseResiduals:
    """What :func:`layers_to_refine_within` takes from each test sky that no encoding of the
    base layers changes, made once for every ETC1S split of a stack that is tried
    (bake.compress): the sky's coefficients ``c = V^T r'`` (k, 3) float32, the uncoded base
    composite's error ``truth - U c`` (T, 3) float32 and the master's mean. Each split's
    choice then adds only its layers' losses (``sum_j c_j e_j``) to that error: the same
    operations on the same values as the rule made alone, so the same layers.

    Kept in memory, or with ``folder`` in a file there (skies x texels: as large as the
    spectrum's composites, which a large atlas keeps on disk too)."""

    def __init__(self, f: Factors, skies, selection, truths, folder=None):
        self.cs, self.means = [], []
        T = len(f.U)
        self._store = None if folder is None else RowFile.create(
            Path(folder) / f"residuals-{id(self)}.npy", (len(skies) * T, 3))
        self._held = []
        for s, (c, a, mean) in enumerate(_sky_terms(f, skies, selection, truths)):
            self.cs.append(c)
            self.means.append(mean)
            if self._store is None:
                self._held.append(a)
            else:
                self._store.write(s * T, a)
        self.T = T

    def __iter__(self):
        """Each sky's ``(c, truth - U c, mean)``, in the skies' order."""
        return ((c, self.residual(s), mean)
                for s, (c, mean) in enumerate(zip(self.cs, self.means, strict=True)))

    def __len__(self) -> int:
        return len(self.cs)

    def residual(self, s: int) -> np.ndarray:
        """Sky ``s``'s ``truth - U c`` (T, 3) float32."""
        if self._store is None:
            return self._held[s]
        return self._store.read(s * self.T, (s + 1) * self.T)

    def held(self, items):
        """``enumerate(items)``, these errors removed when it ends or is left."""
        try:
            yield from enumerate(items)
        finally:
            self.remove()

    def remove(self) -> None:
        """Let go of the errors (and their file)."""
        if self._store is not None:
            self._store.remove()
        self._held = []


def _sky_terms(f: Factors, skies, selection, truths):
    """Per sky, one at a time: ``c = V^T r'`` (k, 3) float32, ``truth - U c`` (T, 3) float32
    and the master's mean (at least 1e-30)."""
    for sky, truth in zip(skies, truths, strict=True):
        rest = sky.r.copy()
        rest[selection(sky.r)] = 0.0
        c = (f.V.T @ rest).astype(np.float32)  # (k, 3)
        a = truth.astype(np.float32) - np.einsum("tck,kc->tc", f.U, c)
        yield c, a, max(float(truth.mean()), 1e-30)


def layers_to_refine_within(losses, f, skies, selection, truths, target: float,
                            refinable: int | None = None, restored=None,
                            base: BaseResiduals | None = None) -> list[int]:
    """The fewest base layers to refine so that the *decoded* composite stays within
    ``target`` (RMS error over the mean, as :func:`bake.stackerrors.record_errors` judges it)
    on every test sky: the RMS-judged stacks' budget-driven rule (the per-layer rule,
    :func:`layers_to_refine`, refines every layer whose own loss passes a tenth of the
    budget on some sky, whether or not the sum needs it: docs/compact-assets.md,
    "Encoding").

    ``losses`` (k, T, 3) what each layer's coarse encoding lost (ETC1S layers' too: their
    loss is part of what every sky sees, but only layers below ``refinable`` (default all)
    can be refined); ``truths`` the master's composite (T, 3) per sky, in the order of
    ``skies`` (an iterable, read once). Unit gain (the RMS-judged stacks): ``U`` and the
    losses are in the composite's units.

    On sky ``s`` (``c = V^T r'``) the coarse composite's error is ``a_s = truth - sum_j c_j
    (U_j - e_j)``, and refining layer ``j`` takes ``c_j r_j`` off it, ``r_j`` what its
    refinement restores as decoded: ``restored`` (refinable, T, 3), each refinable layer's
    refinement encoded and decoded. A refinement is an 8-bit image of the loss over the
    loss's own range, so where a few texels lost much it restores little elsewhere: with
    ``r_j = e_j`` (the default, an ideal refinement) the 40-light draft lightmap was
    predicted 0.89 % and decoded 1.30 %. Layers are added greedily, each time the one that
    lowers the worst sky's error most (ties: the lower index), until every sky is within
    ``target``, or, where refining every refinable layer would not bring it there, within
    1 % of what that would give. The errors come from Gram matrices (R x R per
    channel, R per sky and channel), so each step is cheap.

    ``base`` (for the same factors, skies and selection) replaces ``truths``: each sky's
    ``c``, ``truth - U c`` and mean as made once for all the splits tried."""
    k = f.k
    refinable = k if refinable is None else min(refinable, k)
    if refinable == 0 or not skies:
        return []
    restored = losses[:refinable] if restored is None else restored[:refinable]
    G = np.einsum("jtc,ltc->cjl", restored, restored, dtype=np.float64)  # (3, R, R)
    if base is not None and len(base) != len(skies):
        raise ValueError("the base residuals are for other skies")
    A, P, C, means = [], [], [], []
    for c, a, mean in _sky_terms(f, skies, selection, truths) if base is None else base:
        a = a + np.einsum("ktc,kc->tc", losses, c)
        A.append((a.astype(np.float64) ** 2).sum(axis=0))  # (3,)
        P.append(np.einsum("tc,jtc->cj", a, restored, dtype=np.float64))  # (3, R)
        C.append(c[:refinable].T.astype(np.float64))  # (3, R)
        means.append(mean)
    A, P, C, means = np.array(A), np.array(P), np.array(C), np.array(means)
    count = losses.shape[1] * 3  # the texel values the RMS is over

    def worst(chosen: list[int]) -> float:
        x = np.zeros((len(skies), 3, refinable))
        x[:, :, chosen] = C[:, :, chosen]  # the refined layers' c
        sq = A - 2.0 * (x * P).sum(axis=2) + np.einsum("scj,cjl,scl->sc", x, G, x)
        errors = np.sqrt(np.maximum(sq.sum(axis=1), 0.0) / count) / means
        return float(errors.max())

    # Where even every refinable layer refined stays over the target (a try the bake then
    # rejects, or its last, kept whatever its error), no more than brings the error within
    # 1 % of that floor: refining the rest would cost a layer each for nothing.
    target = max(target, 1.01 * worst(list(range(refinable))))
    chosen: list[int] = []
    current = worst(chosen)
    while current > target:
        candidates = [j for j in range(refinable) if j not in chosen]
        if not candidates:
            break
        scores = [worst(chosen + [j]) for j in candidates]
        best = int(np.argmin(scores))
        chosen.append(candidates[best])
        current = scores[best]
    return sorted(chosen)
