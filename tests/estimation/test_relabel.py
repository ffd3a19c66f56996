"""Labels as the paper defines them (eq. 5d): the fitter's samples follow the re-clustering."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from pcvfe_drake.contexts.clustering import ClusteringParams, ContextClusterer
from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import ProbeState
from pcvfe_drake.estimation.sample_store import SampleStore, labels_from_frames, visit_members
from pcvfe_drake.handing.config import HandingConfig, Prior, Probe
from pcvfe_drake.handing.context_state import ContextHanding
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.params import ford_escort

STATE = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def params():
    return ford_escort()


def _store(labels, chunk_size=4):
    store = SampleStore(chunk_size=chunk_size)
    for i, label in enumerate(labels):
        store.append(0.01 * i, STATE + i, [0.0, float(i)], label)
    return store


def test_store_keeps_time_order_and_labels_and_shares_full_chunks_between_copies():
    store = _store([2, 2, -1, -1, 5, 5, 5, 2, 2, -1])
    assert len(store) == 10
    np.testing.assert_array_equal(store.labels(), [2, 2, -1, -1, 5, 5, 5, 2, 2, -1])
    t, states, inputs = store.rows(np.flatnonzero(store.labels() == 2))
    np.testing.assert_allclose(t, [0.0, 0.01, 0.07, 0.08])
    # each row holds the input read at the next sample: the one applied from the row on
    np.testing.assert_allclose(inputs[:, 1], [1, 2, 8, 9])
    np.testing.assert_allclose(states[:, 3], 5.0 + np.array([0, 1, 7, 8]))

    # A copy (what Drake does at every update) shares the full chunks, copies the tail.
    other = copy.deepcopy(store)
    assert all(a is b for a, b in zip(other._chunks, store._chunks, strict=True))
    assert other._tail is not store._tail and other._tail_labels is not store._tail_labels
    # Relabelling one never writes into the other's arrays.
    new = store.labels()
    new[[2, 3, 9]] = 5
    assert other.set_labels(new) == 3
    np.testing.assert_array_equal(other.labels(), new)
    np.testing.assert_array_equal(store.labels(), [2, 2, -1, -1, 5, 5, 5, 2, 2, -1])
    # The chunk whose labels did not change keeps its (shared) array.
    assert other._labels[1] is store._labels[1] and other._labels[0] is not store._labels[0]
    with pytest.raises(ValueError, match="expected 10 labels"):
        other.set_labels(new[:-1])


def test_store_retains_the_newest_rows_of_each_label():
    labels = [2] * 7 + [-1] * 5 + [5] * 2 + [2] * 3
    store = _store(labels, chunk_size=3)
    assert store.retain(4) == 7 + 3 - 4 + 1  # label 2: 10 rows -> 4; noise: 5 -> 4
    kept = store.labels()
    assert {k: int((kept == k).sum()) for k in (2, -1, 5)} == {2: 4, -1: 4, 5: 2}
    t = store.times()
    assert np.all(np.diff(t) > 0)  # time order kept
    # label 2's newest: the samples at 0.06 s and the last three
    np.testing.assert_allclose(t[kept == 2], [0.06, 0.14, 0.15, 0.16])
    assert store.retain(4) == 0


def test_each_sample_takes_the_label_of_the_frame_covering_its_time():
    t = np.round(np.arange(0.0, 1.0, 0.01), 6)
    old = np.full(t.size, -1)
    old[:30] = 2
    # Frames every 0.1 s: 0.0-0.2 context 2, 0.3-0.6 the new context 7, 0.7 noise; the frame at
    # 0.8 is not stored (a sparse reservoir) and 0.9 is context 7 again.
    ft = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.9])
    fl = np.array([2, 2, 2, 7, 7, 7, 7, -1, 7])
    new = labels_from_frames(t, old, ft, fl, 0.1)
    # A sample at a frame's instant still reads the previous frame (zero-order hold): 0.3 -> 2.
    assert new[30] == 2 and new[31] == 7
    assert np.all(new[31:71] == 7) and np.all(new[71:81] == -1)
    # 0.81 .. 0.9 s: the frame at 0.8 is gone; the one at 0.7 is too old to cover them: they
    # keep their label (noise here).
    assert np.all(new[81:91] == -1) and np.all(new[91:] == 7)
    # Frames in any order give the same labels.
    rng = np.random.default_rng(0)
    order = rng.permutation(ft.size)
    np.testing.assert_array_equal(labels_from_frames(t, old, ft[order], fl[order], 0.1), new)


def test_uncovered_samples_follow_a_merge_of_their_context():
    t = np.round(np.arange(0.0, 2.0, 0.01), 6)
    old = np.where(t < 1.0, 4, 6)
    # A reservoir kept only a few frames of each; the re-clustering merged 6 into 4.
    ft = np.array([0.2, 0.5, 1.2, 1.5, 1.8])
    fl = np.array([4, 4, 4, 4, 4])
    new = labels_from_frames(t, old, ft, fl, 0.1)
    assert np.all(new == 4)
    # Noise by the re-clustering (a vanished context) does not spread to uncovered samples.
    new = labels_from_frames(t, old, ft, np.array([4, 4, -1, -1, -1]), 0.1)
    assert np.all(new[t < 1.0] == 4)
    covered = np.zeros(t.size, dtype=bool)
    for f in (1.2, 1.5, 1.8):
        covered |= (t > f + 1e-9) & (t <= f + 0.1 + 1e-9)
    assert np.all(new[covered] == -1) and np.all(new[(t >= 1.0) & ~covered] == 6)


def _drive(params):
    """3 s on mu 0.45 reported as context 2, then 4 s on mu 0.8 reported as noise (a new
    terrain before its first re-clustering), then 1 s on mu 0.8 reported as context 5."""
    t, S, U = s_curve_drive(params, [0.45, 0.8], duration_s=5.0, phase_rad=[0.0, 1.5])
    n1, n2 = 300, 500
    times = np.concatenate([t[:n1], 3.0 + t[:n2]])
    states = np.concatenate([S[0][:n1], S[1][:n2]])
    inputs = np.concatenate([U[0][:n1], U[1][:n2]])
    ids = np.concatenate([np.full(n1, 2), np.full(400, -1), np.full(100, 5)])
    return np.round(times, 6), states, inputs, ids


def test_noise_samples_of_a_new_terrain_count_after_the_recluster(params):
    times, states, inputs, ids = _drive(params)
    cfg = LiveFitConfig(handing=HandingConfig(unknown=Prior()))
    est = ContextEstimator(params, cfg)
    for k in range(times.size):
        est.add_sample(times[k], states[k], inputs[k], [ids[k]])
    est.refit(8.0)
    without = est.table().get(5)
    assert without.samples == 100  # the 4 s of noise do not count

    frames_t = np.round(np.arange(0.0, 8.0, 0.1), 6)
    frames_l = np.where(frames_t < 3.0 - 1e-9, 2, 5)  # the re-clustering found terrain 5
    before = copy.deepcopy(est)
    # (The first noise sample, at 3.0 s, reads the frame taken at 2.9 s: terrain 2.)
    assert est.relabel(frames_t, frames_l, 0.1, version=1) == {-1: -400, 2: 1, 5: 399}
    assert est.relabel(frames_t, frames_l, 0.1, version=1) == {}  # this version is done
    assert est.labels_version == 1 and est.relabelled_samples == 400
    assert est.pending() == [2, 5]
    assert before.table().get(5).samples == 100  # the copy is untouched
    entry = est.table().get(5)
    assert entry.samples == 499 and est.table().relabelled_samples == 400
    est.refit(8.5)
    fitted = est.table().get(5)
    assert fitted.fitted and abs(fitted.mu - 0.8) < 0.01
    assert fitted.n_windows > 4 * max(without.n_windows, 1)
    assert est.table().get(2).samples == 301


def test_a_context_that_grows_by_relabelling_is_refitted_and_one_that_shrinks_too(params):
    times, states, inputs, ids = _drive(params)
    ids = np.where(ids == 5, 2, ids)  # the new terrain's frames first joined context 2 online
    ids[300:700] = 2
    est = ContextEstimator(params, LiveFitConfig(max_contexts_per_update=1))
    for k in range(times.size):
        est.add_sample(times[k], states[k], inputs[k], [ids[k]])
    est.refit(8.0)
    mixed = est.table().get(2)
    assert mixed.fitted and est.pending() == []
    # The re-clustering separates the two terrains: 500 samples move from 2 to 5.
    frames_t = np.round(np.arange(0.0, 8.0, 0.1), 6)
    frames_l = np.where(frames_t < 3.0 - 1e-9, 2, 5)
    assert est.relabel(frames_t, frames_l, 0.1, version=3) == {2: -500, 5: 500}
    assert est.pending() == [5, 2]  # round-robin after context 2's fit
    assert est.refit(9.0) == [5] and est.refit(10.0) == [2]  # bounded: one per call
    e2, e5 = est.table().get(2), est.table().get(5)
    assert abs(e2.mu - 0.45) < 0.01 and abs(e5.mu - 0.8) < 0.01
    assert e2.samples == 300 and e5.samples == 500
    assert e5.first_fit_s == 9.0 and e2.first_fit_s == 8.0 and e2.fits == 2


def test_a_renamed_context_passes_its_fit_and_its_exploration_to_the_new_id(params):
    # one terrain (mu 0.8) fitted as context 5 and explored up to 0.55; a re-clustering then
    # names the same frames 7 (the paper's centroid matching gave the grown cluster a fresh id)
    t, S, U = s_curve_drive(params, [0.8], duration_s=8.0)
    cfg = LiveFitConfig(handing=HandingConfig(unknown=Prior(), unidentified=Probe()))
    est = ContextEstimator(params, cfg)
    for k in range(t.size):
        est.add_sample(float(t[k]), S[0][k], U[0][k], [5])
    est.refit(8.0)
    fit5 = est.table().get(5)
    assert fit5.fitted
    est.handing.contexts[5] = ContextHanding(probe=ProbeState(mu=0.55, last_step_s=7.0, steps=3))
    before = est.theta_for(5)
    frames_t = np.round(np.arange(0.0, 8.0, 0.1), 6)
    assert est.relabel(frames_t, np.full(frames_t.size, 7), 0.1, version=1) == {5: -801, 7: 801}
    fit7 = est.table().get(7)
    assert fit7.fitted and fit7.mu == fit5.mu and fit7.first_fit_s == fit5.first_fit_s
    assert fit7.samples == 801 and est.table().get(5).samples == 0
    assert est.handing.probe_of(7) == est.handing.probe_of(5)
    np.testing.assert_array_equal(est.theta_for(7), before)  # not the unknown value again
    assert 7 in est.pending()  # refitted on its data, from the fit it took over
    # the samples context 5's fit used were used: under the new id they do not wait again
    waited = est.table().get(7).sample_to_estimate_s
    assert waited == fit5.sample_to_estimate_s and waited[2] > 0
    for k in range(50):  # half a second more on the same ground, then the refit publishes it
        est.add_sample(8.0 + 0.01 * (k + 1), S[0][-1], U[0][-1], [7])
    est.refit(9.0)
    p50, p99, counted = est.table().get(7).sample_to_estimate_s
    assert 0 < counted - waited[2] <= 50  # the new samples join the waits counted before
    assert p50 <= waited[0] and p99 <= waited[1]  # (counted again, the old ones waited longer)
    # a split is no renaming: a context that keeps samples keeps its own state, and an id
    # that has a fit of its own keeps it
    frames_l = np.where(frames_t < 4.0 - 1e-9, 7, 9)
    est.relabel(frames_t, frames_l, 0.1, version=2)
    assert not est.table().get(9).fitted and est.handing.probe_of(9) == ProbeState()


def test_memory_stays_bounded_and_the_current_id_still_drives_the_controller(params):
    cfg = LiveFitConfig(buffer_s=1.0, handing=HandingConfig(unknown=Prior()))  # 100 per label
    est = ContextEstimator(params, cfg)
    for k in range(5000):
        est.add_sample(0.01 * k, STATE, [0.0, 0.0], [(k // 700) % 3 - 1])
        assert len(est._store) <= (len(est._slots) + 2) * 100
    labels = est._store.labels()
    assert all((labels == k).sum() <= 200 for k in (-1, 0, 1))
    assert est.current_context == 0  # k = 4999: (4999 // 700) % 3 - 1


def test_relabel_with_a_real_clusterer_gives_the_new_terrain_its_noise_frames(params):
    """Two synthetic terrains through ContextClusterer at 10 Hz; the fitter at 100 Hz."""
    rng = np.random.default_rng(1)
    clusterer = ContextClusterer(ClusteringParams(min_cluster_duration_s=2.0))
    est = ContextEstimator(params, LiveFitConfig())
    centres = (np.zeros(8), np.full(8, 3.0))
    for k in range(2000):  # 20 s: terrain A for 12 s, then terrain B
        t = round(0.01 * k, 6)
        if k % 10 == 0:
            z = centres[0 if t < 12.0 else 1] + 0.1 * rng.standard_normal(8)
            current = clusterer.assign(z, t)
            if k % 1000 == 0 and k:
                clusterer.recluster(t)
        est.add_sample(t, STATE, [0.0, 0.0], [current])
    noise_b = est.table().noise_samples
    assert noise_b >= 790  # 12 s .. 20 s on B before any re-clustering saw it (and 0..10 s on A)
    clusterer.recluster(20.0)
    frames = clusterer.frame_labels()
    assert np.all(np.diff(frames.t_s) > 0) and frames.version == 2
    assert frames.frame_period_s == pytest.approx(0.1)
    gained = est.relabel(frames.t_s, frames.labels, frames.frame_period_s, frames.version)
    new_id = clusterer.table().active_ids[-1]
    assert gained[new_id] >= 790  # B's samples since 12.0 s (the first one reads A's frame)
    table = est.table()
    assert table.get(new_id).samples == gained[new_id]
    a_id = clusterer.table().active_ids[0]
    assert table.get(a_id).samples >= 1190  # A's noise samples before 10 s joined it too


def test_visit_members_take_the_noise_spells_that_return_to_the_context_within_the_hold():
    labels = np.array([-1, 0, 0, -1, -1, 0, 1, -1, 0, -1, -1, -1, 0, -1])
    times = 0.1 * np.arange(labels.size)
    # the spell at 0.3-0.4 s is back at 0.5 s (0.2 s away), the one at 0.9-1.1 s at 1.2 s
    # (0.3 s); 0.7 s lies between contexts 1 and 0; the first and the last sample have no side
    np.testing.assert_array_equal(
        visit_members(labels, times, 0, 0.3), [0, 1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1, 0]
    )
    np.testing.assert_array_equal(
        visit_members(labels, times, 0, 0.2), [0, 1, 1, 1, 1, 1, 0, 0, 1, 0, 0, 0, 1, 0]
    )
    np.testing.assert_array_equal(visit_members(labels, times, 0, 0.0), labels == 0)
    np.testing.assert_array_equal(visit_members(labels, times, 1, 1.0), labels == 1)
    np.testing.assert_array_equal(visit_members(labels, times, 7, 1.0), labels == 7)


def _fit_labelled_drive(params, t, states, inputs, ids, hold_s: float):
    """The estimate table after a drive's samples, each with its context id, and one refit at
    its end; the visit rule's hold ``hold_s`` [s], windows of 0.5 s every 0.25 s."""
    cfg = LiveFitConfig(handing=HandingConfig(unknown=Prior(), noise_hold_s=hold_s))
    cfg = dataclasses.replace(cfg, horizon_steps=50, stride_steps=25, min_windows=10)
    est = ContextEstimator(params, cfg)
    for k in range(t.size):
        est.add_sample(round(float(t[k]), 6), states[k], inputs[k], [ids[k]])
    est.refit(float(t[-1]))
    return est.table()


