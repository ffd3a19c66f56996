"""``pcvfe diagnose``: JSON output, run folders, reports, and clear errors on bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from drive_logs import drag_45s_log

from pcvfe_drake.cli import main
from pcvfe_drake.runs.drivelog import write_drive_log


@pytest.fixture(scope="module")
def drag_log(tmp_path_factory, run_cache):
    df = drag_45s_log(run_cache)
    path = tmp_path_factory.mktemp("logs") / "drive.csv"
    write_drive_log(df, path)
    return df, path


def test_json_with_add(drag_log, tmp_path, capsys):
    _, path = drag_log
    out = tmp_path / "report"
    code = main(
        [
            "diagnose",
            str(path),
            "--add",
            "drag",
            "--candidates",
            "drag,rolling_resistance",
            "--json",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    report = json.loads(lines[-1])
    assert set(report["baseline"]["fit_percent"]) >= {"v", "psi_dot", "beta"}
    assert report["baseline"]["heldout_error"] > 0
    # --add drag: the loop starts from baseline + drag and ranks the rest on top of it
    assert report["selection"]["start"] == ["drag"]
    ranked = report["ranked_effects"]
    assert [r["name"] for r in ranked] == ["rolling_resistance"]
    for r in ranked:
        assert {
            "name",
            "significant",
            "p_value",
            "confidence",
            "heldout_error_drop",
            "drop_p_value",
            "drop_note",
            "params",
        } <= set(r)
    assert report["selected"] == []  # nothing significant on top of drag
    assert report["verdict"]["kind"] == "explained"
    assert report["verdict"]["text"].startswith("explained by drag")
    assert report["added"]["effects"] == ["drag"]
    assert 0.5 <= report["error_drop"] <= 1.0
    assert "drag.CdA" in report["added"]["params"]
    # the written report
    saved = json.loads((out / "report.json").read_text())
    assert saved["verdict"]["kind"] == "explained"
    html = (out / "report.html").read_text()
    # the figure list itself is checked in test_workbench_report; here: the command wrote the
    # report, and its page embeds every PNG it wrote
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) >= 9
    assert html.count("data:image/png;base64,") == len(pngs)
    for png in pngs:
        assert png.stat().st_size > 1000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp left


def test_run_folder_and_text_output(drag_log, tmp_path, capsys):
    df, _ = drag_log
    run = tmp_path / "run_001"
    write_drive_log(df, run / "log.parquet")
    (run / "summary.json").write_text("{}")
    assert main(["diagnose", str(run), "--candidates", "drag,gyro_bias"]) == 0
    text = capsys.readouterr().out
    assert "1. + drag" in text
    assert "verdict: explained by drag" in text


def test_json_selected_and_verdict_fields(drag_log, capsys):
    _, path = drag_log
    assert main(["diagnose", str(path), "--candidates", "drag,grade", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (step,) = report["selected"]
    assert step["name"] == "drag" and step["p_value"] < 1e-6
    assert step["heldout_error_after"] < step["heldout_error_before"]
    assert abs(step["params"]["drag.CdA"]["value"] - 0.75) < 0.15 * 0.75
    assert report["verdict"]["kind"] in ("explained", "outside_library")
    assert report["verdict"]["effects"] == ["drag"]
    assert report["best"] == "drag"  # today's fields stay


def test_resample_and_accept_units(drag_log, tmp_path, capsys):
    df, _ = drag_log
    jittered = df.copy()
    rng = np.random.default_rng(0)
    jittered["t"] = df["t"] + rng.uniform(-0.004, 0.004, len(df))  # +-4 ms on 50 ms steps
    path = tmp_path / "jitter.csv"
    write_drive_log(jittered, path)
    assert main(["diagnose", str(path), "--candidates", "drag", "--json"]) == 2
    assert "--resample" in capsys.readouterr().err
    assert main(["diagnose", str(path), "--candidates", "drag", "--resample", "20", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["resampled_hz"] == 20.0 and abs(report["rate_hz"] - 20.0) < 1e-6
    assert report["best"] == "drag"
    # a steering column in degrees trips the unit check; --accept-units overrides it
    degrees = df.copy()
    degrees["beta"] = np.degrees(df["beta"]) * 30.0
    path = tmp_path / "deg.csv"
    degrees.to_csv(path, index=False)  # write_drive_log would refuse it
    assert main(["diagnose", str(path), "--candidates", "drag", "--json"]) == 2
    assert "degrees instead of rad" in capsys.readouterr().err
    argv = ["diagnose", str(path), "--candidates", "drag", "--json"]
    assert main([*argv, "--accept-units", "a spin test"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["unit_checks"] == {"run": False, "reason": "a spin test"}


def _expect_error(capsys, tmp_path, argv, *needles):
    out = tmp_path / "out"
    code = main(["diagnose", *argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    for needle in needles:
        assert needle in err, err
    assert not out.exists()  # nothing half-written
    return err


def test_unknown_effect_lists_the_known_ones(drag_log, tmp_path, capsys):
    _, path = drag_log
    err = _expect_error(capsys, tmp_path, [str(path), "--add", "warp_drive"], "warp_drive")
    for name in ("drag", "rolling_resistance", "steering_lag", "input_delay", "tire_saturation"):
        assert name in err


def test_missing_column(drag_log, tmp_path, capsys):
    df, _ = drag_log
    bad = tmp_path / "bad.csv"
    df.drop(columns=["beta"]).to_csv(bad, index=False)
    _expect_error(capsys, tmp_path, [str(bad)], "missing column", "beta")


def test_non_increasing_time(drag_log, tmp_path, capsys):
    df, _ = drag_log
    bad = tmp_path / "bad.csv"
    d = df.copy()
    d.loc[300, "t"] = d.loc[298, "t"]
    d.to_csv(bad, index=False)
    _expect_error(capsys, tmp_path, [str(bad)], "time does not increase", "300")


def test_nan_run(drag_log, tmp_path, capsys):
    df, _ = drag_log
    bad = tmp_path / "bad.csv"
    d = df.copy()
    d.loc[200:240, "v"] = np.nan
    d.to_csv(bad, index=False)
    _expect_error(capsys, tmp_path, [str(bad)], "'v'", "NaN", "200")


def test_too_short(drag_log, tmp_path, capsys):
    df, _ = drag_log
    bad = tmp_path / "short.csv"
    df.iloc[:200].to_csv(bad, index=False)
    _expect_error(capsys, tmp_path, [str(bad)], "too short")


def test_missing_file(tmp_path, capsys):
    _expect_error(capsys, tmp_path, [str(tmp_path / "nope.csv")], "nope.csv")


def test_unknown_vehicle(drag_log, tmp_path, capsys):
    _, path = drag_log
    _expect_error(capsys, tmp_path, [str(path), "--vehicle", "batmobile"], "batmobile")


def test_effects_file_adds_a_user_effect(drag_log, tmp_path, capsys):
    from pcvfe_drake.models.effects import known_effects, unregister_effect

    _, path = drag_log
    plugin = tmp_path / "my_effects.py"
    plugin.write_text(
        "from pcvfe_drake.workbench import Effect, EffectParam, register_effect\n"
        "@register_effect\n"
        "class AccelGainCli(Effect):\n"
        "    name = 'accel_gain_cli'\n"
        "    params = (EffectParam('k', '-', 0.5, 1.5, 1.0, 0.1, 1.0),)\n"
        "    def accel(self, accel, ctx, p):\n"
        "        return p['k'] * accel\n"
    )
    try:
        code = main(
            [
                "diagnose",
                str(path),
                "--effects-file",
                str(plugin),
                "--candidates",
                "accel_gain_cli",
                "--add",
                "accel_gain_cli",
                "--json",
            ]
        )
        assert code == 0
        report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert report["added"]["effects"] == ["accel_gain_cli"]
        assert "accel_gain_cli.k" in report["added"]["params"]
    finally:
        if "accel_gain_cli" in known_effects():
            unregister_effect("accel_gain_cli")


def test_fit_resample(drag_log, tmp_path, capsys):
    df, _ = drag_log
    uneven = df.iloc[np.union1d(np.arange(0, len(df), 2), np.arange(1, len(df), 3))]  # uneven
    path = tmp_path / "uneven.csv"
    uneven.to_csv(path, index=False)
    assert main(["fit", str(path), "--resample", "10", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["resampled_hz"] == 10.0 and abs(out["dt_s"] - 0.1) < 1e-9
    (ctx,) = out["contexts"].values()
    assert abs(ctx["theta"]["mu"] - 1.05) < 0.1
    assert main(["fit", str(path), "--resample", "-5"]) == 2
    assert "--resample" in capsys.readouterr().err
