"""map_store.ObservationTable: the observations of a set of landmarks read once into arrays and shared by
one keyframe's mapping steps (descriptors, covisibility, window, BA's edges, keyframe culling). Every
reader must give what chaining the landmarks' ``obs`` dicts gives, in the dicts' order where order matters."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from canopy.backend import MappingParams
from canopy.backend.keyframe_culling import cull_keyframe, cull_redundant_keyframes, redundant_fraction
from canopy.backend.map_store import Landmark, LandmarkStore
from canopy.backend.observations import ObservationTable
from tests.test_keyframe_culling import _consistent, _still_run


def _random_store(rng, n_lm=60, n_kf=12):
    """Landmarks whose dicts were built with insertions, pops and re-insertions (a re-inserted key goes last)."""
    store = LandmarkStore()
    for lid in range(n_lm):
        obs = {}
        for _ in range(int(rng.integers(0, 25))):
            k = int(rng.integers(0, n_kf))
            if k in obs and rng.random() < 0.5:
                obs.pop(k)
            else:
                obs.pop(k, None)
                obs[k] = int(rng.integers(0, 500))
        store[lid] = Landmark(lid, np.zeros(3), np.zeros(32, np.uint8), obs)
    return store


def _chained(store, ids):
    kf = [k for i in ids for k in store[i].obs]
    kp = [j for i in ids for j in store[i].obs.values()]
    return np.array(kf, np.int64), np.array(kp, np.int64), np.array([len(store[i].obs) for i in ids], np.int64)


@pytest.mark.parametrize("seed", range(4))
def test_the_table_gives_the_chained_dicts_in_their_order(seed):
    rng = np.random.default_rng(seed)
    store = _random_store(rng)
    whole = ObservationTable(store, rng.permutation(len(store)))
    grown = ObservationTable(store, [3, 5])
    for part in np.array_split(rng.permutation(len(store)), 4):   # added in parts, some twice
        grown.add(np.r_[part, [3, 5]])
    for _ in range(5):
        ids = rng.integers(0, len(store), int(rng.integers(0, 40)))   # any order, repeats
        for table in (whole, grown):
            for got, want in zip(table.of(ids), _chained(store, ids.tolist())):
                np.testing.assert_array_equal(got, want)


def test_dropping_a_keyframe_matches_the_popped_dicts():
    rng = np.random.default_rng(7)
    store = _random_store(rng)
    table = ObservationTable(store, np.arange(len(store)))
    for k in (4, 0, 11, 4):
        for lm in store.values():
            lm.obs.pop(k, None)
        table.drop_keyframe(k)
        ids = rng.permutation(len(store))
        for got, want in zip(table.of(ids), _chained(store, ids.tolist())):
            np.testing.assert_array_equal(got, want)


def _median_definition(mapper, lm, m):
    """ORB-SLAM's ComputeDistinctiveDescriptors written out: unpacked bits, float medians, first minimum."""
    obs = list(lm.obs.items())[-m:] if m else list(lm.obs.items())
    bits = np.unpackbits(np.array([mapper.keyframes[k].descriptors[i] for k, i in obs]), axis=1).astype(int)
    D = (bits[:, None, :] != bits[None, :, :]).sum(2)
    return mapper.keyframes[obs[int(np.argmin(np.median(D, axis=1)))][0]].descriptors[obs[int(np.argmin(
        np.median(D, axis=1)))][1]]


