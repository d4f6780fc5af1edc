"""The one index rule: light i is position i in the manifest and in every basis stack.

A small occluder is placed exactly along one light's centroid direction as seen from a ground
point. Only that light's basis values there may drop when the virtual objects are present;
if the manifest's order and the stacks' order disagreed anywhere, another index would drop.
"""

from __future__ import annotations

import numpy as np

from bake.dome import Dome
from bake.evaluate import Build
from bake.pipeline import bake
from daylit.stackio import read_stack_exr
from tests.sites import make_site, sphere


def test_occluder_along_one_light_darkens_only_that_light(tmp_path):
    dome = Dome.for_light_count(40)
    target = 17
    direction = dome.centroids[target]
    distance = 4.0 / direction[1]  # put the ball 4 m up along the light's centroid
    centre = distance * direction
    radius = 0.25 * distance * np.sqrt(dome.solid_angles_sr[target] / np.pi)
    scene = make_site(
        tmp_path / "scene",
        virtual=[("ball", sphere(radius, centre), (0, 0, 0))],
        ground_albedo=(0, 0, 0),
        direct_rays=4000,
        ground_texel_m=0.25,
    )
    bake(scene, tmp_path / "build", progress=False, log=lambda m: None)
    build = Build(tmp_path / "build")
    lights = build.manifest["dome"]["lights"]
    assert [light["index"] for light in lights] == list(range(40))
    assert np.allclose(np.array(lights[target]["centroid"]), direction, atol=1e-9)
    sample = build.locate([0.0, 0.0, 0.0], [0, 1, 0])
    I = build.basis_at(sample, "I")[:, 1]
    d = build.basis_at(sample, "d")[:, 1]
    drop = 1.0 - I / d
    assert np.argmax(drop) == target
    assert drop[target] > 0.03
    others = np.delete(drop, target)
    assert np.all(np.abs(others) < 0.2 * drop[target])
    # The same holds in the raw EXR channels: channel group L0017 is light 17.
    stack = read_stack_exr(tmp_path / "build" / "exr" / "ground.I.exr")
    assert stack.shape[2] == 40
    texel = stack[int(sample.y), int(sample.x)]
    assert np.allclose(texel[:, 1] / d, I / d, atol=0.2 * drop[target])
