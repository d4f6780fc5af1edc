"""The shipped GLSL, evaluated in headless Chromium against answers computed here.

- ``irradianceSH`` (materials.glsl.js, hull-plane mode's shading): on skies and normals that
  tell the nine terms apart (bright toward +x, +z or -y only, bands, random quadratics; each
  axis both ways and oblique normals), against the cosine-weighted integral of the sky over
  each normal's hemisphere (tests/web/sh9oracle.py: exact quadrature, no harmonics, and the
  harmonics' constants written from the paper).
- ``domeSkyFragment`` (relight.glsl.js, the sky's one GLSL partition of unity, also in the
  view sky's fragment): against ``bake.views.sky_weights``, the Python the baker uses, on a
  random dome and light vector.

Tolerances: the SH irradiance's constants have six digits (1.6e-6 relative measured between
the quadrature and the paper's formula) and the GPU float32; 1e-4 of the sky's largest
irradiance is far above both and far below the error of any misplaced term (an x/z swap is
off by 0.3 or more of it on the skies bright toward +x or +z). The dome: 1e-3 of the sky's
largest radiance (SwiftShader's float32 exp, sin and cos: measured median 9e-6, worst 2.0e-4);
a width 1.4 % off (factor 0.69 or 0.71 for 0.7) is off by 2e-2.
"""

from __future__ import annotations

import numpy as np
import pytest

from bake.views import sky_weights
from tests.web import sh9oracle
from tests.web.shaderpage import pixels, shader_page

pytestmark = [pytest.mark.browser]

SH_PROGRAM = """async (args) => {
  const { irradianceSHChunk, sh9Fragment } = await import('/src/materials.glsl.js');
  const source = `#version 300 es
precision highp float;
${irradianceSHChunk}
uniform vec3 normals[${args.count}];
out vec4 outColor;
void main() { outColor = vec4(irradianceSH(normals[int(gl_FragCoord.x)]), 1.0); }`;
  const out = window.runFragment(source, args.count, 1, {
    'L[0]': { type: '3fv', value: args.L }, 'normals[0]': { type: '3fv', value: args.normals },
  });
  return { out, shipped: sh9Fragment.includes(irradianceSHChunk) };
}"""


def test_irradiance_sh_shader_matches_the_integral(browser):
    rng = np.random.default_rng(21)
    skies = sh9oracle.skies_that_differ(rng)
    normals = sh9oracle.normals_that_differ()
    names = list(skies)
    worst = 0.0
    with shader_page(browser) as (page, errors):
        # Three skies a draw, one per colour channel.
        for first in range(0, len(names), 3):
            group = names[first:first + 3]
            L = np.stack([sh9oracle.sky_sh9(skies[name]) for name in group], axis=1)  # (9, 3)
            got = page.evaluate(SH_PROGRAM, {"L": L.ravel().tolist(), "count": len(normals),
                                             "normals": normals.ravel().tolist()})
            assert got["shipped"], "sh9Fragment does not use the chunk this test evaluates"
            gpu = pixels(got["out"], len(normals), 1)[0, :, :3]
            for ch, name in enumerate(group):
                want = sh9oracle.irradiance(skies[name], normals)
                # The oracle agrees with itself: the paper's formula on these band-limited skies.
                paper = sh9oracle.irradiance_from_sh9(L[:, ch], normals)
                assert np.allclose(paper, want, rtol=1e-5, atol=1e-5 * want.max())
                error = np.abs(gpu[:, ch] - want).max() / want.max()
                worst = max(worst, error)
                assert error <= 1e-4, (name, gpu[:, ch], want)
        assert not errors, errors
    print(f"\nirradianceSH: worst {worst:.2e} of the sky's largest irradiance")


DOME_PROGRAM = """async (args) => {
  const { domeSkyFragment, skyInvWidth2 } = await import('/src/relight.glsl.js');
  const n = args.n;
  const data = new Float32Array(4 * n * 2);
  for (let i = 0; i < n; i++) {
    data.set([...args.r.slice(3 * i, 3 * i + 3), 1], 4 * i);
    data.set([...args.centroids.slice(3 * i, 3 * i + 3), 1], 4 * (n + i));
  }
  const source = '#version 300 es\\n' + domeSkyFragment({ lights: n, encodeRGBE: false });
  return window.runFragment(source, args.width, args.height, {
    lightTex: { type: 'tex', value: { width: n, height: 2, data: Array.from(data) } },
    invWidth2: { type: '1f', value: [skyInvWidth2(n)] },
    size: { type: '2f', value: [args.width, args.height] },
  });
}"""


def test_dome_sky_shader_matches_python_sky_weights(browser):
    """The client's sky (one GLSL copy of the partition of unity, and the width it is given)
    against bake.views.sky_weights, the baker's."""
    rng = np.random.default_rng(5)
    n, width, height = 40, 64, 16
    centroids = rng.normal(size=(n, 3))
    centroids[:, 1] = np.abs(centroids[:, 1])
    centroids /= np.linalg.norm(centroids, axis=1, keepdims=True)
    r = rng.random((n, 3)) * rng.random((n, 1)) * 10.0
    with shader_page(browser) as (page, errors):
        flat = page.evaluate(DOME_PROGRAM, {"n": n, "width": width, "height": height,
                                            "r": r.ravel().tolist(),
                                            "centroids": centroids.ravel().tolist()})
        assert not errors, errors
    gpu = pixels(flat, width, height)[..., :3]
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    azimuth = 2.0 * np.pi * u[None, :]
    elevation = 0.5 * np.pi * v[:, None]
    dirs = np.stack(np.broadcast_arrays(np.sin(azimuth) * np.cos(elevation), np.sin(elevation),
                                        -np.cos(azimuth) * np.cos(elevation)), axis=-1)
    want = (sky_weights(dirs.reshape(-1, 3), centroids) @ r).reshape(height, width, 3)
    error = np.abs(gpu - want) / want.max()
    assert error.max() <= 1e-3, error.max()
    # The sky varies across the image, so a misplaced pixel or light would not pass.
    assert want.std() > 0.05 * want.max()
    print(f"\ndome sky: worst {error.max():.2e} of the sky's largest radiance")
