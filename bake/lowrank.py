"""Low-rank factorization of a basis stack and the choice of its rank: the prior-weighted
eigenbasis and the rank search (RMS error, and the per-texel shadow ratio of a shadowing
pair). Which base layers need a refinement after coarse encoding: bake.refinement.

A stack ``B`` (texels x n lights, per RGB channel) is approximated as ``U V^T r'`` plus the
selected lights' own images (bake.compress). ``U V^T`` (Teo et al., cited in Sato Sec. 8) is
a rank-k approximation, weighted by the covariance ``C`` of expected light vectors with their
brightest patches removed: with ``S = C^(1/2)`` and ``Y`` the top eigenvectors of ``S G S``
(``G = B^T B``), ``U = B S Y`` and ``V = S^-1 Y``; it is the best rank-k fit for those skies
(not for arbitrary columns). ``k`` is the smallest rank whose error stays within a share of
the budget on the test skies (bake.testskies).

Shapes: texels ``M`` (T, n, 3) over a stack's valid texels, gain (T,), ``U`` (T, 3, k),
``V`` (n, k), light vectors (n, 3) in W/(m^2 sr).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bake.rowstore import ROW_BLOCK_BYTES, RowFile, row_block, rows_of
from bake.testskies import TestSky
from daylit.selection import Selection

TRUNCATION_SHARE = 0.6  # of the budget allowed to rank truncation; the rest is for encoding
GRAM_ROWS = 65536  # rows per chunk when accumulating B^T B in float64


@dataclass
class Factors:
    """A stack's factors. ``U`` (T, 3, k) over the valid texels, ``V`` (n, k)."""

    k: int
    U: np.ndarray
    V: np.ndarray
    truncation_error: dict


def prior_sqrt(training: list[np.ndarray], selection: Selection):
    """``S = C^(1/2)`` and ``S^-1`` of the second moment of training vectors whose selected
    lights are removed (those come from their own images), with a small ridge."""
    columns = []
    for r in training:
        r = r.copy()
        r[selection(r)] = 0.0
        columns.append(r)
    X = np.concatenate(columns, axis=1)  # (n, 3 * skies)
    C = X @ X.T / X.shape[1]
    C += 1e-4 * np.trace(C) / len(C) * np.eye(len(C))
    w, E = np.linalg.eigh(C)
    w = np.maximum(w, w.max() * 1e-12)
    return (E * np.sqrt(w)) @ E.T, (E / np.sqrt(w)) @ E.T


RATIO_TRUNCATION = 0.008  # per-texel shadow-ratio error allowed to truncation (test: 0.02)
# Per-texel shadow-ratio error that the base layers left unrefined may add, for each stack of
# a pair (d and delta: twice this at most). Most of a pair's layers can go unrefined within
# it, and refinements had been most of the base's bytes (docs/benchmarks.md,
# "Figures behind choices in the code").
RATIO_UNREFINED = 0.002
RATIO_FLOOR = 0.05  # ratios are checked where sum r d exceeds this share of its mean


