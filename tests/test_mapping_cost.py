"""Local mapping's cheaper steps give the results of their plain definitions (issue 8, s17-mapcost)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend.local_mapper import distinctive_index


def _reference_distinctive(desc: np.ndarray) -> np.ndarray:
    """ORB-SLAM's ComputeDistinctiveDescriptors as written there: per landmark, the observation whose
    median Hamming distance to the others is least (the first on ties)."""
    bits = np.unpackbits(desc, axis=-1).astype(np.int64)                     # (G,n,256)
    D = np.abs(bits[:, :, None, :] - bits[:, None, :, :]).sum(-1)           # (G,n,n)
    return np.array([int(np.argmin([np.median(row) for row in d])) for d in D])


@pytest.mark.parametrize("n", [3, 4, 5, 8, 13, 20, 21])
def test_distinctive_index_is_the_least_median_distance_observation(n):
    rng = np.random.default_rng(n)
    # observations of one landmark: a base descriptor with a few flipped bytes (so medians tie often)
    base = rng.integers(0, 256, (64, 1, 32), dtype=np.uint8)
    flips = ((rng.random((64, n, 32)) < 0.04) * rng.integers(1, 256, (64, n, 32))).astype(np.uint8)
    desc = base ^ flips
    ref = _reference_distinctive(desc)
    assert np.array_equal(distinctive_index(desc), ref)
    # and on unrelated descriptors (large distances, an uint16 sum of up to 256 per pair)
    far = rng.integers(0, 256, (16, n, 32), dtype=np.uint8)
    assert np.array_equal(distinctive_index(far), _reference_distinctive(far))


def _still_keyframes(n_kf=10, seed=0):
    """Keyframes of a camera hanging still over a generated scene: each sees every landmark, so
    keyframe culling finds the older ones redundant (as on EuRoC's hover)."""
    from canopy.frontend.geometry import se3_exp
    from tests.test_backend import keyframe, scene

    rng = np.random.default_rng(seed)
    moving, X = scene(rng)
    n = len(X)
    ids = np.arange(n, dtype=np.int64)
    out = []
    for k in range(n_kf):
        T = moving[0] @ se3_exp(np.r_[1e-5 * rng.standard_normal(3), 3e-4 * rng.standard_normal(3)])
        existing, new = (np.full(n, -1, np.int64), ids) if k == 0 else (ids, np.full(n, -1, np.int64))
        out.append(keyframe(k, T, T, X, existing, new, rng))
    return out


def test_keyframes_of_a_closed_loop_are_never_culled():
    """ORB-SLAM's SetNotErase: the loop's two keyframes stay in the map, through the actor's handling of
    the loop closer's answer; the other redundant keyframes are culled as before."""
    from actors.local_mapping import LocalMappingActor
    from canopy.backend import MappingParams
    from protocol.messages import LoopResult
    from tests.test_backend import CALIB
    from tests.test_map_snapshot_save import _Transport

    keyframes = _still_keyframes()
    params = MappingParams(keyframe_culling=True, keyframe_culling_keep_recent=2)   # 2 and 3 alive at the loop

    def run(loop_at: int | None):
        actor = LocalMappingActor({"calib": CALIB, "params": params, "snapshot_period_s": 1e9})
        ctx = _Transport()
        actor.setup(ctx)
        for kf in keyframes:
            actor.on_message(kf, ctx)
            if kf.index == loop_at:   # a loop from keyframe 3 back to 2 (no correction: identity)
                assert 2 in actor.mapper.keyframes and 3 in actor.mapper.keyframes
                actor._on_loop_result(LoopResult(keyframe_index=3, closed=True, candidate=2, keyframe_ids=np.array([0]),
                                                 corrections=np.eye(4)[None]), actor.last_update)
        return actor.mapper

    plain, looped = run(None), run(3)
    assert {2, 3} <= set(plain.culled_keyframes)            # redundant on a still camera: culled without the loop
    assert {2, 3} <= set(looped.keyframes) and not ({2, 3} & set(looped.culled_keyframes))
    assert looped.loop_keyframes == {2, 3}
    assert looped.n_keyframes_culled >= 4                   # the others still go
    for lid, lm in looped.landmarks.items():                # and the map stays consistent
        for k, i in lm.obs.items():
            assert looped.keyframes[k].landmark[i] == lid
