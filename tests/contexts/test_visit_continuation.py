"""A rejected frame continuing the visit of the context before it
(ClusteringParams.continuation_gate_scale), and the one-terrain re-clustering when
min_samples is larger than min_cluster_size."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams, ContextClusterer
from pcvfe_drake.estimation.estimate_table import ContextEstimate
from pcvfe_drake.handing.config import HandingConfig, Probe, StatedFloor
from pcvfe_drake.handing.handing import Handing
from pcvfe_drake.vehicle.params import ford_escort

A = np.array([1.0, 0.0, 0.0])
B = np.array([0.0, 1.0, 0.0])
FAR = np.array([0.0, 0.0, 1.0])
VP = ford_escort()


def fit(ident: int, mu: float) -> ContextEstimate:
    """An identified context fitted at ``mu``."""
    return ContextEstimate(
        ident, (mu, VP.C_Sf, VP.C_Sr), (0.01, math.nan, math.nan), fits=1, identifiable=True
    )


def handing(**cfg) -> Handing:
    return Handing(HandingConfig(**cfg), tuple(VP.theta), VP)


def drive(h: Handing, fits: dict, t: float, ids: list[int]) -> tuple[list[float], float]:
    """Feed frames ``ids`` (one per 0.1 s); the mu handed after each."""
    mus = []
    for ident in ids:
        t += 0.1
        h.observe(t, ident, ident in fits)
        mus.append(float(h.theta(fits)[0]))
    return mus, t


def two_terrains(scale: float | None) -> tuple[ContextClusterer, int, int]:
    """10 s on terrain A, 10 s on B (10 Hz, spread 0.01), re-clustered; ids of A and B."""
    clusterer, a, b = two_terrains_into(
        ContextClusterer(ClusteringParams(frame_rate_hz=10.0, continuation_gate_scale=scale))
    )
    assert a >= 0 and b >= 0 and a != b
    return clusterer, a, b


def shifted(clusterer: ContextClusterer, centre: np.ndarray, away: np.ndarray) -> np.ndarray:
    """The first point from ``centre`` toward ``away`` that the outlier gate rejects."""
    for m in np.linspace(0.0, 0.5, 501):
        z = centre + m * (away - centre) / np.linalg.norm(away - centre)
        if clusterer.predict(z)[0] == NOISE:
            return z
    raise AssertionError("no rejected point found")


def test_params_validate_the_scale():
    assert ClusteringParams().continuation_gate_scale is None  # off: the paper's design
    ClusteringParams(continuation_gate_scale=1.0)
    for bad in (0.5, 0.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="continuation_gate_scale"):
            ClusteringParams(continuation_gate_scale=bad)


def test_a_frame_just_outside_the_gate_continues_the_visit():
    clusterer, a, _ = two_terrains(3.0)
    z = shifted(clusterer, A, FAR)
    assert clusterer.assign(A, 20.0) == a
    n_a = clusterer.table().records[a].size
    stored_noise = int(np.sum(clusterer.stored().labels == NOISE))
    for k in range(5):  # a run of such frames keeps the id: the reference is the stored members
        assert clusterer.assign(z, 20.1 + 0.1 * k) == a
    assert clusterer.continued_frames == 5
    # stored as noise, the context unchanged: re-clustering decides as always
    assert clusterer.table().records[a].size == n_a
    assert int(np.sum(clusterer.stored().labels == NOISE)) == stored_noise + 5
    # a frame far from every context ends the visit, and the near frame after it is noise
    assert clusterer.assign(FAR, 21.0) == NOISE
    assert clusterer.assign(z, 21.1) == NOISE


def test_off_and_after_noise_the_frame_stays_noise():
    off, a, _ = two_terrains(None)
    z = shifted(off, A, FAR)
    assert off.assign(A, 20.0) == a
    assert off.assign(z, 20.1) == NOISE
    assert off.continued_frames == 0
    on, a, _ = two_terrains(3.0)
    assert on.assign(FAR, 20.0) == NOISE  # no visit to continue
    assert on.assign(shifted(on, A, FAR), 20.1) == NOISE


def test_a_frame_far_beyond_the_widened_gate_or_nearer_another_context_is_noise():
    clusterer, a, b = two_terrains(1.5)
    assert clusterer.assign(A, 20.0) == a
    assert clusterer.assign(A + 0.3 * (FAR - A), 20.1) == NOISE  # far beyond 1.5 gates
    # nearest to B's members (though B's gate rejects it): not A's visit
    assert clusterer.assign(A, 20.2) == a
    z = shifted(clusterer, B, A)
    assert np.linalg.norm(z - B) < np.linalg.norm(z - A)
    assert clusterer.assign(z, 20.3) == NOISE
    assert clusterer.assign(B, 20.4) == b


def test_one_terrain_with_min_samples_above_min_cluster_size():
    # 34 frames >= min_cluster_size (30) but fewer than min_samples (50) + 1: no cluster yet,
    # no error (HDBSCAN refuses min_samples above the number of points)
    params = ClusteringParams(frame_rate_hz=10.0, min_cluster_duration_s=3.0)
    assert params.min_samples > params.min_cluster_size
    clusterer = ContextClusterer(params)
    rng = np.random.default_rng(1)
    for k in range(34):
        clusterer.assign(A + 0.01 * rng.standard_normal(3), 0.1 * k)
    assert clusterer.recluster(3.4).records == []
    for k in range(34, 80):
        clusterer.assign(A + 0.01 * rng.standard_normal(3), 0.1 * k)
    assert len(clusterer.recluster(8.0).records) == 1


def test_a_hold_keeps_the_visit_open_through_frames_beyond_the_widened_gate():
    """``continuation_hold_s``: a frame beyond the widened gate but nearest to the visit's
    context is noise and leaves the visit open for the hold (brick's blurred last frames lay
    1.1-3.3 gates away, one at 3.08-3.09 ended the visit and the 1.1-2.8 gate frames after it
    stayed noise); far from it, nearer another context, or after the hold, it ends the visit."""
    beyond = A + 0.3 * (FAR - A)  # nearest to A's members, beyond 3 gates

    def held(hold):
        clusterer = ContextClusterer(
            ClusteringParams(frame_rate_hz=10.0, continuation_gate_scale=3.0, **hold)
        )
        return two_terrains_into(clusterer)

    off, a, _ = held({})
    z = shifted(off, A, FAR)
    assert off.assign(A, 20.0) == a
    assert off.assign(beyond, 20.1) == NOISE
    assert off.assign(z, 20.2) == NOISE  # without the hold the visit ended
    on, a, b = held({"continuation_hold_s": 1.0})
    assert on.assign(A, 20.0) == a
    assert on.assign(beyond, 20.1) == NOISE  # noise itself
    assert on.assign(z, 20.2) == a  # the visit goes on
    for k in range(11):  # beyond for longer than the hold: the visit ends
        assert on.assign(beyond, 20.3 + 0.1 * k) == NOISE
    assert on.assign(z, 21.5) == NOISE
    assert on.assign(A, 22.0) == a
    assert on.assign(shifted(on, B, A), 22.1) == NOISE  # nearest to B: ends A's visit
    assert on.assign(z, 22.2) == NOISE
    ClusteringParams(continuation_gate_scale=3.0, continuation_hold_s=0.0)
    for bad in (
        {"continuation_hold_s": 1.0},
        {"continuation_gate_scale": 3.0, "continuation_hold_s": -1.0},
    ):
        with pytest.raises(ValueError, match="continuation_hold_s"):
            ClusteringParams(**bad)


def two_terrains_into(clusterer: ContextClusterer) -> tuple[ContextClusterer, int, int]:
    """10 s on terrain A, 10 s on B (10 Hz, spread 0.01) into ``clusterer``, re-clustered; ids
    of A and B."""
    rng = np.random.default_rng(4)
    t = 0.0
    for centre in (A, B):
        for _ in range(100):
            clusterer.assign(centre + 0.01 * rng.standard_normal(3), t)
            t += 0.1
    clusterer.recluster(t)
    ids = clusterer.predict(np.array([A, B]))
    return clusterer, int(ids[0]), int(ids[1])


def two_terrains_at_speed(speed_mps: float) -> tuple[ContextClusterer, int]:
    """Terrains A and B driven at ``speed_mps`` (10 s each), with the widened gate and the
    hold (``paper_eval``'s continuation); the clusterer and A's id."""
    clusterer = ContextClusterer(
        ClusteringParams(frame_rate_hz=10.0, continuation_gate_scale=3.0, continuation_hold_s=1.0)
    )
    rng = np.random.default_rng(4)
    t = 0.0
    for centre in (A, B):
        for _ in range(100):
            clusterer.assign(centre + 0.01 * rng.standard_normal(3), t, speed_mps)
            t += 0.1
    clusterer.recluster(t)
    return clusterer, int(clusterer.predict(A)[0])


def test_other_ground_after_a_held_gap_is_not_handed_the_context_friction():
    """Brick's visit, a strip beyond even the widened gate (held), then another terrain within
    brick's widened gate: at a speed brick's members were taken at, blur cannot explain those
    frames, so they are noise and the handing gives the unknown value, not brick's friction.
    Faster than every member (the camera's blur), the same frames continue the visit."""
    strip = A + 0.3 * (FAR - A)  # nearest to A's members, beyond 3 gates: held
    clusterer, a = two_terrains_at_speed(8.0)
    other = shifted(clusterer, A, FAR)  # just outside A's gate, inside the widened one

    def frames(c: ContextClusterer, speed: float) -> list[int]:
        ids = [c.assign(A, 20.0, speed)]
        ids += [c.assign(strip, 20.1 + 0.1 * k, speed) for k in range(3)]
        return ids + [c.assign(other, 20.4 + 0.1 * k, speed) for k in range(20)]

    ids = frames(copy.deepcopy(clusterer), 7.5)
    assert ids == [a] + [NOISE] * 23
    fits = {a: fit(a, 0.8)}
    h = handing(unknown=StatedFloor(), unidentified=Probe(), floor_mu=0.2)
    mus, t = drive(h, fits, 0.0, [a] * 20)
    assert mus[-1] == pytest.approx(0.8)
    mus, _ = drive(h, fits, t, ids[1:])
    assert mus == pytest.approx([0.2] * 23)  # never brick's 0.8 on the other ground
    unexplained = copy.deepcopy(clusterer)
    unexplained.assign(A, 20.0, 7.5)
    unexplained.assign(strip, 20.1, 7.5)
    assert unexplained.last_evidence == "unexplained"
    # faster than every member: the blur can explain it, the visit goes on as before
    assert frames(copy.deepcopy(clusterer), 11.0) == [a] + [NOISE] * 3 + [a] * 20
    # no speed known (a caller without the state): the continuation as before
    assert frames(copy.deepcopy(clusterer), None) == [a] + [NOISE] * 3 + [a] * 20
