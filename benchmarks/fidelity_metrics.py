"""The fidelity benchmark's metrics: how daylit's answers are scored against Radiance's.

PSNR with the largest reference value as peak, RMS error relative to the mean reference; along
a shadow line the 10-90 % penumbra width and the 50 % point of the normalised (isotonic)
profile.
"""

from __future__ import annotations

import math

import numpy as np


def psnr_rms(got: np.ndarray, ref: np.ndarray) -> dict:
    """PSNR (dB, peak = the largest reference value over these points and channels) and RMS
    error relative to the mean reference (%)."""
    keep = np.all(np.isfinite(got), axis=1) & np.all(np.isfinite(ref), axis=1)
    got, ref = got[keep], ref[keep]
    if len(ref) == 0:
        return {"n": 0, "psnr_db": float("nan"), "rms_pct": float("nan")}
    mse = float(np.mean((got - ref) ** 2))
    peak = float(ref.max())
    psnr = float("inf") if mse == 0 else 10.0 * math.log10(peak**2 / mse)
    return {"n": int(len(ref)), "psnr_db": psnr, "rms_pct": 100.0 * math.sqrt(mse) / ref.mean(),
            "peak_W_m2": peak, "mean_W_m2": float(ref.mean()),
            "bias_pct": 100.0 * float((got - ref).mean() / ref.mean())}


def isotonic(y: np.ndarray) -> np.ndarray:
    """Least-squares non-decreasing fit (pool adjacent violators)."""
    values, weights, sizes = [], [], []
    for v in y:
        values.append(float(v))
        weights.append(1.0)
        sizes.append(1)
        while len(values) > 1 and values[-2] > values[-1]:
            w = weights[-2] + weights[-1]
            values[-2] = (values[-2] * weights[-2] + values[-1] * weights[-1]) / w
            weights[-2] = w
            sizes[-2] += sizes[-1]
            del values[-1], weights[-1], sizes[-1]
    return np.repeat(values, sizes)


def profile_points(t: np.ndarray, e: np.ndarray) -> dict:
    """10, 50 and 90 % points of a profile across a shadow edge (umbra at low ``t``),
    normalised by its own ends (the mean of its first and last 8 %), after an isotonic fit."""
    k = max(2, len(e) // 12)
    lo, hi = float(e[:k].mean()), float(e[-k:].mean())
    f = isotonic((e - lo) / (hi - lo))
    out = {"umbra_W_m2": lo, "lit_W_m2": hi}
    for level in (0.1, 0.5, 0.9):
        i = int(np.argmax(f >= level))
        if i == 0:
            out[f"t{round(100 * level)}_m"] = float(t[0])
            continue
        f0, f1 = f[i - 1], f[i]
        out[f"t{round(100 * level)}_m"] = float(t[i - 1] + (level - f0) / max(f1 - f0, 1e-12)
                                                * (t[i] - t[i - 1]))
    out["width_m"] = out["t90_m"] - out["t10_m"]
    return out