@pytest.mark.parametrize("hold_s, fitted", [(1.0, True), (0.0, False)])
def test_a_context_chopped_by_short_noise_spells_is_fitted_on_its_visit(params, hold_s, fitted):
    """8 s on mu 0.8 with a noise frame (0.1 s) every 0.3 s, as an online clustering unsure of
    a terrain it knows reports it: with the visit rule the fit has its windows at once; with
    the spells left out no window fits between two of them."""
    t, S, U = s_curve_drive(params, [0.8], duration_s=8.0)
    ids = np.where((np.arange(t.size) % 30) >= 20, -1, 4)
    ids[-1] = 4
    entry = _fit_labelled_drive(params, t, S[0], U[0], ids, hold_s).get(4)
    assert entry.fitted is fitted
    if fitted:
        assert abs(entry.mu - 0.8) < 0.02 and entry.n_windows >= 20


@pytest.mark.parametrize(
    "mu, strip_mu, strip_s", [(0.3, 0.8, 0.3), (0.3, 0.8, 0.9), (0.8, 0.25, 0.9)]
)
def test_a_strip_of_another_terrain_held_into_a_visit_widens_the_fit_instead_of_misleading_it(
    params, mu, strip_mu, strip_s
):
    """The visit rule's risk: a strip of another friction shorter than the hold, which the
    camera calls noise, enters the context's fit as part of its visit. Its samples pull the
    estimate (up where the strip grips more: the unsafe side), but the windows that span it
    fit worse, and the interval widens with them: the 95 % interval still holds the context's
    friction. Without the hold the strip is left out and the fit is as tight as the data."""
    duration_s = 12.0
    t = np.arange(round(duration_s / 0.01) + 1) * 0.01
    strip = (t >= 4.8) & (t < 4.8 + strip_s)  # in the second bend
    t, S, U = s_curve_drive(params, np.where(strip, strip_mu, mu)[None, :], duration_s=duration_s)
    ids = np.where(strip, -1, 4)
    held, left_out = (
        _fit_labelled_drive(params, t, S[0], U[0], ids, hold_s).get(4) for hold_s in (1.0, 0.0)
    )
    assert held.n_windows > left_out.n_windows  # the strip's windows are in the held fit
    assert abs(held.mu - mu) > 0.005  # and they pull it ...
    assert abs(held.mu - mu) <= 1.96 * held.theta_std[0]  # ... within its widened interval
    assert held.theta_std[0] > 3.0 * left_out.theta_std[0]
    assert abs(left_out.mu - mu) <= max(1.96 * left_out.theta_std[0], 0.01)
