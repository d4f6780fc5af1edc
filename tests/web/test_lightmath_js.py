"""web/src/lightmath.js (run by Node) against the Python reference: the light selection
A(r) with its tie rule and the selectable lights, c = V^T r', the spherical-harmonic shading
of hull-plane mode, the open-sky irradiance, the client's smoothing, and the patch that holds
the sun (whose sun-bounce images the client fetches; against daylit.spherical.PatchLookup)."""

import json
import math
import subprocess
from pathlib import Path

import numpy as np

from daylit.selection import Selection
from tests.web.harness import node_path

ROOT = Path(__file__).resolve().parents[2]


def test_lightmath_matches_python(reference):
    manifest = reference.manifest
    lights = manifest["dome"]["lights"]
    n = len(lights)
    solid = [light["solid_angle_sr"] for light in lights]
    selectable = reference.selection.selectable.tolist()
    rng = np.random.default_rng(11)
    cases_select = [
        {"r": reference.light_vector("clear:135,40").tolist(), "solid": solid, "m": 4},
        {"r": np.ones((n, 3)).tolist(), "solid": [1.0] * n, "m": 4},  # all tied: lowest
        {"r": np.where(rng.random((n, 1)) < 0.9, 0.0, rng.random((n, 3))).tolist(),
         "solid": solid, "m": 4},  # mostly zero: zero-score lights never chosen
        # The build's selectable lights, under a sky whose brightest patches cannot be selected.
        {"r": np.where(np.isin(np.arange(n), selectable)[:, None], 1.0, 50.0).repeat(3, 1)
         .tolist(), "solid": solid, "m": 4, "selectable": selectable},
    ]
    V = rng.normal(size=(n, 5)).astype(np.float32)
    r = rng.random((n, 3))
    up = [0.0, 1.0, 0.0]
    cases = {
        "select": cases_select,
        "coefficients": [{"V": V.tolist(), "k": 5, "r": r.tolist(), "selected": [1, 7]}],
        "sh9": [{"r": np.ones((n, 3)).tolist(), "sh9": [light["sh9"] for light in lights],
                 "normal": up}],
        "open": [{"r": np.ones((n, 3)).tolist(),
                  "cosw": [light["cosine_weighted_sr"] for light in lights]}],
        "patch": [],
    }
    # Suns all over the upper hemisphere, some on the patches' edges (a vertex direction).
    suns = [rng.normal(size=3) for _ in range(40)] + [np.array(lights[3]["vertices"][0])]
    suns = [d / np.linalg.norm(d) * [1, np.sign(d[1]) or 1, 1] for d in suns]
    for d in suns:
        cases["patch"].append({"lights": lights, "direction": d.tolist()})
    result = subprocess.run([node_path(), str(ROOT / "tests" / "web" / "lightmath_cases.mjs")],
                            input=json.dumps(cases), capture_output=True, text=True,
                            timeout=60, check=True)
    got = json.loads(result.stdout)
    for case, chosen in zip(cases_select, got["select"], strict=True):
        selection = Selection.of(np.array(case["solid"]), case["m"], case.get("selectable"))
        assert chosen == selection(np.array(case["r"])).tolist()
    assert set(got["select"][3]) <= set(selectable) and len(got["select"][3]) == 4
    assert got["select"][1] == [0, 1, 2, 3]
    rest = r.copy()
    rest[[1, 7]] = 0.0
    assert np.allclose(np.array(got["coefficients"][0]).reshape(5, 3), V.T.astype(float) @ rest,
                       rtol=1e-6, atol=1e-9)
    from daylit.spherical import PatchLookup

    patches = PatchLookup(np.array([light["vertices"] for light in lights]))(np.array(suns))
    assert got["patch"] == patches.tolist()
    # A uniform sky of unit radiance: pi on an upward surface, from the SH9 (exact for l <= 2
    # over a hemisphere) and from the cosine-weighted solid angles.
    assert np.allclose(got["sh9"][0], math.pi, rtol=5e-3)
    assert np.allclose(got["open"][0], math.pi, rtol=1e-6)
    assert np.allclose(got["smoothing"][0], 1.0 - math.exp(-1.0))


def test_lightmath_sh9_against_the_integral():
    """skySH9 and irradianceSH9 (lightmath.js) on the skies and normals of the shader's test
    (tests/web/sh9oracle.py): the 'lights' are the sphere's quadrature points (radiance r_i,
    sh9_i = Y(w_i) dw_i with the paper's constants), the answer the cosine-weighted integral
    over each normal's hemisphere. Fails, never skips, without Node."""
    from tests.web import sh9oracle

    rng = np.random.default_rng(21)
    skies = sh9oracle.skies_that_differ(rng)
    normals = sh9oracle.normals_that_differ()
    dirs, weight = sh9oracle.sphere_quadrature()
    sh9 = (sh9oracle.harmonics(dirs) * weight[:, None]).tolist()
    names = list(skies)
    groups = [names[i:i + 3] for i in range(0, len(names), 3)]
    cases = {"sh9Known": [{"r": np.stack([skies[name](dirs) for name in group], axis=1).tolist(),
                           "sh9": sh9, "normals": normals.tolist()} for group in groups]}
    result = subprocess.run(["node", str(ROOT / "tests" / "web" / "lightmath_cases.mjs")],
                            input=json.dumps(cases), capture_output=True, text=True,
                            timeout=60, check=True)
    got = json.loads(result.stdout)["sh9Known"]
    for group, e in zip(groups, got, strict=True):
        e = np.array(e)  # (normals, 3)
        for ch, name in enumerate(group):
            want = sh9oracle.irradiance(skies[name], normals)
            assert np.abs(e[:, ch] - want).max() <= 1e-4 * want.max(), (name, e[:, ch], want)
