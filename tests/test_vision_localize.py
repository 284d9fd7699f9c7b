"""The localizer's guard for real tracks: a landmark that the refinement leaves on a camera
centre (a wrong association can) is dropped with its factors, counted, and the marginals of
the rest still factor."""

import numpy as np
import pytest

from factorgraph import localize, simulate_traverse
from factorgraph.localize import LocalizeParams, _drop_landmarks_at_cameras, _Tracks
from factorgraph.marginals import landmark_marginals
from terrain.synthetic import DEFAULT_SITE_BOUNDS, default_site


@pytest.fixture(scope="module")
def result():
    W, _, _, N = DEFAULT_SITE_BOUNDS
    log = simulate_traverse(default_site(2.0), np.array([[W + 20, N - 75], [W + 80, N - 75]]))
    return localize(log, LocalizeParams(refine=False))


def test_landmark_on_a_camera_is_dropped_and_marginals_factor(result):
    import gtsam

    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    graph, estimate = result.graph, gtsam.Values(result.estimate)
    bTc = gtsam.Pose3(result.log.sensors.camera.body_T_camera())
    lid = int(result.landmark_id[len(result.landmark_id) // 2])
    # the keyframe that sees it first: put the point 1 mm in front of that camera
    k = int(result.log.obs_k[np.flatnonzero(result.log.obs_id == lid)[0]])
    wTc = estimate.atPose3(X(k)).compose(bTc)
    estimate.update(L(lid), wTc.transformFrom(np.array([0.0, 0.0, 1e-3])))
    K = result.log.n_keyframes
    with pytest.raises(np.linalg.LinAlgError):  # the failure the guard removes
        landmark_marginals(graph, estimate, K, result.landmark_id.tolist(), True, True)
    tracks = _Tracks(active=set(result.landmark_id.tolist()))
    kept = _drop_landmarks_at_cameras(graph, estimate, tracks, bTc, 0.5)
    assert tracks.dropped == {"depth_after_refine": 1} and lid not in tracks.active
    assert not estimate.exists(L(lid))
    n_lid = sum(1 for i in range(graph.size()) if L(lid) in graph.at(i).keys())
    assert kept.size() == graph.size() - n_lid > 0
    marg = landmark_marginals(kept, estimate, K, sorted(tracks.active), True, True)
    assert marg.landmark_cov.shape == (len(tracks.active), 3, 3)
    assert (np.linalg.eigvalsh(marg.landmark_cov) > 0).all()
    # nothing to drop: the graph comes back as it was
    again = _Tracks(active=set(tracks.active))
    assert _drop_landmarks_at_cameras(kept, estimate, again, bTc, 0.5) is kept
    assert not again.dropped