@pytest.mark.parametrize("m", [0, 4])
def test_the_mappers_readers_agree_with_the_dicts(m):
    mapper, _ = _still_run(MappingParams(descriptor_max_observations=m), n_kf=8, seed=3)
    rng = np.random.default_rng(1)
    for k, rec in mapper.keyframes.items():   # distinct descriptors per observation, so the choice matters
        rec.descriptors = rng.integers(0, 256, rec.descriptors.shape).astype(np.uint8)
    lms = list(mapper.landmarks.values())
    mapper._update_descriptors(lms)
    for lm in lms:
        if len(lm.obs) >= 3:
            np.testing.assert_array_equal(lm.descriptor, _median_definition(mapper, lm, m))
    for k, rec in mapper.keyframes.items():
        want = Counter(kk for lid in rec.landmark[rec.landmark >= 0].tolist() for kk in mapper.landmarks[lid].obs)
        want.pop(k, None)
        assert mapper._covisible(rec) == dict(want)
    local, kf_set = [7, 6, 5], {7, 6, 5, 2, 0}
    lm_ids, e_kf, e_lm, e_kp = mapper._observation_edges(local, kf_set)
    ids = sorted({lid for k in local for lid in mapper.keyframes[k].landmark.tolist() if lid >= 0})
    edges = [(k, lid, i) for lid in ids for k, i in mapper.landmarks[lid].obs.items() if k in kf_set]
    assert lm_ids == ids
    assert list(zip(e_kf.tolist(), e_lm.tolist(), e_kp.tolist())) == edges


def _redundant_definition(mapper, k, min_observers):
    rec = mapper.keyframes[k]
    rows = np.flatnonzero(rec.landmark >= 0)
    good = 0
    for i in rows.tolist():
        lm = mapper.landmarks[int(rec.landmark[i])]
        others = sum(1 for kk, j in lm.obs.items() if kk != k and mapper.keyframes[kk].octave[j] <= rec.octave[i] + 1)
        good += others >= min_observers
    return good / len(rows) if len(rows) else 0.0


def test_culling_with_one_shared_table_culls_as_the_dicts_say():
    params = MappingParams(keyframe_culling_redundancy=0.9, keyframe_culling_observers=3)
    shared, fresh = (_still_run(params, n_kf=9, seed=5)[0] for _ in range(2))
    for mapper in (shared, fresh):   # some coarser observations, so that redundancy differs by keyframe
        for k in (1, 4, 6):
            mapper.keyframes[k].octave[::3] = 3
    rec = shared.keyframes[8]
    table = ObservationTable(shared.landmarks, rec.landmark[rec.landmark >= 0])
    culled = cull_redundant_keyframes(shared, rec, shared._covisible(rec, table), table)
    # the same loop on the dicts: each candidate judged on the map its predecessors left, no table kept
    want = []
    counts = fresh._covisible(fresh.keyframes[8])
    for k in sorted(counts, key=lambda kk: (-counts[kk], -kk)):
        if k in (0, 8) or k not in fresh.keyframes:
            continue
        assert redundant_fraction(fresh, k, 3) == pytest.approx(_redundant_definition(fresh, k, 3))
        if _redundant_definition(fresh, k, 3) > 0.9:
            cull_keyframe(fresh, k)
            want.append(k)
    assert culled == want and len(culled) >= 2
    assert shared.culled_keyframes.keys() == fresh.culled_keyframes.keys()
    assert all(shared.culled_keyframes[k][0] == fresh.culled_keyframes[k][0] for k in culled)
    assert {i: lm.obs for i, lm in shared.landmarks.items()} == {i: lm.obs for i, lm in fresh.landmarks.items()}
    _consistent(shared)


def _stored_vs_dicts(store: LandmarkStore, ids):
    st = store.observations
    assert st is not None
    for got, want in zip(st.of(ids), _chained(store, list(ids))):
        np.testing.assert_array_equal(got, want)


