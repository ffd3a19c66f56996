"""``pcvfe calibrate``: the car's effect model from a calibration drive (planted truths)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcvfe_drake.models.data import prepare
from pcvfe_drake.models.effect_model import load_model_file, vehicle_constants
from pcvfe_drake.vehicle.mb_truth import MbSingularity
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench.calibration import calibrate
from pcvfe_drake.workbench.calibration_drive import CIRCLE_LEVELS, CIRCLE_RADIUS_M, programme
from pcvfe_drake.workbench.synth import Truth, simulate_truths

VP = ford_escort()
CONST = vehicle_constants("ford_escort", VP)
PLANTED = Truth(
    mf_peak=0.8,
    axle_stiffness=(0.93, 1.12),
    roll_camber=(CONST["roll_camber"]["f0"], 0.0, CONST["roll_camber"]["s0"]),
    track=(VP.track, VP.track, -0.5),
)


@pytest.fixture(scope="module")
def calibration():
    df = simulate_truths([PLANTED], VP, duration_s=40.0, seed=3)[0]
    data = prepare(df, "planted")
    return calibrate(data, "ford_escort", VP, 0.0, candidates=("axle_stiffness",))


def test_calibration_recovers_the_planted_car_and_holds_its_constants(calibration):
    model = calibration.model
    effects = {e.name: e for e in model.effects}
    assert calibration.effects[-1] == "axle_stiffness" and set(effects) == {
        "peak_tyre",
        "track_slip",
        "roll_camber",
        "axle_stiffness",
    }
    axle = effects["axle_stiffness"]
    assert axle.fixed["k_f"] == pytest.approx(0.93, abs=0.05)
    assert axle.fixed["k_r"] == pytest.approx(1.12, abs=0.05)
    assert 0 < axle.std["k_f"] < 0.05
    # the car's own constants are held exactly (std 0): the track and the tyre's camber
    assert effects["track_slip"].fixed["t"] == VP.track and effects["track_slip"].std["t"] == 0
    assert effects["roll_camber"].fixed == CONST["roll_camber"]
    assert effects["peak_tyre"].fixed == {"k_s": 0.0}
    assert calibration.surface_mu["all"] == pytest.approx(0.8, abs=0.04)
    assert model.calibrated_mu == pytest.approx(0.8, abs=0.04)
    assert calibration.heldout_error < calibration.baseline_heldout_error
    assert math.isfinite(model.model_error_rel) and model.model_error_rel < 0.1


def test_the_written_model_file_is_what_the_fitter_reads(calibration, tmp_path):
    from pcvfe_drake.models.effect_model import write_model_file

    path = write_model_file(
        tmp_path / "car_model.yaml", calibration.model, "ford_escort", "a\nb", calibration.summary()
    )
    assert path.read_text().startswith("# a\n# b\n")
    again = load_model_file(path)
    assert again.to_dict() == calibration.model.to_dict()


def test_the_programme_drives_the_stated_circles():
    segments = programme("ford_escort", 0.9)
    circles = [s for s in segments if s.kind == "circle" and abs(s.value) == 1 / CIRCLE_RADIUS_M]
    assert len(circles) == 2 * len(CIRCLE_LEVELS)
    levels = [s.v_mps**2 / CIRCLE_RADIUS_M / (0.9 * VP.g) for s in circles]
    np.testing.assert_allclose(levels, list(CIRCLE_LEVELS) * 2)
    assert {s.kind for s in segments} == {"cruise", "circle", "step", "sweep", "brake"}
    assert all(s.value > 0 for s in segments if s.kind == "brake")


@pytest.mark.parametrize(
    "argv, message",
    [
        (["calibrate"], "give a calibration drive LOG or --simulate VEHICLE"),
        (["calibrate", "log.csv", "--simulate", "bmw_320i"], "(one of them)"),
        (["calibrate", "log.csv"], "a calibration LOG needs --vehicle"),
        (["calibrate", "--simulate", "roboracer"], "has no CommonRoad multi-body parameters"),
    ],
)
def test_calibrate_arguments_are_checked_before_any_work(argv, message, capsys):
    from pcvfe_drake.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


@pytest.fixture(scope="module")
def short_log():
    """The planted car, 25 s (a log for the command's plumbing; copy before changing it)."""
    return simulate_truths([PLANTED], VP, duration_s=25.0, seed=3)[0]


def test_calibrate_reads_only_what_a_car_measures(short_log, tmp_path, capsys, monkeypatch):
    """Truth columns of the log never reach the calibration."""
    import pcvfe_drake.models.data as data_module
    from pcvfe_drake.cli import main
    from pcvfe_drake.runs.drivelog import REQUIRED_COLUMNS

    df = short_log.copy()
    df["mu_true"] = 0.8
    df["true_v"] = df["v"]
    df.to_csv(tmp_path / "drive.csv", index=False)
    seen = {}

    def fake(table, *args, **kwargs):
        seen["columns"] = list(table.columns)
        raise ValueError("stop here")

    monkeypatch.setattr(data_module, "prepare", fake)
    argv = ["calibrate", str(tmp_path / "drive.csv"), "--vehicle", "ford_escort"]
    assert main(argv) == 2
    assert "stop here" in capsys.readouterr().err
    assert seen["columns"] == list(REQUIRED_COLUMNS)


def test_check_mu_needs_the_simulated_programme(capsys):
    from pcvfe_drake.cli import main

    argv = ["calibrate", "log.csv", "--vehicle", "ford_escort", "--check-mu", "0.3"]
    assert main(argv) == 2
    assert "--check-mu drives a second surface: it needs --simulate" in capsys.readouterr().err


def test_the_check_surface_measures_the_held_model_at_another_friction(calibration, tmp_path):
    """The model calibrated at mu 0.8 fits only mu on a drive at 0.7: the offset is measured,
    and between the two frictions the handing adds no extrapolated error."""
    from dataclasses import replace

    from pcvfe_drake.commands.calibrate import check_surface
    from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
    from pcvfe_drake.models.effect_model import write_model_file
    from pcvfe_drake.runs.drivelog import REQUIRED_COLUMNS

    low = replace(PLANTED, mf_peak=0.7)
    df = simulate_truths([low], VP, duration_s=30.0, seed=4)[0]
    check = check_surface(df, list(REQUIRED_COLUMNS), "planted", VP, calibration.model, 0.7)
    assert check["mu_known"] == 0.7 and abs(check["mu_fitted"] - 0.7) < 0.05
    assert check["offset_rel"] == round(abs(check["mu_fitted"] - 0.7) / 0.7, 4)

    model = replace(calibration.model, model_error_rel=0.1, calibrated_mu=0.8, checked_mu=0.4)
    assert model.measured_mu_range == (0.4, 0.8)
    again = load_model_file(write_model_file(tmp_path / "m.yaml", model, "ford_escort", "x", {}))
    assert again.checked_mu == 0.4 and again.to_dict() == model.to_dict()
    error = LiveFitConfig(model=model).model_error()
    assert error.calibrated_mu == (0.4, 0.8)
    assert error.handed_mu(0.5) == 0.5  # measured there: the budget alone
    assert error.handed_mu(0.2) < 0.2  # below the checked surface: extrapolated
    with pytest.raises(ValueError, match="checked_mu must be > 0"):
        replace(model, checked_mu=-1.0)


def test_a_check_surface_the_truth_cannot_drive_is_a_warning(
    calibration, short_log, tmp_path, capsys, monkeypatch
):
    """The multi-body truth failing on the check surface leaves a model without checked_mu and
    a warning that says why, not an internal error."""
    import copy

    import pcvfe_drake.workbench.calibration as calibration_module
    import pcvfe_drake.workbench.calibration_drive as drive_module
    from pcvfe_drake.cli import main

    df = short_log.copy()
    surfaces = []

    def drive(vehicle, mapping, mu, seed=0, progress=None):
        surfaces.append(mu)
        if len(surfaces) == 2:
            raise MbSingularity("wheel ground speed <= 0 (rear right -0.2 m/s)", np.zeros(29))
        return df

    monkeypatch.setattr(drive_module, "calibration_drive", drive)
    monkeypatch.setattr(calibration_module, "calibrate", lambda *a, **k: copy.deepcopy(calibration))
    out = tmp_path / "model.yaml"
    argv = [
        "calibrate",
        "--simulate",
        "ford_escort",
        "--mapping",
        "lateral_peak",
        "--out",
        str(out),
    ]
    assert main([*argv, "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "warning: the check surface" in err and "the model has no checked_mu" in err
    assert "MbSingularity: multi-body truth singular: wheel ground speed" in err  # the child's
    check_mu = float(err.split("the check surface (mu ")[1].split(")")[0])
    assert check_mu == pytest.approx(0.3 * surfaces[0], rel=1e-4)
    model = load_model_file(out)
    assert model.checked_mu is None and model.calibrated_mu is not None


def test_a_check_drive_past_its_bound_is_stopped_with_a_warning(
    calibration, tmp_path, capsys, monkeypatch
):
    """A check drive that crawls (here: hangs) is stopped after its bound, derived from the
    calibration drive's wall time per simulated second; the model is written without
    checked_mu, as when the truth fails there."""
    import copy
    import time

    import pcvfe_drake.commands.calibrate as command
    import pcvfe_drake.workbench.calibration as calibration_module
    import pcvfe_drake.workbench.calibration_drive as drive_module
    from pcvfe_drake.cli import main

    df = simulate_truths([PLANTED], VP, duration_s=25.0, seed=3)[0]
    calls = []

    def drive(vehicle, mapping, mu, seed=0, progress=None):
        calls.append(mu)
        if len(calls) == 2:  # in the check drive's process
            time.sleep(60.0)
        time.sleep(0.02)
        return df

    monkeypatch.setattr(drive_module, "calibration_drive", drive)
    monkeypatch.setattr(calibration_module, "calibrate", lambda *a, **k: copy.deepcopy(calibration))
    monkeypatch.setattr(command, "CHECK_MIN_S", 0.5)
    out = tmp_path / "model.yaml"
    argv = ["calibrate", "--simulate", "ford_escort", "--mapping", "lateral_peak"]
    start = time.monotonic()
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    assert time.monotonic() - start < 20.0
    err = capsys.readouterr().err
    assert "CheckDriveTimeout" in err and "ran past its bound" in err
    assert "the model has no checked_mu" in err
    model = load_model_file(out)
    assert model.checked_mu is None and model.calibrated_mu is not None


def test_the_check_drive_bound_follows_the_calibration_drive():
    from pcvfe_drake.commands.calibrate import (
        CHECK_MIN_S,
        CHECK_SLOWDOWN,
        bounded_drive,
        check_drive_limit_s,
    )

    # 100 s of programme driven in 200 s: 2 s per simulated second
    assert check_drive_limit_s(200.0, 100.0, 120.0) == pytest.approx(CHECK_SLOWDOWN * 240.0)
    assert check_drive_limit_s(0.1, 100.0, 100.0) == CHECK_MIN_S
    assert bounded_drive(lambda a, b=0: a + b, 5.0, 1, b=2) == 3
    with pytest.raises(FloatingPointError, match="overflow"):
        bounded_drive(lambda: (_ for _ in ()).throw(FloatingPointError("overflow")), 5.0)


def test_the_driver_holds_the_heading_where_the_yaw_mode_is_unstable():
    """Under ``peak_and_stiffness`` at the check surface's friction the Ford's yaw mode diverges
    at 8 m/s (the whole tyre scaled to a third); a driver who only catches the side slip lets
    the yaw rate grow until the truth's integration crawls. Holding the heading keeps it still."""
    from pcvfe_drake.workbench.calibration_drive import Segment, calibration_drive

    log = calibration_drive(
        "ford_escort",
        "peak_and_stiffness",
        0.3147,
        noise=None,
        segments=[Segment("cruise", 3.0, 8.0)],
    )
    late = log[log.t >= 2.0]
    assert late.psi_dot.abs().max() < 5e-4 and late.beta.abs().max() < 5e-4


def test_the_driver_changes_speed_within_a_share_of_the_grip():
    from pcvfe_drake.workbench.calibration_drive import (
        SPEED_BRAKE_G,
        SPEED_BRAKE_MPS2,
        SPEED_DRIVE_G,
        SPEED_DRIVE_MPS2,
        Segment,
        calibration_drive,
    )

    speed_up = [Segment("cruise", 1.0, 5.0), Segment("cruise", 2.0, 12.0)]
    speed_up.append(Segment("cruise", 2.0, 3.0))
    low = calibration_drive("ford_escort", "lateral_peak", 0.3, noise=None, segments=speed_up)
    assert low.accel.max() == pytest.approx(SPEED_DRIVE_G * 0.3 * VP.g)
    assert low.accel.min() == pytest.approx(-SPEED_BRAKE_G * 0.3 * VP.g)
    dry = calibration_drive("ford_escort", "lateral_peak", 1.05, noise=None, segments=speed_up)
    assert dry.accel.max() == SPEED_DRIVE_MPS2 and dry.accel.min() == -SPEED_BRAKE_MPS2
    with pytest.raises(ValueError, match="unknown segment kind 'drift'"):
        calibration_drive("ford_escort", "lateral_peak", 1.0, segments=[Segment("drift", 1.0, 5.0)])
