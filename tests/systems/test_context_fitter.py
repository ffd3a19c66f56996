"""ContextFitter LeafSystem: ports, prior handling, and a short run on a recorded drive."""

from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from pcvfe_drake.contexts.cluster_table import FrameLabels
from pcvfe_drake.estimation.context_estimator import EstimateTable
from pcvfe_drake.handing.config import HandingConfig
from pcvfe_drake.hardware.scheduling import control_priority, real_time_permitted
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.systems.context_fitter import ContextFitter, HeldSamples
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def params():
    return ford_escort()


def test_ports_and_prior_with_fixed_inputs(params):
    fitter = ContextFitter(params)
    assert [fitter.get_input_port(i).get_name() for i in range(4)] == [
        "state",
        "actuation",
        "context_id",
        "frame_labels",
    ]
    assert fitter.GetOutputPort("theta_hat").size() == 3
    context = fitter.CreateDefaultContext()
    # Before any sample (the controller's first update reads it before the first decision):
    # what the handing gives an unknown terrain (the default policy: the floor mu 0.3 with the
    # prior's small-slip stiffness mu * C_S), never the prior's dry friction.
    unknown = [0.3, params.C_Sf * params.mu / 0.3, params.C_Sr * params.mu / 0.3]
    np.testing.assert_array_equal(fitter.GetOutputPort("theta_hat").Eval(context), unknown)
    assert not fitter.HasAnyDirectFeedthrough()

    state = np.array([0.0, 0.0, 0.02, 8.0, 0.0, 0.1, 0.01])
    fitter.GetInputPort("state").FixValue(context, state)
    fitter.GetInputPort("actuation").FixValue(context, [0.0, 0.0])
    fitter.GetInputPort("context_id").FixValue(context, [3.0])
    simulator = Simulator(fitter, context)
    simulator.AdvanceTo(0.5)
    table = fitter.GetOutputPort("estimate_table").Eval(context)
    assert isinstance(table, EstimateTable)
    entry = table.get(3)
    assert entry.samples == 50  # t = 0, 0.01, ..., 0.49 (the update at 0.5 is still due)
    assert entry.status == "prior" and not entry.fitted
    # No fit yet: the default unknown-context policy ("conservative"): the floor mu 0.3, with the
    # prior's small-slip stiffness mu * C_S.
    np.testing.assert_array_equal(fitter.GetOutputPort("theta_hat").Eval(context), unknown)

    # Non-finite state: not stored, and the output stays finite.
    fitter.GetInputPort("state").FixValue(context, np.full(7, np.nan))
    simulator.AdvanceTo(1.2)  # includes the first refit at t = 1 s
    table = fitter.GetOutputPort("estimate_table").Eval(context)
    assert table.rejected_samples == 70
    assert table.get(3).samples == 50
    assert table.get(3).status == "too_little_data"
    assert np.all(np.isfinite(fitter.GetOutputPort("theta_hat").Eval(context)))


def test_bad_settings_are_rejected(params):
    with pytest.raises(ValueError, match="period_s"):
        ContextFitter(params, period_s=0.0)
    with pytest.raises(ValueError, match="unknown setting"):
        ContextFitter(params, horizon=3)
    with pytest.raises(ValueError, match="horizon_steps"):
        ContextFitter(params, horizon_steps=0)


