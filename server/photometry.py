"""How a camera's pixel codes become sky radiance (Sato Sec. 5): the inverse response curve
(code -> linear) and the photometric settings (exposure, photometric factor, vignetting,
saturation level).

Units: a frame's linear value ``x = exposure * vignetting * L / photometric_factor`` for sky
radiance ``L`` in W/(m^2 sr).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def inverse_response_table(spec, levels: int = 256) -> np.ndarray:
    """The inverse camera response as a table ``(levels, 3)`` float32: code -> linear in [0, 1].

    ``spec`` is ``"linear"``, ``"srgb"`` (IEC 61966-2-1, the usual default of webcams),
    ``"gamma:G"`` (``x = (code / max)^G``), or a list of ``levels`` numbers (one curve for all
    channels) or of ``levels`` RGB triples, e.g. from a Debevec-Malik or Robertson calibration.
    """
    code = np.arange(levels, dtype=np.float64) / (levels - 1)
    if isinstance(spec, str):
        if spec == "linear":
            curve = code
        elif spec == "srgb":
            curve = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
        elif spec.startswith("gamma:"):
            try:
                g = float(spec.split(":", 1)[1])
            except ValueError:
                raise ValueError(f"response {spec!r}: gamma must be a number") from None
            if not 0.1 <= g <= 10.0:
                raise ValueError(f"response {spec!r}: gamma must be between 0.1 and 10")
            curve = code**g
        else:
            raise ValueError(f"unknown response {spec!r}: use linear, srgb, gamma:G or a table")
        return np.repeat(curve[:, None], 3, axis=1).astype(np.float32)
    table = np.asarray(spec, dtype=np.float64)
    if table.ndim == 1:
        table = np.repeat(table[:, None], 3, axis=1)
    if table.shape != (levels, 3):
        raise ValueError(f"a response table needs {levels} values or RGB triples: {table.shape}")
    if not np.all(np.isfinite(table)) or np.any(np.diff(table, axis=0) < 0):
        raise ValueError("a response table must be finite and non-decreasing")
    return (table / max(table[-1].max(), 1e-12)).astype(np.float32)


@dataclass
class Photometry:
    """How pixel codes become radiance (Sato Sec. 5).

    Attributes
    ----------
    response : str or list
        Inverse response curve, see :func:`inverse_response_table`.
    exposure : float
        Linear value of unit radiance (W/(m^2 sr)) at the camera's fixed setting; a frame
        that reports its own exposure (the simulated sky, auto-exposing cameras) overrides it.
    photometric_factor : RGB
        Multiplies the result: the calibration between camera units and the unit radiance of
        the baked basis (white balance included).
    vignetting : tuple of float
        Relative illumination ``g(theta) = 1 + a1 theta^2 + a2 theta^4 + ...`` (theta in radians
        from the optical axis); measured values are divided by it. Empty: none.
    saturation_level : float
        Fraction of full scale at or above which a code counts as clipped.
    """

    response: object = "srgb"
    exposure: float = 1.0
    photometric_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    vignetting: tuple[float, ...] = ()
    saturation_level: float = 0.98

    def vignetting_gain(self, theta_rad: np.ndarray) -> np.ndarray:
        gain = np.ones_like(theta_rad)
        t2 = theta_rad * theta_rad
        power = np.ones_like(theta_rad)
        for a in self.vignetting:
            power = power * t2
            gain = gain + a * power
        return gain

