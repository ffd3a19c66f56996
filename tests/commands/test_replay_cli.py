"""`pcvfe replay` reruns a deterministic run to the same numbers, at the default rates (the
drive log's features of every frame and the fitter's samples: one frame in 2 s saved)."""

import json

import numpy as np
import pandas as pd

from pcvfe_drake.cli import main

SCENARIO = """\
name: replay_check
duration_s: 12.0
laps: null
"""


def test_replay_of_a_run_reproduces_its_contexts_and_estimates(tmp_path):
    (tmp_path / "s.yaml").write_text(SCENARIO)
    original, replay = tmp_path / "original", tmp_path / "replay"
    common = ["--no-progress"]
    assert main(["simulate", str(tmp_path / "s.yaml"), "--no-meshcat", "--out", str(original),
                 *common]) == 0  # fmt: skip
    assert main(["replay", str(original), "--out", str(replay), *common]) == 0
    a = pd.read_csv(original / "drive_log.csv")
    b = pd.read_csv(replay / "drive_log.csv")
    assert len(a) == len(b) == 241
    assert a["image"].notna().sum() == 7  # a frame in 2 s: the replay does not need the others
    assert (a["context"] >= 0).any()  # a re-clustering at 10 s named a context
    numeric = [c for c in a.columns if a[c].dtype.kind in "fi"]
    assert {"mu_hat", "f_00", "steer_rate", "mu_true", "true_sx"} <= set(numeric)
    np.testing.assert_array_equal(a[numeric].to_numpy(), b[numeric].to_numpy())
    assert (replay / "summary.json").is_file()
    assert json.loads((replay / "replay.json").read_text())["exact"] is True
