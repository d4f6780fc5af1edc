"""The same accuracy targets when the light, the sun and the camera's noise change.

Shorter runs (6 s) of the standard sequence with one thing changed each. Compressed video is
test_occlusion_synthetic_codecs.py's.
"""

from __future__ import annotations

import dataclasses

import pytest

from server.occlusion.synthetic import VIRTUAL_BOX, box_depth_image, default_site
from tests.server.occlusion.conftest import run_sequence

VARIANTS = {
    "sun high in the south": {"sun_azimuth_deg": 200.0, "sun_elevation_deg": 50.0},
    "low sun, shadows away": {"sun_azimuth_deg": 150.0, "sun_elevation_deg": 25.0},
    # sky states (server/occlusion/spectralcamera.py; the standard sequence's is clear all
    # along): clear to hazy (shadows from 0.25 to 0.42 of the sunlit ground, less blue), hazy
    # to thin cloud (paler, nearly neutral shadows: ln(G/B) shift 0.18 -> 0.08), thin cloud
    "clear to hazy": {"sky_states": ("clear", "hazy")},
    "hazy to thin cloud": {"sky_states": ("hazy", "thin cloud")},
    "thin cloud, pale shadows": {"sky_states": ("thin cloud", "thin cloud")},
    "daylight halving": {"brightness": (1.0, 0.5)},
    "noise of 3 codes": {"noise_codes": 3.0},
}


# Not met since the sequence is drawn with daylight spectra (2026-11-25; docs/occlusion.md,
# Limitations): strict, so that a fix shows as a pass to be taken out of this list. Empty
# since 2026-12-04: "hazy to thin cloud" (the sky brightening against the ground as the
# cloud veils the sun, person IoU 0.25) passes with the sky's gain of its own
# (regiongain.py); "sun high in the south" since shadow_ratio's floor is 0.05.
NOT_MET: dict[str, str] = {}


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=NOT_MET[n])) if n in NOT_MET
    else n for n in sorted(VARIANTS)])
def test_accuracy_holds_when_the_conditions_change(name):
    site = dataclasses.replace(default_site(480, 270, duration_s=6.0), **VARIANTS[name])
    virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
    _, stats = run_sequence(site, virtual)
    assert stats.person_iou >= 0.95, stats.person_iou
    assert stats.shadow_removed_fraction >= 0.9, stats.shadow_removed_fraction
    assert stats.person_kept >= 0.95, stats.person_kept
    wrong = [d for d in stats.decisions if (d[3] < 0.9 if d[2] else d[3] > 0.02)]
    assert len(wrong) <= len(stats.decisions) // 20, wrong
