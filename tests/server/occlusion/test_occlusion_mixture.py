"""The person colour mixture's warm refit (server/occlusion/mixture.py) against OpenCV's EM.

The refit runs EM in numpy (issue 18: ``cv2.ml.EM.trainM`` set the pipeline's p95). It must be
the same EM as OpenCV's ``trainM`` started from the same posteriors: same iteration, same
stopping rule, same parameters to rounding. OpenCV's implementation (per-sample loops, an SVD
per component) is the independent answer here.
"""

import cv2
import numpy as np
import pytest

from server.occlusion.mixture import ColourMixture, em_from_posteriors


def _clusters(rng, n_per=60):
    """(5 n_per, 3) colours in five elongated clusters (codes), like garments under light."""
    centres = np.array([[40, 50, 60], [120, 100, 90], [200, 180, 170], [30, 30, 120],
                        [90, 160, 90]], float)
    out = []
    for c in centres:
        a = rng.normal(size=(3, 3)) * 6.0
        out.append(c + rng.normal(size=(n_per, 3)) @ a)
    return np.concatenate(out)


def _opencv_train_m(x, probs, k, max_iter, eps):
    em = cv2.ml.EM_create()
    em.setClustersNumber(k)
    em.setCovarianceMatrixType(cv2.ml.EM_COV_MAT_GENERIC)
    em.setTermCriteria((cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, max_iter, eps))
    assert em.trainM(x, probs)[0]
    return (np.asarray(em.getMeans()).reshape(k, 3), np.asarray(em.getCovs()).reshape(k, 3, 3),
            np.asarray(em.getWeights()).reshape(k))


@pytest.mark.parametrize("max_iter, eps, seed", [(1, 1e-3, 0), (5, 1e-3, 1), (5, 0.0, 2),
                                                 (30, 1e-6, 3), (5, 1e-3, 4)])
def test_numpy_em_is_opencvs_train_m(max_iter, eps, seed):
    rng = np.random.default_rng(seed)
    x = _clusters(rng)
    # Posteriors as a warm start gives them: soft, from a mixture that is near but not at
    # the answer (random responsibilities sharpened toward the true cluster).
    k = 5
    truth = np.repeat(np.arange(k), len(x) // k)
    probs = rng.uniform(0.0, 1.0, (len(x), k))
    probs[np.arange(len(x)), truth] += 2.0
    probs /= probs.sum(1, keepdims=True)
    ours = em_from_posteriors(x, probs.copy(), max_iter, eps)
    theirs = _opencv_train_m(x, probs.copy(), k, max_iter, eps)
    for a, b, name in zip(ours, theirs, ("means", "covs", "weights"), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7, err_msg=name)


def test_an_empty_component_copies_the_lightest_as_opencv_does():
    rng = np.random.default_rng(7)
    x = _clusters(rng)
    probs = np.zeros((len(x), 5))
    probs[:, :4] = rng.uniform(0.1, 1.0, (len(x), 4))
    probs /= probs.sum(1, keepdims=True)  # component 4 has no weight at all
    ours = em_from_posteriors(x, probs.copy(), 1, 1e-3)
    theirs = _opencv_train_m(x, probs.copy(), 5, 1, 1e-3)
    for a, b in zip(ours, theirs, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7)


def test_the_warm_refit_follows_colours_that_drift():
    """Refit on colours shifted by 6 codes: the means follow (the model is not frozen)."""
    rng = np.random.default_rng(3)
    x = _clusters(rng)
    mix = ColourMixture(5, max_iter=5)
    assert mix.fit(x, warm=False)
    before = np.sort(mix.means[:, 0])
    assert mix.fit(x + 6.0, warm=True)
    np.testing.assert_allclose(np.sort(mix.means[:, 0]) - before, 6.0, atol=1.0)


def test_singular_covariances_are_refused():
    """The caller then keeps its model (ColourMixture.fit returns False)."""
    rng = np.random.default_rng(5)
    flat = np.zeros((300, 3))
    flat[:, 0] = rng.uniform(0, 255, 300)  # a line in colour space: singular covariances
    probs = np.full((300, 5), 0.2)
    assert em_from_posteriors(flat, probs, 5, 1e-3) is None
