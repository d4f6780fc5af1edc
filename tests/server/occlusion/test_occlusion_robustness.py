"""The same accuracy targets when the light, the sun and the camera's noise change.

Shorter runs (6 s) of the standard sequence with one thing changed each. Compressed video is a
known weakness (docs/occlusion.md, Limitations) and is not asserted here.
"""

from __future__ import annotations

import dataclasses

import pytest

from server.occlusion.synthetic import VIRTUAL_BOX, box_depth_image, default_site
from tests.server.occlusion.conftest import run_sequence

VARIANTS = {
    "sun high in the south": {"sun_azimuth_deg": 200.0, "sun_elevation_deg": 50.0},
    "low sun, shadows away": {"sun_azimuth_deg": 150.0, "sun_elevation_deg": 25.0},
    "clear blue sky, warmer sun": {"t_sky_k": 15000.0, "t_lit_k": (6500.0, 5000.0)},
    "daylight halving": {"brightness": (1.0, 0.5)},
    "pale shadows": {"shadow_fraction": 0.55},
    "noise of 3 codes": {"noise_codes": 3.0},
}


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_accuracy_holds_when_the_conditions_change(name):
    site = dataclasses.replace(default_site(480, 270, duration_s=6.0), **VARIANTS[name])
    virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
    _, stats = run_sequence(site, virtual)
    assert stats.person_iou >= 0.95, stats.person_iou
    assert stats.shadow_removed_fraction >= 0.9, stats.shadow_removed_fraction
    assert stats.person_kept >= 0.95, stats.person_kept
    wrong = [d for d in stats.decisions if (d[3] < 0.9 if d[2] else d[3] > 0.02)]
    assert len(wrong) <= len(stats.decisions) // 20, wrong