def test_recorded_drive_converges_and_switches_context(params):
    """A recorded drive: mu 0.45 on context 2 for 3 s, noise, 3 s of mu 0.8 on context 5."""
    t, S, U = s_curve_drive(params, [0.45, 0.8], duration_s=3.0, phase_rad=[0.0, 1.5])
    n = t.size
    times = np.concatenate([t, t + 3.01 + 0.5])
    states = np.concatenate([S[0], S[1]])
    inputs = np.concatenate([U[0], U[1]])
    ctx = np.concatenate([np.full(n, 2.0), np.full(n, 5.0)])
    ctx[-50:] = -1.0  # the last half second is "noise"
    # Zero-order holds: the first drive's last sample is held until the second drive starts
    # (3.0 s .. 3.51 s); it is labelled noise, so the held (stale) state is not fitted.
    ctx[n - 1] = -1.0
    builder = DiagramBuilder()
    sources = [
        builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(times, y.T)))
        for y in (states, inputs, ctx[None, :].T)
    ]
    fitter = builder.AddNamedSystem(
        "fitter", ContextFitter(params, period_s=1.0, handing=HandingConfig(noise_hold_s=0.25))
    )
    for source, name in zip(sources, ("state", "actuation", "context_id"), strict=True):
        builder.Connect(source.get_output_port(), fitter.GetInputPort(name))
    log = LogVectorOutput(fitter.GetOutputPort("theta_hat"), builder, publish_period=0.05)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()

    simulator.AdvanceTo(2.95)  # fitted at t = 1 s and 2 s; still on context 2
    fc = fitter.GetMyContextFromRoot(root)
    theta = fitter.GetOutputPort("theta_hat").Eval(fc)
    assert abs(theta[0] - 0.45) < 0.01
    assert theta[1] == params.C_Sf and theta[2] == params.C_Sr

    simulator.AdvanceTo(times[-1])
    table = fitter.GetOutputPort("estimate_table").Eval(fc)
    assert [e.context_id for e in table.entries] == [2, 5]
    e2, e5 = table.get(2), table.get(5)
    assert abs(e2.mu - 0.45) < 0.01 and e2.fits >= 1 and e2.mu_std < 0.01
    assert abs(e5.mu - 0.8) < 0.01 and e5.last_update_s > 3.5
    assert table.noise_samples >= 50
    # Context -1 at the end, for longer than noise_hold_s: the conservative policy's mu, the
    # floor 0.3 (both fitted contexts' lower bounds, 0.45 - 2 std and 0.8 - 2 std, lie above).
    np.testing.assert_array_equal(
        fitter.GetOutputPort("theta_hat").Eval(fc),
        [0.3, params.C_Sf * params.mu / 0.3, params.C_Sr * params.mu / 0.3],
    )
    data = log.FindLog(root).data()
    assert np.all(np.isfinite(data))


@pytest.mark.parametrize("relabel", [True, False])
def test_frame_labels_relabel_the_noise_samples_of_a_new_terrain(params, relabel):
    """2 s of mu 0.8 reported as noise; then the clustering's labels say it was context 5."""
    t, S, U = s_curve_drive(params, [0.8], duration_s=2.5)
    fitter = ContextFitter(params, period_s=1.0, relabel=relabel)
    context = fitter.CreateDefaultContext()
    ports = {name: fitter.GetInputPort(name) for name in ("state", "actuation", "context_id")}
    ports["context_id"].FixValue(context, [-1.0])
    frames = fitter.GetInputPort("frame_labels")
    frames.FixValue(context, FrameLabels(version=0, frame_period_s=0.1))
    simulator = Simulator(fitter, context)
    for k in range(t.size):  # one sample per 10 ms step
        ports["state"].FixValue(context, S[0, k])
        ports["actuation"].FixValue(context, U[0, k])
        simulator.AdvanceTo(t[k] + 0.005)
    table = fitter.GetOutputPort("estimate_table").Eval(context)
    assert table.entries == () and table.noise_samples == t.size
    # A re-clustering: every frame so far was terrain 5.
    ft = np.round(np.arange(0.0, t[-1], 0.1), 6)
    frames.FixValue(context, FrameLabels(ft, np.full(ft.size, 5), 1, 0.1))
    simulator.AdvanceTo(t[-1] + 0.015)  # the next sample update relabels, then refits
    table = fitter.GetOutputPort("estimate_table").Eval(context)
    if not relabel:
        assert table.entries == () and table.relabelled_samples == 0
        return
    entry = table.get(5)
    assert table.relabelled_samples == t.size - 1 and table.labels_version == 1
    assert entry.samples == t.size - 1  # the first sample precedes every frame
    assert entry.fitted and abs(entry.mu - 0.8) < 0.01
    assert entry.first_fit_s == pytest.approx(t[-1] + 0.01)  # not at the next refit (3 s)