@dataclass
class Spectrum:
    """One stack's valid texels, gain-normalized, and what choosing a rank needs.

    ``M`` (T, n, 3) are the texels divided by their gain ``g`` (T,), in memory or on disk
    (a :class:`bake.rowstore.RowFile`, read by blocks of rows: every use of ``M`` is row-wise,
    so a stack's spectrum is never held whole); the prior-weighted eigenvectors ``Y`` (n, n,
    strongest first) are those of the normalized texels, so the basis fits every texel to
    the same *relative* precision (dim texels too); the per-channel Gram matrices ``G``
    (3, n, n) and column sums (3, n) are of the *absolute* values ``g M``, which the error
    budget is stated in. ``work``: where the composites under the test skies are kept
    (:meth:`truths`; None: in memory).
    """

    M: np.ndarray
    gain: np.ndarray
    G: np.ndarray
    colsum: np.ndarray
    Y: np.ndarray
    work: Path | None = None
    _width: int = 0
    _truths: dict = field(default_factory=dict)

    @property
    def T(self) -> int:  # noqa: N802  (texels, as in the shapes above)
        return len(self.M)

    @property
    def n(self) -> int:
        return self.M.shape[1]

    def blocks(self) -> list[tuple[int, int]]:
        """Row ranges of the texels, each a working block (bake.rowstore.row_block)."""
        step = row_block(self.n)
        return [(a, min(a + step, self.T)) for a in range(0, self.T, step)]

    def rows(self, start: int, stop: int) -> np.ndarray:
        """``M[start:stop]`` (a view in memory, a fresh array from disk)."""
        return rows_of(self.M, start, stop)

    def columns(self, lights) -> np.ndarray:
        """``M[:, lights]`` (T, len(lights), 3), read by blocks of rows."""
        lights = np.asarray(lights, dtype=int)
        out = np.empty((self.T, len(lights), 3), dtype=np.float32)
        if len(lights):
            for a, b in self.blocks():
                out[a:b] = self.rows(a, b)[:, lights]
        return out

    def projection_width(self, k: int) -> int:
        """The columns ``M S Y`` is computed with for rank k: the largest rank asked so far,
        doubling (as a cache of them was: the products' first k columns, and the sums over
        them, then take the same path)."""
        if self._width < k:
            self._width = min(self.Y.shape[1], max(k, 2 * self._width))
        return self._width

    def project_rows(self, S: np.ndarray, K: int, rows: np.ndarray) -> np.ndarray:
        """``rows S Y_K`` (b, 3, K) float32 of texel rows (b, n, 3) of ``M``."""
        SY = (S @ self.Y[:, :K]).astype(np.float32)
        flat = np.ascontiguousarray(rows.transpose(0, 2, 1)).reshape(len(rows) * 3, self.n)
        return (flat @ SY).reshape(len(rows), 3, K)

    def truths(self, skies: list[TestSky]):
        """Exact normalized composites ``M r`` (T, 3) under the test skies, one per sky as
        they are iterated; computed once (by blocks of rows, each block one BLAS product for
        every missing sky: :func:`sky_composites`) and kept in memory or, with ``work``, on
        disk (skies x texels: a large atlas's were 1 GB a stack)."""
        missing = [sky for sky in skies if sky.name not in self._truths]
        if missing:
            r = np.stack([sky.r for sky in missing])
            if self.work is None:
                values = sky_composites(self.M, r)
                self._truths.update(zip((sky.name for sky in missing), values, strict=True))
            else:
                store = RowFile.create(
                    Path(self.work) / f"truths-{id(self)}-{len(self._truths)}.npy",
                    (len(missing) * self.T, 3),
                )
                for a, b in self.blocks():
                    values = sky_composites(self.rows(a, b), r)
                    for j in range(len(missing)):
                        store.write(j * self.T + a, values[j])
                for j, sky in enumerate(missing):
                    self._truths[sky.name] = (store, j)
        return (self._truth(sky.name) for sky in skies)

    def _truth(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """The composite under the sky ``name`` (computed by :meth:`truths`), rows
        ``start .. stop`` of it."""
        stop = self.T if stop is None else min(stop, self.T)
        held = self._truths[name]
        if isinstance(held, np.ndarray):
            return held[start:stop]
        store, j = held
        return store.read(j * self.T + start, j * self.T + stop)

    def remove(self) -> None:
        """Remove what the spectrum keeps on disk (its texels, its composites)."""
        if isinstance(self.M, RowFile):
            self.M.remove()
        for held in self._truths.values():
            if isinstance(held, tuple):
                held[0].remove()
        self._truths = {}

    def absolute_truths(self, skies: list[TestSky]):
        """Exact composites of the absolute values ``g M r`` (T, 3) under the test skies."""
        return (truth * self.gain[:, None] for truth in self.truths(skies))

    @classmethod
    def of(cls, M, gain: np.ndarray, S: np.ndarray, work: Path | None = None) -> Spectrum:
        T, n = len(M), M.shape[1]
        G = np.zeros((3, n, n))
        G_normalized = np.zeros((n, n))
        colsum = np.zeros((3, n))
        # With unit gain (the RMS-judged stacks) the normalized Gram matrix is the sum of the
        # absolute ones: half the products.
        unit_gain = bool(np.all(gain == 1.0))
        for start in range(0, T, GRAM_ROWS):
            # float32 products per block (BLAS sgemm), accumulated in float64 across blocks.
            rows = rows_of(M, start, start + GRAM_ROWS)
            block = np.ascontiguousarray(rows.transpose(2, 0, 1))
            del rows
            g = gain[start : start + GRAM_ROWS].astype(np.float32)
            for c in range(3):
                absolute = block[c] if unit_gain else block[c] * g[:, None]
                G[c] += absolute.T @ absolute
                colsum[c] += absolute.sum(axis=0, dtype=np.float64)
                if not unit_gain:
                    G_normalized += block[c].T @ block[c]
        if unit_gain:
            G_normalized = G.sum(axis=0)
        eigenvalues, Y = np.linalg.eigh(S @ G_normalized @ S)
        if work is None and isinstance(M, RowFile):
            work = M.path.parent
        return cls(M, gain, G, colsum, Y[:, np.argsort(eigenvalues)[::-1]], work)

    def composites(self, P: np.ndarray, k: int, S_inv, rs: list[np.ndarray],
                   chosen: list[np.ndarray], rows: np.ndarray) -> np.ndarray:
        """(len(rs), b, 3) normalized composites of rank k under the light vectors ``rs``
        (each (n, 3)) with the lights ``chosen`` (one index array per vector) exact,
        ``M (Q_k r' + r_A)``, from the projections ``P`` (b, 3, K >= k) of texel rows
        ``rows`` of ``M`` (b, n, 3).

        The rank-k part is one float32 matrix product per channel for every vector at once,
        ``P[:, c, :k]`` (b, k) by the vectors' coefficients ``c = Y_k^T S^-1 r'`` (k, len(rs)):
        until 2026-12-06 an einsum per vector, which walked ``P`` once per sky and was the
        largest array cost of a shadowing pair's rank search (docs/benchmarks.md, "One
        composite per sky, one product per rank"). Float32 either way, summed in another
        order: the same values to float32 rounding."""
        C = np.empty((3, k, len(rs)), dtype=np.float32)
        for s, (r, lights) in enumerate(zip(rs, chosen, strict=True)):
            rest = r.copy()
            rest[lights] = 0.0
            C[:, :, s] = (self.Y[:, :k].T @ (S_inv @ rest)).astype(np.float32).T  # (3, k)
        out = np.empty((len(rs), len(P), 3), dtype=np.float32)
        for c in range(3):
            out[:, :, c] = (P[:, c, :k] @ C[c]).T
        for s, (r, lights) in enumerate(zip(rs, chosen, strict=True)):
            if len(lights):
                out[s] += np.einsum("tnc,nc->tc", rows[:, lights], r[lights].astype(np.float32))
        return out


def sky_composites(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``sum_i M[t, i, c] r[s, i, c]``: the composites (K, T, 3) float32 of a stack's texels
    ``M`` (T, n, 3) under K light vectors ``r`` (K, n, 3).

    One BLAS product of the texels as (T, 3n) rows with a block matrix (3n, 3K) that keeps the
    channels apart. Two thirds of its products are with zeros, yet it is far faster than an
    einsum per sky, which walks the whole stack each time (docs/benchmarks.md, "Baking")."""
    T, n, _ = M.shape
    K = len(r)
    blocks = np.zeros((n, 3, 3, K), dtype=np.float32)  # [light, channel in, channel out, sky]
    for c in range(3):
        blocks[:, c, c, :] = r[:, :, c].T
    rows = np.ascontiguousarray(M, dtype=np.float32).reshape(T, 3 * n)
    out = rows @ blocks.reshape(3 * n, 3 * K)  # (T, 3K)
    return np.ascontiguousarray(out.reshape(T, 3, K).transpose(2, 0, 1))


def rms_rank(spec: Spectrum, S, S_inv, skies, selection, settings) -> tuple[int, dict]:
    """Smallest k whose RMS error is within ``TRUNCATION_SHARE`` of the budget on every sky.

    The error of every rank comes in closed form from the per-channel Gram matrices,
    ``err_c^2 = e_c^T (I - Q)^T G_c (I - Q) e_c`` with ``e = r - r_A``: no pass over texels.
    """
    T, n = spec.T, spec.n
    rest, mean = [], []
    for sky in skies:
        e = sky.r.copy()
        e[selection(sky.r)] = 0.0
        rest.append(e)
        mean.append(np.einsum("cn,nc->", spec.colsum, sky.r) / (3 * T))
    target = TRUNCATION_SHARE * settings.budget
    errors = {}
    for k in range(1, min(settings.max_rank, n) + 1):
        Yk = spec.Y[:, :k]
        errors = {}
        for sky, e, mu in zip(skies, rest, mean, strict=True):
            d = e - S @ (Yk @ (Yk.T @ (S_inv @ e)))  # (I - Q) e, (n, 3)
            sq = sum(d[:, c] @ spec.G[c] @ d[:, c] for c in range(3)) / (3 * T)
            errors[sky.name] = float(np.sqrt(max(sq, 0.0)) / max(mu, 1e-30))
        if max(errors.values()) <= target:
            return k, errors
    return min(settings.max_rank, n), errors


def ratio_checks(spec_d: Spectrum, spec_delta: Spectrum, skies):
    """Per sky ``(sky, d, delta, lit)``: a shadowing pair's exact normalized composites
    (T, 3) and where its ratio is checked, ``sum r d`` above ``RATIO_FLOOR`` of its mean
    (T, 3) bool."""
    for sky, d_true, delta_true, d_absolute in zip(
        skies,
        spec_d.truths(skies),
        spec_delta.truths(skies),
        spec_d.absolute_truths(skies),
        strict=True,
    ):
        yield sky, d_true, delta_true, d_absolute > RATIO_FLOOR * d_absolute.mean()


def ratio_error(
    spec_delta: Spectrum, spec_d: Spectrum, k: int, S, S_inv, skies, selection, settings,
    above: float | None = None,
) -> float:
    """Worst per-texel error of ``sum r I / sum r d`` at rank k over the skies, where
    ``sum r d`` is not tiny (above ``RATIO_FLOOR`` of its mean), with ``I = d - delta``. The
    two spectra share one gain, which cancels in the ratio.

    By blocks of texel rows (the two spectra's projections of a block, then the skies'
    composites a batch at a time, :meth:`Spectrum.composites`), with each sky's threshold
    from its whole composite first: the same maximum as over whole arrays, without holding
    texels x rank or texels x skies (a batch's composites within ``ROW_BLOCK_BYTES``).

    With ``above``, the search stops at the first block and sky whose error passes it and
    returns the worst found so far: over ``above`` exactly when the whole maximum is (a
    rank being tested needs no more; :func:`ratio_rank`)."""
    floors = [RATIO_FLOOR * d.mean() for d in spec_d.absolute_truths(skies)]
    spec_delta.truths(skies)  # computed once, read by blocks below
    chosen = [selection(sky.r) for sky in skies]
    K_delta, K_d = spec_delta.projection_width(k), spec_d.projection_width(k)
    worst = 0.0
    for a, b in spec_d.blocks():
        rows_d, rows_delta = spec_d.rows(a, b), spec_delta.rows(a, b)
        P_d = spec_d.project_rows(S, K_d, rows_d)
        P_delta = spec_delta.project_rows(S, K_delta, rows_delta)
        gain = spec_d.gain[a:b, None]
        # The rank-k composites of a batch of skies at a time, each sky then judged as
        # before: one sky, then twice as many each batch (a rank over the bound is mostly
        # rejected within the first few skies), up to two (skies, b, 3) arrays within the
        # working block's bytes.
        most = max(1, ROW_BLOCK_BYTES // (2 * 3 * 4 * max(b - a, 1)))
        first, batch = 0, 1
        while first < len(skies):
            these = range(first, min(first + batch, len(skies)))
            first, batch = these.stop, min(2 * batch, most)
            rs, lights = [skies[s].r for s in these], [chosen[s] for s in these]
            D_k = spec_d.composites(P_d, k, S_inv, rs, lights, rows_d)
            X_k = spec_delta.composites(P_delta, k, S_inv, rs, lights, rows_delta)
            for i, s in enumerate(these):
                sky = skies[s]
                d_true = spec_d._truth(sky.name, a, b)
                I_true = d_true - spec_delta._truth(sky.name, a, b)
                lit = d_true * gain > floors[s]
                d_k = D_k[i]
                I_k = d_k - X_k[i]
                if lit.any():
                    error = np.abs(
                        I_k / np.maximum(d_k, 1e-12) - I_true / np.maximum(d_true, 1e-12)
                    )
                    worst = max(worst, float(error[lit].max()))
                    if above is not None and worst > above:
                        return worst
            del D_k, X_k
    return worst


def ratio_rank(spec_I, spec_d, k_start, S, S_inv, skies, selection, settings) -> int:
    """Smallest rank at least ``k_start`` found (doubling, then bisection) whose shadow ratio
    is within ``RATIO_TRUNCATION`` at every texel on the skies; at most ``max_rank``."""
    top = min(settings.max_rank, spec_I.n)

    def ok(k):  # a rank over the bound is rejected at its first texels over it
        return (
            ratio_error(spec_I, spec_d, k, S, S_inv, skies, selection, settings,
                        above=RATIO_TRUNCATION)
            <= RATIO_TRUNCATION
        )

    low, high = k_start, k_start
    while not ok(high):
        if high >= top:
            return top
        low, high = high + 1, min(top, 2 * high)
    while low < high:
        middle = (low + high) // 2
        if ok(middle):
            high = middle
        else:
            low = middle + 1
    return high


def factors(spec: Spectrum, k: int, S, S_inv, errors: dict) -> Factors:
    """``U = M S Y_k`` (T, 3, k) and ``V = S^-1 Y_k`` (n, k)."""
    K = spec.projection_width(k)
    U = np.empty((spec.T, 3, k), dtype=np.float32)
    for a, b in spec.blocks():
        U[a:b] = spec.project_rows(S, K, spec.rows(a, b))[:, :, :k]
    return Factors(k, U, (S_inv @ spec.Y[:, :k]).astype(np.float32), errors)


# A texel's level is at least this share of its values' mean magnitude (texel_means): the
# signed mean of a texel with values of both signs is the level of its composites, which its
# shadow ratio is measured against, but it can fall to zero. A tenth keeps every demo texel at
# its signed mean (the least share there was 0.15) and the palace's ground pair within its
# budget, its ratio 0.09 off at worst against 0.29 with the magnitude itself, both at one of
# its two texels whose signed mean is below zero (docs/benchmarks.md, "The palace's ground
# pair").
LEVEL_FLOOR = 0.1


def gain_of(M: np.ndarray) -> np.ndarray:
    """Per-texel gain (T,): the texel's level (:func:`texel_means`), floored at a millionth
    of its overall mean so that empty texels stay finite."""
    return floored_gain(texel_means(M))


def texel_means(M: np.ndarray) -> np.ndarray:
    """Each texel's level (T,) float64, of rows ``M`` (T, n, 3) (row-wise: the same bits by
    blocks of rows): the mean of its basis values over lights and channels, but never below
    ``LEVEL_FLOOR`` times the mean of their magnitudes.

    A texel moved onto a contact line holds its direct light extended along the chord to its
    buried centre (bake.contact.extrapolate_direct), negative for the lights hidden at the
    contact line, and its signed mean can be near zero or below it. Floored there by
    :func:`floored_gain`, the gain was a millionth of the atlas's level, that texel's
    normalized values millions, and every base layer's 8-bit range was theirs: the palace's
    ground pair decoded 583 % off (docs/benchmarks.md, "The palace's ground pair"). Where no
    value is negative the two means are equal, and the level is the mean, bit for bit."""
    signed = M.mean(axis=(1, 2), dtype=np.float64)
    magnitude = np.abs(M).mean(axis=(1, 2), dtype=np.float64)
    return np.maximum(signed, LEVEL_FLOOR * magnitude)


def floored_gain(g: np.ndarray) -> np.ndarray:
    """:func:`gain_of` from every valid texel's :func:`texel_means` ``g`` (T,)."""
    return np.maximum(g, 1e-6 * max(g.mean(), 1e-30)).astype(np.float32)


def factor(M, S, S_inv, skies, selection, settings, min_k: int = 0) -> Factors:
    """Choose k (RMS criterion, at least ``min_k``) and factor ``M`` (T, n, 3) normalized
    by its own gain."""
    gain = gain_of(M)
    spec = Spectrum.of(M / gain[:, None, None], gain, S)
    k, errors = rms_rank(spec, S, S_inv, skies, selection, settings)
    return factors(spec, max(k, min_k), S, S_inv, errors)
