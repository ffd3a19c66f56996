"""The fitter's sample store (``estimation/sample_store.py``): each row's input is the one applied
from it to the next row, although a sample reads the input applied before its own time."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.effect_fit import EffectFitter
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.sample_store import SampleStore, inputs_as_read
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
MODEL = ["peak_tyre:k_s=0.0", "axle_stiffness:k_f=1.01,k_r=1.24"]


def test_a_row_takes_the_input_read_at_the_next_sample_and_copies_keep_theirs():
    store = SampleStore(chunk_size=3)
    state = np.zeros(7)
    for k in range(5):  # the input read at sample k was applied over [k - 1, k)
        store.append(float(k), state, np.array([k, -k], dtype=float), 0)
    snapshot = copy.deepcopy(store)
    store.append(5.0, state, np.array([5.0, -5.0]), 0)
    t, _, u = store.rows()
    np.testing.assert_array_equal(u[:, 0], [1, 2, 3, 4, 5, 5])  # the newest holds its reading
    np.testing.assert_array_equal(u[:, 1], -u[:, 0])
    np.testing.assert_array_equal(snapshot.rows()[2][:, 0], [1, 2, 3, 4, 4])  # a copy: its own
    # the previous row closed a chunk (rows 0-2 full after the third append): that chunk is
    # replaced by a copy, never written in place, so a copy taken before keeps its rows
    store2 = SampleStore(chunk_size=3)
    for k in range(3):
        store2.append(float(k), state, np.array([k, 0.0]), 0)
    before = copy.deepcopy(store2)
    store2.append(3.0, state, np.array([3.0, 0.0]), 0)
    assert store2.rows()[2][2, 0] == 3.0 and before.rows()[2][2, 0] == 2.0
    with pytest.raises(ValueError):
        store2._chunks[0][0, 0] = 1.0  # full chunks stay read-only


def test_the_fitter_reads_its_inputs_applied_from_each_sample():
    """A drive whose inputs are read as a simulation's samples read them (the input applied
    before each sample instant): the estimator's store gives the fit the input applied from each
    sample, so its fit equals the fit of the drive as simulated."""
    df = synth.simulate_truths(
        [synth.Truth(mu=0.8, mu_peak=0.7)], duration_s=12.0, rate_hz=50.0, seed=4, substeps=2
    )[0]
    t, S = df["t"].to_numpy(), df[STATES].to_numpy()
    U = df[["steer_rate", "accel"]].to_numpy()  # U[k] applied over [t_k, t_k+1)
    read = inputs_as_read(U)  # what a sample at t_k reads: the input before t_k
    est = ContextEstimator(ford_escort(), LiveFitConfig(model=synth_model(), sample_period_s=0.02))
    for k in range(t.size):
        est.add_sample(t[k], S[k], read[k], 0)
    _, _, stored = est._store.rows()
    np.testing.assert_array_equal(stored[:-1], U[:-1])
    fitter = EffectFitter(ford_escort(), MODEL)
    as_driven = fitter(t, S, U, None, 1.0489)
    as_stored = fitter(t, S, stored, None, 1.0489)
    as_read = fitter(t, S, read, None, 1.0489)
    assert as_stored.theta[0] == pytest.approx(as_driven.theta[0], abs=1e-9)
    assert abs(as_read.theta[0] - as_driven.theta[0]) > 1e-3  # inputs one sample late: another fit


def synth_model():
    from pcvfe_drake.models.effect_model import EffectModel

    return EffectModel(effects=MODEL)