def test_declared_latency_publishes_the_refit_later_in_simulated_time(params):
    """A refit started at t = 2 s on the data up to 2 s is handed over at 2 s + latency."""
    t, S, U = s_curve_drive(params, [0.45], duration_s=3.0)

    def run(latency_s):
        builder = DiagramBuilder()
        fitter = builder.AddNamedSystem(
            "fitter", ContextFitter(params, period_s=1.0, latency_s=latency_s)
        )
        for y, name in ((S[0], "state"), (U[0], "actuation"), (np.full((t.size, 1), 2.0), "id")):
            source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(t, y.T)))
            builder.Connect(
                source.get_output_port(),
                fitter.GetInputPort("context_id" if name == "id" else name),
            )
        simulator = Simulator(builder.Build())
        fc = fitter.GetMyContextFromRoot(simulator.get_mutable_context())
        out = {}
        for when in (2.0, 2.2, 2.4):
            simulator.AdvanceTo(when + 1e-6)
            out[when] = fitter.GetOutputPort("estimate_table").Eval(fc).get(2)
        return out

    at_once, late = run(0.0), run(0.3)
    assert at_once[2.0].last_update_s == pytest.approx(2.0)
    assert not late[2.2].last_update_s >= 2.0  # in flight: the last published one is handed
    assert late[2.4].last_update_s == pytest.approx(2.3)
    # the same data (up to the start), so the same estimate, only later
    assert late[2.4].fitted and late[2.4].mu == pytest.approx(at_once[2.0].mu, abs=1e-12)
    assert late[2.4].data_end_s == pytest.approx(at_once[2.0].data_end_s)
    assert late[2.4].sample_to_estimate_s[0] >= 0.3
    with pytest.raises(ValueError, match="latency_s"):
        ContextFitter(params, period_s=1.0, latency_s=1.0)


def test_refit_worker_publishes_the_same_fit_without_holding_up_the_updates(params):
    """With a worker the refit runs beside the loop and is adopted once done and due."""
    t, S, U = s_curve_drive(params, [0.45], duration_s=3.0)
    results = {}
    for worker in (False, True):
        fitter = ContextFitter(params, period_s=1.0, latency_s=0.1, refit_worker=worker)
        context = fitter.CreateDefaultContext()
        simulator = Simulator(fitter, context)
        entry, k = None, 0
        while entry is None or not entry.fitted:
            fitter.GetInputPort("state").FixValue(context, S[0][k])
            fitter.GetInputPort("actuation").FixValue(context, U[0][k])
            fitter.GetInputPort("context_id").FixValue(context, [2.0])
            simulator.AdvanceTo(context.get_time() + 0.01)
            if worker and context.get_time() > 1.1:
                time.sleep(0.002)  # the worker thread runs between the loop's steps
            entry = fitter.GetOutputPort("estimate_table").Eval(context).get(2)
            k = min(k + 1, t.size - 1)
            assert context.get_time() < 30.0
        results[worker] = entry
    assert results[True].mu == pytest.approx(results[False].mu, abs=1e-12)
    assert results[True].data_end_s == pytest.approx(results[False].data_end_s)


def _thread_ids() -> set[int]:
    return {int(tid) for tid in os.listdir("/proc/self/task")}


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or not real_time_permitted(),
    reason="SCHED_FIFO not permitted here (no root, CAP_SYS_NICE or rtprio limit)",
)
def test_the_refit_worker_runs_at_ordinary_priority_beside_a_real_time_loop(params):
    """The loop's thread at SCHED_FIFO starts the worker, which inherits that policy where the
    loop was raised without SCHED_RESET_ON_FORK (``children_inherit``, as ``chrt`` would): the
    worker drops it, so a refit cannot preempt the loop."""
    t, S, U = s_curve_drive(params, [0.45], duration_s=3.0)
    before = _thread_ids()
    fitter = ContextFitter(params, period_s=1.0, latency_s=0.1, refit_worker=True)
    context = fitter.CreateDefaultContext()
    simulator = Simulator(fitter, context)
    entry, k, policies = None, 0, {}
    with control_priority(3, "hardware.control_priority", children_inherit=True):
        while entry is None or not entry.fitted:
            fitter.GetInputPort("state").FixValue(context, S[0][k])
            fitter.GetInputPort("actuation").FixValue(context, U[0][k])
            fitter.GetInputPort("context_id").FixValue(context, [2.0])
            simulator.AdvanceTo(context.get_time() + 0.01)
            if context.get_time() > 1.1:
                time.sleep(0.002)
            entry = fitter.GetOutputPort("estimate_table").Eval(context).get(2)
            k = min(k + 1, t.size - 1)
            assert context.get_time() < 30.0
        loop = threading.get_native_id()
        policies = {tid: os.sched_getscheduler(tid) for tid in _thread_ids() - before}
        loop_policy = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK
    assert loop_policy == os.SCHED_FIFO and loop not in policies
    assert policies, "the refit ran in no new thread"
    assert set(policies.values()) == {os.SCHED_OTHER}, policies


