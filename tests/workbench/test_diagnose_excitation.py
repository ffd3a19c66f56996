"""``pcvfe diagnose`` gives no verdict on a log that carries no excitation, and names what is
missing; the verdict's "where" names the time and place where the error remains."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.models.data import DriveData, prepare
from pcvfe_drake.models.synthetic_drive import drive_frame
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import NX, PSI_DOT, V, rk4_step
from pcvfe_drake.workbench.excitation import NotDiagnosable, excitation
from pcvfe_drake.workbench.report import diagnose
from pcvfe_drake.workbench.verdict import hot_span, where_sentence

DT = 0.05


def straight_drive(n: int = 600, seed: int = 0):
    """30 s straight at 10 m/s, no commands (the ST model), with the default sensor noise."""
    params = ford_escort()
    x = np.zeros((1, NX))
    x[0, V] = 10.0
    u = np.zeros((n, 2))
    states = np.empty((n, NX))
    for i in range(n):
        states[i] = x[0]
        x = rk4_step(x, u[i : i + 1], params, DT)
    noisy = states + np.random.default_rng(seed).standard_normal(states.shape) * (
        MeasurementNoise().sigma
    )
    return drive_frame(np.arange(n) * DT, noisy, u)


def arrays(psi_dot: np.ndarray, v: np.ndarray) -> DriveData:
    n = psi_dot.size
    x = np.zeros((n, NX))
    x[:, PSI_DOT], x[:, V] = psi_dot, v
    sigma = np.full(NX, 0.01)
    t = np.arange(n) * DT
    return DriveData(t, DT, x, np.zeros((n, 2)), np.zeros(n, int), ["all"], sigma, "arrays")


def test_straight_drive_is_refused_naming_what_is_missing(tmp_path, capsys):
    df = straight_drive()
    ex = excitation(prepare(df, "straight"))
    assert ex["missing"] == ["yaw excitation", "speed change"] and not ex["diagnosable"]
    with pytest.raises(NotDiagnosable, match="straight: not diagnosable: no yaw excitation"):
        diagnose(prepare(df, "straight"))
    path = tmp_path / "straight.csv"
    df.to_csv(path, index=False)
    assert main(["diagnose", str(path)]) == 2
    err = capsys.readouterr().err
    assert "not diagnosable: no yaw excitation (yaw rate rms" in err
    assert "no speed change (speed std" in err and "Traceback" not in err


def test_which_channels_are_excited():
    t = np.arange(400) * DT
    slalom = 0.3 * np.sin(2 * np.pi * 0.3 * t)
    steady = arrays(slalom, np.full(t.size, 10.0))  # constant speed: no speed change
    ex = excitation(steady)
    assert ex["diagnosable"] and ex["missing"] == ["speed change"]
    assert ex["channels"]["yaw excitation"]["ratio"] == pytest.approx(0.3 / np.sqrt(2) / 0.01)
    circle = excitation(arrays(np.full(t.size, 0.2), 10.0 + 2.0 * np.sin(0.5 * t)))
    assert circle["missing"] == []  # a steady circle excites the yaw rate (its rms)
    # below the fitter's factor (5 x the noise) the yaw rate is noise
    flat = excitation(arrays(np.full(t.size, 0.049), np.full(t.size, 10.0)))
    assert not flat["diagnosable"] and "needs > 5 x" in flat["text"]


def test_where_names_the_span_holding_most_of_the_error():
    n = 2000
    t = np.arange(n) * DT
    x = np.zeros((n, NX))
    x[:, 0], x[:, 1] = t * 10.0, -5.0
    context = np.where(t < 50.0, 0, 1)
    data = DriveData(t, DT, x, np.zeros((n, 2)), context, ["sand", "brick"], np.ones(NX), "s")
    starts = np.arange(0, n - 20, 10)
    excess = np.full(starts.size, 0.1)
    hot = (t[starts] >= 60.0) & (t[starts] < 70.0)
    excess[hot] = 5.0
    excess[np.flatnonzero(t[starts] >= 20.0)[0]] = 3.0  # a single hot window elsewhere
    span = hot_span(excess, starts, 20, data)
    assert span["t0_s"] == pytest.approx(60.0) and span["t1_s"] == pytest.approx(70.5)
    assert span["context"] == "brick" and span["sx_m"] == pytest.approx(652.5)
    assert span["share"] == pytest.approx(100.0 / (100.0 + 3.0 + 0.1 * (starts.size - 21)))
    where = {"concentrated": [], "worst_state": "beta", "span": span}
    text = where_sentence(where, contexts=2)
    assert "at t 60.0-70.5 s, around (652, -5) m, on brick" in text
    assert hot_span(np.zeros(starts.size), starts, 20, data) is None