def test_the_store_follows_every_kind_of_change_of_the_dicts():
    """ObservationStore mirrors the dicts through ObsDict's hooks (one by one), the bulk paths
    (append, drop_keyframe) and the LandmarkStore's own changes (insertion, removal, reassignment)."""
    rng = np.random.default_rng(11)
    store = _random_store(rng, n_lm=80, n_kf=15)
    ids = np.arange(80)
    _stored_vs_dicts(store, ids)
    for step in range(300):
        lm = store[int(rng.integers(0, 80))]
        k = int(rng.integers(0, 15))
        op = step % 8
        if op == 0:
            lm.obs[k] = int(rng.integers(0, 500))          # new key last, or overwritten in place
        elif op == 1:
            lm.obs.pop(k, None)
        elif op == 2 and k in lm.obs:
            del lm.obs[k]
        elif op == 3:
            lm.obs.update({k: 7, (k + 1) % 15: 8})
        elif op == 4 and lm.obs:
            lm.obs.popitem()
        elif op == 5:
            lm.obs.setdefault(k, 3)
        elif op == 6:   # a loop's merge assigns a new dict
            lm.obs = {k: 1, (k + 3) % 15: 2} if step % 3 else {}
        else:
            lm.obs.clear()
        _stored_vs_dicts(store, rng.permutation(80))
    # the mapper's bulk paths: a keyframe's observations appended, a keyframe culled
    fresh = [i for i in range(80) if 20 not in store[i].obs][:30]
    for i, lid in enumerate(fresh):
        dict.__setitem__(store[lid].obs, 20, 100 + i)
    store.observations.append(np.array(fresh), 20, 100 + np.arange(len(fresh)))
    _stored_vs_dicts(store, ids)
    had = [i for i in range(80) if 3 in store[i].obs]
    for lid in had:
        dict.pop(store[lid].obs, 3)
    store.observations.drop_keyframe(3, had)
    _stored_vs_dicts(store, ids)
    # a landmark removed is no longer mirrored; one stored again under its id is read afresh
    gone = store.pop(5)
    gone.obs[14] = 1
    del store[6]
    store[5] = Landmark(5, np.zeros(3), np.zeros(32, np.uint8), {9: 9, 2: 2})
    _stored_vs_dicts(store, [i for i in range(80) if i != 6])
    # a landmark never stored changes as a plain dict
    loose = Landmark(99, np.zeros(3), np.zeros(32, np.uint8), {1: 2})
    loose.obs[3] = 4
    loose.obs.pop(1)
    loose.obs = dict(loose.obs, **{})
    loose.obs.clear()
    assert loose.obs == {}
    # pickled and copied as plain dicts
    import copy
    import pickle
    assert pickle.loads(pickle.dumps(store[5])).obs == {9: 9, 2: 2}
    assert type(copy.copy(store[5].obs)) is dict and pickle.loads(pickle.dumps(store[5].obs)) == {9: 9, 2: 2}


def _store_turned_off_by(lid_of) -> None:
    """A still run's mapper; adding landmark ``lid_of(mapper)`` turns its observation store off for
    good, and covisibility and BA's edges read from the dicts are what the store gave."""
    mapper, _ = _still_run(MappingParams(), n_kf=6, seed=2)
    rec = mapper.keyframes[5]
    before = mapper._covisible(rec)
    edges = mapper._observation_edges([5, 4], {5, 4, 0})
    assert mapper.landmarks.observations is not None
    lid = lid_of(mapper)
    mapper.landmarks[lid] = Landmark(lid, np.zeros(3), np.zeros(32, np.uint8), {0: 0})
    assert mapper.landmarks.observations is None                      # off for good
    del mapper.landmarks[lid]
    assert mapper._covisible(rec) == before
    for got, want in zip(mapper._observation_edges([5, 4], {5, 4, 0}), edges):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_sparse_ids_turn_the_store_off_and_the_readers_chain_the_dicts():
    _store_turned_off_by(lambda mapper: 10 ** 9)


def test_the_store_turns_off_past_its_memory_budget_and_the_readers_agree(monkeypatch):
    import canopy.backend.map_store as map_store

    def next_id_past_the_budget(mapper):
        st = mapper.landmarks.observations
        monkeypatch.setattr(map_store, "OBSERVATION_STORE_MAX_BYTES", st.kf.nbytes)   # the next landmark passes it
        return max(mapper.landmarks) + 1

    _store_turned_off_by(next_id_past_the_budget)