def _recorded_drive_diagram(params, decision_period_s, latency_s):
    """The recorded drive of the test above (two contexts, noise between and at the end) into a
    fitter deciding every ``decision_period_s`` (with its HeldSamples where that is longer
    than the sample period)."""
    t, S, U = s_curve_drive(params, [0.45, 0.8], duration_s=3.0, phase_rad=[0.0, 1.5])
    n = t.size
    times = np.concatenate([t, t + 3.01 + 0.5])
    ctx = np.concatenate([np.full(n, 2.0), np.full(n, 5.0)])
    ctx[-50:] = -1.0
    ctx[n - 1] = -1.0
    builder = DiagramBuilder()
    sources = [
        builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(times, y.T)))
        for y in (np.concatenate([S[0], S[1]]), np.concatenate([U[0], U[1]]), ctx[None, :].T)
    ]
    fitter = builder.AddNamedSystem(
        "fitter",
        ContextFitter(
            params,
            period_s=1.0,
            latency_s=latency_s,
            decision_period_s=decision_period_s,
            handing=HandingConfig(noise_hold_s=0.25),
        ),
    )
    takers = [fitter]
    if fitter.decision_period_s > fitter.sample_period_s:
        held = builder.AddSystem(
            HeldSamples(sample_period_s=fitter.sample_period_s, capacity=fitter.held_capacity)
        )
        builder.Connect(held.get_output_port(), fitter.GetInputPort("held_samples"))
        takers.append(held)
    for taker in takers:
        for source, name in zip(sources, ("state", "actuation", "context_id"), strict=True):
            builder.Connect(source.get_output_port(), taker.GetInputPort(name))
    return builder.Build(), fitter, times[-1]


@pytest.mark.parametrize("latency_s", [0.0, 0.33])
def test_a_decision_period_hands_the_controller_what_a_decision_every_sample_does(
    params, latency_s
):
    """Deciding every 0.05 s from held samples: the estimator takes the same steps, so between
    samples before each decision tick (where a controller reads it) theta_hat is the same, and
    so are the final estimates; the fitter's own state is copied 5 times less often."""
    runs = {}
    for decision in (None, 0.05):
        diagram, fitter, end = _recorded_drive_diagram(params, decision, latency_s)
        simulator = Simulator(diagram)
        fc = fitter.GetMyContextFromRoot(simulator.get_mutable_context())
        thetas = []
        for k in range(1, int(end / 0.05)):
            simulator.AdvanceTo(k * 0.05 - 0.002)  # after the last decision before tick k
            thetas.append(np.array(fitter.GetOutputPort("theta_hat").Eval(fc)))
        simulator.AdvanceTo(end - 0.002)
        runs[decision] = (np.array(thetas), fitter.estimator(fc).table(end))
    (every, table_every), (held, table_held) = runs[None], runs[0.05]
    assert np.ptp(every[:, 0]) > 0.3  # the drive moves theta (prior, 0.45, 0.8, the floor)
    np.testing.assert_array_equal(every, held)
    assert repr(table_every) == repr(table_held)  # (NaN std entries: not ==)


def test_held_samples_and_decision_period_are_checked(params):
    with pytest.raises(ValueError, match="whole multiple of sample_period_s"):
        ContextFitter(params, decision_period_s=0.025)
    with pytest.raises(ValueError, match="capacity"):
        HeldSamples(sample_period_s=0.01, capacity=0)
    fitter = ContextFitter(params, decision_period_s=0.05)
    assert fitter.held_capacity == 6 and fitter.HasInputPort("held_samples")
    assert not fitter.HasAnyDirectFeedthrough()
    context = fitter.CreateDefaultContext()
    for name, value in (("state", np.zeros(7)), ("actuation", np.zeros(2)), ("context_id", [0])):
        fitter.GetInputPort(name).FixValue(context, value)
    simulator = Simulator(fitter, context)
    with pytest.raises(RuntimeError, match="held_samples input is not connected"):
        simulator.AdvanceTo(0.05)
