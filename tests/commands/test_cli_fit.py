"""``pcvfe fit``: per-context estimates from a drive log, as a table or one JSON object."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    """4 s on sand (mu 0.45) then 4 s on brick (mu 0.8), ST truth, noise-free, 100 Hz."""
    params = ford_escort()
    t, S, U = s_curve_drive(params, [0.45, 0.8], duration_s=4.0, phase_rad=[0.0, 2.0])
    sand = drive_frame(t, S[0], U[0], terrain="sand", context=0, mu_true=0.45)
    brick = drive_frame(t + t[-1] + 0.01, S[1], U[1], terrain="brick", context=1, mu_true=0.8)
    path = tmp_path_factory.mktemp("fit") / "drive.csv"
    pd.concat([sand, brick]).to_csv(path, index=False)
    return path


def test_json_per_terrain(log_path, capsys):
    assert main(["fit", str(log_path), "--context-column", "terrain", "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    report = json.loads(out[-1])
    assert report["vehicle"] == "ford_escort"
    assert set(report["contexts"]) == {"sand", "brick"}
    for name, mu in (("sand", 0.45), ("brick", 0.8)):
        entry = report["contexts"][name]
        assert abs(entry["theta"]["mu"] - mu) < 0.01
        assert entry["std"]["mu"] is not None and entry["std"]["C_Sf"] is None
        assert entry["converged"] and entry["samples"] == 401
    assert report["windows_skipped"]["context_change"] == 2


def test_table_and_single_context(log_path, capsys):
    assert main(["fit", str(log_path), "--context-column", "context"]) == 0
    out = capsys.readouterr().out
    assert "+-std" in out and "converged" in out
    lines = [ln.split() for ln in out.splitlines()]
    rows = {ln[0]: ln for ln in lines if ln and ln[0] in {"0", "1"}}
    assert abs(float(rows["0"][3]) - 0.45) < 0.01 and abs(float(rows["1"][3]) - 0.8) < 0.01
    # By default the context column is context (as pcvfe diagnose); with none the whole log
    # is one context: a compromise friction.
    assert main(["fit", str(log_path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["context_column"] == "context" and list(report["contexts"]) == ["0", "1"]
    assert main(["fit", str(log_path), "--context-column", "none", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert list(report["contexts"]) == ["all"]
    assert 0.45 < report["contexts"]["all"]["theta"]["mu"] < 0.8


def test_joint_without_priors_warns(log_path, capsys):
    code = main(
        ["fit", str(log_path), "--context-column", "terrain", "--joint", "--prior-rel", "0"]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "ill-conditioned" in out and "mu*C_Sf" in out


def test_bad_input_is_a_clean_error(tmp_path, log_path, capsys):
    assert main(["fit", str(tmp_path / "missing.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    broken = pd.read_csv(log_path).drop(columns=["beta"])
    path = tmp_path / "broken.csv"
    broken.to_csv(path, index=False)
    assert main(["fit", str(path)]) == 2
    assert "beta" in capsys.readouterr().err
    # NaN rows: rejected by the validating reader, skipped and counted with --lenient.
    holes = pd.read_csv(log_path)
    holes.loc[100, "psi_dot"] = np.nan
    path = tmp_path / "holes.csv"
    holes.to_csv(path, index=False)
    assert main(["fit", str(path)]) == 2
    assert main(["fit", str(path), "--lenient", "--context-column", "terrain", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["windows_skipped"]["non_finite"] == 3  # windows starting at 90, 95, 100
