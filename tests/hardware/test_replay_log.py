"""ReplayLog: the recorded drive as functions of time (core, no pydrake)."""

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.hardware.replay import ReplayLog, capture_time


def drive(tmp_path, n=6, frames=(0, 2, 4), truth=True):
    t = 0.1 * np.arange(n)
    log = pd.DataFrame({"t": t})
    for i, name in enumerate(("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")):
        log[name] = t * (i + 1)
    log["steer_rate"] = np.arange(n) * 0.01
    log["accel"] = np.arange(n) * 0.1
    log["mu_true"] = 0.5 if truth else np.nan
    log["terrain_index"] = 1
    log["image"] = ""
    for k in frames:
        name = f"frames/f{k}.png"
        (tmp_path / "frames").mkdir(exist_ok=True)
        (tmp_path / name).write_bytes(b"png")
        log.loc[k, "image"] = name
    return log


def test_state_hold_actuation_before_and_truth(tmp_path):
    log = ReplayLog.from_frame(drive(tmp_path), tmp_path)
    np.testing.assert_allclose(log.state_at(0.2), 0.2 * np.arange(1, 8))
    np.testing.assert_allclose(log.state_at(0.25), 0.2 * np.arange(1, 8))  # held
    # The input recorded at a row is held from it: just before 0.2 it is row 1's.
    np.testing.assert_allclose(log.actuation_before(0.2), [0.01, 0.1])
    np.testing.assert_allclose(log.actuation_before(0.21), [0.02, 0.2])
    np.testing.assert_allclose(log.actuation_before(0.0), [0.0, 0.0])
    assert log.truth_at(0.3) == (0.5, 1.0) and log.duration_s == pytest.approx(0.5)
    no_truth = ReplayLog.from_frame(drive(tmp_path, truth=False), tmp_path)
    assert not no_truth.has_truth and np.isnan(no_truth.truth_at(0.3)[0])


def test_frames_at_their_capture_times(tmp_path):
    # Rows' own times (an imported bag): frames at 0.0, 0.2, 0.4.
    log = ReplayLog.from_frame(drive(tmp_path), tmp_path)
    assert [log.frame_at(t) for t in (0.0, 0.1, 0.2, 0.2005, 0.39, 0.45)] == [0, 0, 0, 1, 1, 2]
    # Frames saved by `simulate` with rows at 0.0, 0.2, 0.4 at a 0.1 s camera period were taken
    # at the newest camera tick strictly before their row (0.0, 0.1, 0.3).
    sim = ReplayLog.from_frame(drive(tmp_path), tmp_path, camera_period_s=0.1)
    np.testing.assert_allclose(sim.frame_t_s, [0.0, 0.1, 0.3])
    assert capture_time(0.0, 0.1) == 0.0 and capture_time(0.25, 0.1) == pytest.approx(0.2)


def test_missing_frames_and_bad_times_are_named(tmp_path):
    log = drive(tmp_path)
    log.loc[1, "image"] = "frames/nope.png"
    with pytest.raises(FileNotFoundError, match="nope.png"):
        ReplayLog.from_frame(log, tmp_path)
    log = drive(tmp_path)
    log.loc[3, "t"] = 0.1
    with pytest.raises(ValueError, match="not increasing"):
        ReplayLog.from_frame(log, tmp_path)


def test_fidelity_says_what_a_replay_cannot_reproduce(tmp_path):
    every = ReplayLog.from_frame(drive(tmp_path, frames=range(6)), tmp_path)
    assert every.fidelity(sample_period_s=0.1, camera_period_s=0.1)["exact"]
    sparse = ReplayLog.from_frame(drive(tmp_path), tmp_path)  # frames at 0, 0.2, 0.4
    report = sparse.fidelity(sample_period_s=0.01, camera_period_s=0.1)
    assert not report["exact"] and report["frames"] == 3 and report["camera_frames"] == 6
    assert "held for 10 samples" in report["reasons"][0]
    assert "3 of 6 camera frames" in report["reasons"][1]
