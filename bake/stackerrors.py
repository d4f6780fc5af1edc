"""A compressed stack's decoded composite against its master on the test skies: the errors a
manifest entry records (:func:`record_errors`), and the verdict on an ETC1S split tried by
bake.compress (:func:`within_budget`), which stops at the first sky over the budget.

Shapes: a composite (T, 3) float32 at a stack's valid texels; the master's the same.
"""

from __future__ import annotations

import numpy as np

from daylit.selection import Selection

DIGITS = 6  # an entry's errors are rounded to this many decimals


def selected_by_any(skies, selection: Selection) -> list[int]:
    """Every light that some test sky selects (decoded in one run)."""
    return sorted({int(i) for sky in skies for i in selection(sky.r)})


def sky_error(approx: np.ndarray, reference: np.ndarray) -> float:
    """RMS of ``approx - reference`` (T, 3) over the mean of ``reference``."""
    return float(np.sqrt(((approx - reference) ** 2).mean()) / max(reference.mean(), 1e-30))


def record_errors(entry: dict, references: list[np.ndarray], composite, skies) -> None:
    """RMS error over the mean of ``composite(r)`` (T, 3) against the master's composite
    ``references`` (one (T, 3) per sky) on every test sky, into ``entry["error"]``."""
    errors = {}
    for sky, reference in zip(skies, references, strict=True):
        errors[sky.name] = sky_error(composite(sky.r), reference)
    record_sky_errors(entry, errors)


def record_sky_errors(entry: dict, errors: dict) -> None:
    """``errors`` {sky name: RMS error over the mean} into ``entry["error"]``: each rounded
    to ``DIGITS`` decimals (``"encoded"``) and their largest (``"max"``)."""
    entry["error"]["encoded"] = {k: round(v, DIGITS) for k, v in errors.items()}
    entry["error"]["max"] = round(max(errors.values()), DIGITS)


def within_budget(entry: dict, reference, composite, skies, budget: float,
                  first: int = 0) -> tuple[bool, int]:
    """Whether ``composite(r)`` is within ``budget`` of the master on every test sky, as
    :func:`record_errors` followed by ``entry["error"]["max"] <= budget`` decides it, and the
    sky that decided it: the skies are judged from the ``first``'s on (then from the start),
    and the first over the budget ends the judgement (its index is returned; a split that is
    rejected records nothing). Within the budget, every sky was judged and the errors are
    recorded into ``entry`` exactly as :func:`record_errors` records them (in the skies'
    order); the index returned is then ``first``.

    ``reference(sky)`` the master's composite (T, 3) under one sky. The same verdict: an
    entry's maximum is the rounded largest error, and rounding keeps the order of errors, so
    it is over the budget exactly when some sky's rounded error is."""
    errors = {}
    order = list(range(first, len(skies))) + list(range(first))
    for s in order:
        sky = skies[s]
        error = sky_error(composite(sky.r), reference(sky))
        if round(error, DIGITS) > budget:
            return False, s
        errors[s] = error
    record_sky_errors(entry, {sky.name: errors[s] for s, sky in enumerate(skies)})
    return True, first
