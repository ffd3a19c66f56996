"""Run summary and figures on synthetic run logs with a planted truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.control.course import load_course
from pcvfe_drake.runs.figures import context_runs, write_figures
from pcvfe_drake.runs.summary import sample_weights, summarize_run, summary_table

TERRAIN_MU = {"a": 0.3, "b": 0.8, "c": 0.45, "strip": 0.5}
DT = 0.1


def planted_log(course=None, laps: float = 1.1) -> pd.DataFrame:
    """Drive the course at 5 m/s; terrain by quarter of the lap with a short strip between
    quarters; the reported context follows the terrain with a planted delay of 0.3 s on entries
    (noise meanwhile), a 2 s delay for the first entry; mu_hat = truth + 0.02 after 3 s."""
    course = course or load_course("slalom")
    speed = 5.0
    n = int(laps * course.length / speed / DT)
    t = np.arange(n) * DT
    s = speed * t
    x, y, h, _ = course.sample(s)
    quarter = np.floor(course.wrap_s(s) / (course.length / 4)).astype(int)
    names = np.array(["a", "b", "c", "a"])[quarter]
    frac = np.mod(course.wrap_s(s), course.length / 4)
    names = np.where(frac < 2.0, "strip", names)
    ctx_of = {"a": 0, "b": 1, "c": 2}
    context = np.full(n, -1)
    seen: set[str] = set()
    entered_at = 0.0
    for i in range(n):
        if i == 0 or names[i] != names[i - 1]:
            entered_at = t[i]
        name = names[i]
        if name == "strip":
            continue
        delay = 0.3 if name in seen else 2.0
        if t[i] - entered_at >= delay - 1e-9:
            context[i] = ctx_of[name]
            seen.add(name)
    mu_true = np.array([TERRAIN_MU[nm] for nm in names])
    mu_hat = np.where((context >= 0) & (t > 3.0), mu_true + 0.02, 0.5)
    zeros = np.zeros(n)
    return pd.DataFrame(
        {
            "t": t,
            "sx": x,
            "sy": y,
            "delta": zeros,
            "v": np.full(n, speed),
            "psi": h,
            "psi_dot": zeros,
            "beta": zeros,
            "steer_rate": zeros,
            "accel": zeros,
            "terrain": names,
            "mu_true": mu_true,
            "context": context,
            "mu_hat": mu_hat,
        }
    )


@pytest.fixture(scope="module")
def course():
    return load_course("slalom")


def summarize(log: pd.DataFrame, course, **kw) -> dict:
    """summarize_run with the planted terrains, the strip excluded."""
    kw.setdefault("wall_time_s", 1.0)
    return summarize_run(
        log,
        scenario="synthetic",
        terrain_mu=TERRAIN_MU,
        excluded_terrains=["strip"],
        course=course,
        **kw,
    )


def test_summary_recovers_planted_values(course):
    log = planted_log(course)
    s = summarize(log, course, wall_time_s=10.0)
    assert s["laps_completed"] == 1
    assert s["lap_time_s"] == pytest.approx(course.length / 5.0, abs=0.15)
    assert s["catastrophic_failures"] == 0
    assert s["mean_speed_mps"] == pytest.approx(5.0)
    assert s["contexts_discovered"] == 3
    assert s["true_terrains_visited"] == ["a", "b", "c"]
    assert s["realtime_factor"] == pytest.approx(s["sim_time_s"] / 10.0)
    # Perfect clustering apart from the planted noise at entries: ARI high but below 1.
    assert 0.8 < s["ari"] < 1.0
    # Terrain "a" comes back for the last quarter and the lap's end: two re-entries, 0.3 s each.
    reid = s["reidentification_latency_s"]
    assert [e["terrain"] for e in reid] == ["a"]
    assert reid[0]["latency_s"] == pytest.approx(0.3, abs=1e-6)
    assert s["new_terrain_latency_s"] == pytest.approx({"a": 2.0, "b": 2.0, "c": 2.0}, abs=1e-6)
    by_id = {e["id"]: e for e in s["mu_estimates"]}
    assert by_id[1]["majority_terrain"] == "b"
    assert by_id[1]["true_mu"] == 0.8
    assert by_id[1]["mu_hat"] == pytest.approx(0.82)
    assert by_id[1]["abs_error"] == pytest.approx(0.02)
    assert by_id[0]["abs_error_after_settle_mean"] == pytest.approx(0.02)
    # Time-weighted error: 0.02 where identified after 3 s, |0.5 - mu| elsewhere.
    w = sample_weights(log["t"].to_numpy())
    expected = np.average(np.abs(log["mu_hat"] - log["mu_true"]), weights=w)
    assert s["mu_abs_error_time_weighted"] == pytest.approx(expected)
    json.dumps(s, allow_nan=False)  # JSON-ready
    text = summary_table(s)
    assert "re-identification latency" in text and "0.300 s" in text


def test_missed_reidentification_and_failures_are_counted(course):
    log = planted_log(course)
    last_a = (log["terrain"] == "a") & (log["t"] > 0.75 * course.length / 5.0)
    log.loc[last_a, "context"] = 2  # the revisit is reported as the wrong context
    # Two off-course excursions of 5 m and one spin.
    for t0 in (20.0, 40.0):
        sel = (log["t"] >= t0) & (log["t"] < t0 + 1.0)
        log.loc[sel, "sy"] += 5.0 * np.sign(np.cos(log.loc[sel, "psi"]) + 1e-9)
    log.loc[(log["t"] >= 60.0) & (log["t"] < 60.5), "beta"] = 1.0
    s = summarize(log, course, wall_time_s=1.0)
    assert s["reidentification_latency_s"][0]["latency_s"] is None
    assert s["reidentifications_missed"] == 1
    assert s["catastrophic_failures"] == 3
    assert s["max_abs_lateral_error_m"] > 3.0
    events = s["failure_events"]
    assert [e["kind"] for e in events] == ["off_course", "off_course", "spin"]
    t = log["t"].to_numpy()
    for e, t0 in zip(events, (20.0, 40.0, 60.0), strict=True):
        k = int(np.argmax(t >= t0))
        assert e["t_s"] == pytest.approx(t[k])
        assert (e["sx_m"], e["sy_m"]) == pytest.approx((log["sx"][k], log["sy"][k]))
    json.dumps(s, allow_nan=False)


def test_nan_state_is_a_failure_and_estimate_table_wins(course):
    log = planted_log(course, laps=0.5)
    log.loc[100:, ["sx", "sy", "v", "psi", "beta"]] = np.nan
    table = [{"id": 0, "mu": 0.31, "mu_std": 0.004, "samples": 1234}]
    s = summarize(log, course, wall_time_s=1.0, estimate_table=table, interrupted=True)
    assert s["catastrophic_failures"] == 1
    (event,) = s["failure_events"]
    assert event["kind"] == "non_finite" and event["t_s"] == log["t"][100]
    assert (event["sx_m"], event["sy_m"]) == (log["sx"][99], log["sy"][99])
    assert s["interrupted"] is True
    e0 = next(e for e in s["mu_estimates"] if e["id"] == 0)
    assert (e0["mu_hat"], e0["std"], e0["samples"]) == (0.31, 0.004, 1234)
    assert e0["abs_error"] == pytest.approx(0.01)


def test_bad_logs_are_rejected():
    with pytest.raises(ValueError, match="mu_hat"):
        summarize_run(
            pd.DataFrame({"t": [0.0]}), scenario="x", wall_time_s=1.0, terrain_mu=TERRAIN_MU
        )
    empty = planted_log(laps=0.1).iloc[:0]
    with pytest.raises(ValueError, match="empty"):
        summarize_run(empty, scenario="x", wall_time_s=1.0, terrain_mu=TERRAIN_MU)


def test_context_runs():
    runs = context_runs(np.array([0.0, 1.0, 2.0, 3.0]), np.array([-1, -1, 2, 2]))
    assert runs == [(0.0, 2.0, -1), (2.0, 4.0, 2)]
    assert math.isclose(sample_weights(np.array([0.0, 0.5, 1.5]))[-1], 1.0)


def test_figures_are_written(tmp_path, course):
    import cv2

    log = planted_log(course)
    frame_dir = tmp_path / "frames"
    frame_dir.mkdir()
    images = []
    for i in range(len(log)):
        if i % 50 == 0:
            img = np.full((32, 32, 3), 40 * (log.at[i, "context"] + 2), np.uint8)
            cv2.imwrite(str(frame_dir / f"{i}.png"), img)
            images.append(f"frames/{i}.png")
        else:
            images.append("")
    log["image"] = images
    s = summarize(log, course, wall_time_s=1.0)
    map_image = np.full((120, 180, 3), 200, np.uint8)
    out = write_figures(
        log,
        tmp_path / "figures",
        s,
        map_image=map_image,
        map_bounds_m=(-90.0, 90.0, -60.0, 60.0),
        reference_xy=np.column_stack([course.x, course.y]),
        log_dir=tmp_path,
    )
    for name, path in out.items():
        assert path is not None, name
        img = cv2.imread(path)
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 400


def test_final_clustering_scores(course):
    log = planted_log(course)
    ids = {"a": 0, "b": 1, "c": 2, "strip": -1}
    log["final_context"] = [ids[n] for n in log["terrain"]]
    s = summarize(log, course, wall_time_s=1.0)
    assert s["final_clustering"] == {"ari": 1.0, "noise_fraction": 0.0, "contexts": 3}
    assert s["ari"] < 1.0  # the online ids had noise at every entry


def test_mu_error_after_the_first_20_s_of_a_context(course):
    log = planted_log(course)
    t = log["t"].to_numpy()
    w = sample_weights(t)
    rows_b = np.flatnonzero(log["context"].to_numpy() == 1)
    in_b = np.cumsum(w[rows_b]) - w[rows_b]  # driving reported as context 1 before each row
    # Context 1 (terrain b, mu 0.8): off by 0.1 for its first 20 s, then by 0.01 and once 0.03.
    mu_hat = log["mu_hat"].to_numpy().copy()
    mu_hat[rows_b] = np.where(in_b < 20.0, 0.9, 0.81)
    mu_hat[rows_b[-5]] = 0.83
    log["mu_hat"] = mu_hat
    # Context 2 (terrain c) is only reported for its first 15 s: never scored.
    rows_c = np.flatnonzero(log["context"].to_numpy() == 2)
    late_c = rows_c[np.cumsum(w[rows_c]) > 15.0]
    log.loc[late_c, "context"] = -1
    s = summarize(log, course)
    by_id = {e["id"]: e for e in s["mu_estimates"]}
    b = by_id[1]
    scored = in_b >= 20.0
    assert b["scored_time_s"] == pytest.approx(np.sum(w[rows_b][scored]))
    assert b["scored_time_s"] > 10.0
    expected = np.average(np.abs(mu_hat[rows_b][scored] - 0.8), weights=w[rows_b][scored])
    assert b["abs_error_after_settle_mean"] == pytest.approx(expected)
    assert 0.01 < b["abs_error_after_settle_mean"] < 0.012
    assert b["abs_error_after_settle_max"] == pytest.approx(0.03)
    c = by_id[2]
    assert c["abs_error_after_settle_mean"] is None and c["scored_time_s"] == 0.0
    agg = s["mu_error_after_settle"]
    assert agg["settle_time_s"] == 20.0 and 2 in agg["contexts_unscored"]
    assert agg["worst_max"] == pytest.approx(0.03)
    assert agg["worst_mean"] == pytest.approx(max(b["abs_error_after_settle_mean"], 0.02))
    text = summary_table(s)
    assert "mu error after 20 s, worst context" in text and "not scored: 2" in text


def test_a_log_without_truth_is_scored_only_where_truth_is_not_needed(course):
    log = planted_log(course)
    log["terrain"] = ""
    log["mu_true"] = np.nan
    log["final_context"] = log["context"]
    s = summarize(log, course)
    assert s["ground_truth"] is False and "no ground truth" in s["ground_truth_note"]
    assert s["ari"] is None and s["final_clustering"]["ari"] is None
    assert s["mu_abs_error_time_weighted"] is None and s["reidentification_latency_s"] == []
    # What needs no truth is still there: contexts, estimates, tracking.
    assert s["contexts_discovered"] == 3 and s["laps_completed"] == 1
    assert all(e["true_mu"] is None and e["mu_hat"] > 0 for e in s["mu_estimates"])
    s["station_status"] = {
        "source": "lcm",
        "streams": {"state": {"rejected": {"late": 2}, "timeouts": 1}, "camera": {}},
    }
    table = summary_table(s)
    assert "ground truth" in table and "none:" in table
    assert "lcm (state: late 2, timeouts 1)" in table
    assert summarize(planted_log(course), course)["ground_truth"] is True


def test_transition_entries_time_the_id_the_first_fit_and_the_lateral_error(course):
    log = planted_log(course)
    # Context 1 ("b") first fitted 1.5 s after its id; context 2 ("c") fitted before its entry
    # is impossible here, so give it a fit long after its visit ended: none during the visit.
    table = [
        {"id": 1, "mu": 0.82, "mu_std": 0.01, "samples": 10, "first_fit_s": math.nan},
        {"id": 2, "mu": 0.47, "mu_std": 0.01, "samples": 10, "first_fit_s": 1e6},
    ]
    t = log["t"].to_numpy()
    b_entry = t[np.flatnonzero(log["terrain"].to_numpy() == "b")[0]]
    table[0]["first_fit_s"] = b_entry + 3.5
    s = summarize(log, course, estimate_table=table)
    entries = {e["terrain"]: e for e in s["transition_response"]["entries"]}
    b, c = entries["b"], entries["c"]
    assert b["context"] == 1 and b["context_id_s"] == pytest.approx(2.0, abs=1e-6)
    assert b["first_fit_s"] == pytest.approx(3.5, abs=1e-6)
    assert c["context"] == 2 and c["context_id_s"] == pytest.approx(2.0, abs=1e-6)
    assert c["first_fit_s"] is None
    # The planted path follows the course: the lateral error is ~0 on every visit.
    assert all(e["max_abs_lateral_error_m"] < 0.05 for e in entries.values())
    json.dumps(s, allow_nan=False)


def test_a_truth_that_ended_the_run_is_its_last_failure_or_the_end_of_the_one_going_on(course):
    """The multi-body truth's singularity ends a run where no logged row shows it: counted as
    a failure of its own after a clean last row, as the end of the failure going on otherwise."""
    log = planted_log(course, laps=0.2)
    ending = {"t_s": 35.63, "sx_m": 1.0, "sy_m": 2.0, "s_m": 3.0, "kind": "truth_singular",
              "detail": "truth model singular: wheel ground speed <= 0 (rear left -0.1 m/s)"}  # fmt: skip
    s = summarize(log, course, ending_failure=ending)
    assert s["catastrophic_failures"] == 1 and s["failure_events"] == [ending]
    assert "t=35.6 s truth model singular" in summary_table(s)
    off = log.copy()
    off.loc[off["t"] >= off["t"].iloc[-1] - 0.45, "sy"] += 5.0  # off the course at the end
    s = summarize(off, course, ending_failure=ending)
    assert s["catastrophic_failures"] == 1
    (event,) = s["failure_events"]
    assert event["kind"] == "off_course" and event["detail"].endswith("; then " + ending["detail"])
