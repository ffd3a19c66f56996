"""The stand-in rule: parameters of a selected effect tested for stability over the operating
range (pcvfe_drake.workbench.stability), on planted data: a drag fitted to a log whose car has
rolling resistance (a constant force) drifts with speed and is a stand-in; a drag fitted to a
log with planted drag is stable."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import seed3_logs
from scipy.stats import chi2

from pcvfe_drake.models.data import prepare, window_starts
from pcvfe_drake.workbench.ranking import Workbench
from pcvfe_drake.workbench.stability import (
    parameter_stability,
    partitions,
    stand_ins,
    wald_equal,
)


def test_wald_equal_two_groups_is_the_difference_test():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(2), rng.standard_normal(2)
    ca = np.array([[0.5, 0.1], [0.1, 0.3]])
    cb = np.array([[0.2, -0.05], [-0.05, 0.4]])
    stat, dof = wald_equal([a, b], [ca, cb])
    d = a - b
    assert dof == 2
    assert stat == pytest.approx(float(d @ np.linalg.solve(ca + cb, d)), rel=1e-10)


def test_wald_equal_holds_its_size_under_equal_parameters():
    """Three groups with different covariances and the same true parameters: the statistic
    is chi-square with k (G - 1) degrees of freedom."""
    rng = np.random.default_rng(1)
    covs = [np.diag([0.1, 2.0]), np.array([[1.0, 0.6], [0.6, 1.0]]), np.diag([0.5, 0.05])]
    chol = [np.linalg.cholesky(c) for c in covs]
    theta = np.array([0.7, -0.2])
    pvals = []
    for _ in range(4000):
        draws = [theta + L @ rng.standard_normal(2) for L in chol]
        stat, dof = wald_equal(draws, covs)
        pvals.append(chi2.sf(stat, dof))
    pvals = np.array(pvals)
    assert dof == 4
    assert abs(np.mean(pvals < 0.05) - 0.05) < 0.015
    assert np.mean(pvals < 0.01) < 0.02


@pytest.fixture(scope="module")
def benches(run_cache):
    return {n: Workbench(prepare(df, n)) for n, df in seed3_logs(run_cache).items()}


def test_partitions_are_disjoint_and_cover_the_regimes(benches):
    wb = benches["drag"]
    starts = window_starts(wb.data, wb.h_fit, wb.h_fit, "all", wb.config.n_blocks)
    splits = partitions(wb.data, starts, wb.h_fit, 20)
    kinds = [s["kind"] for s in splits]
    assert "speed" in kinds and "time" in kinds
    for s in splits:
        assert len(s["parts"]) == len(s["labels"]) >= 2
        assert all(p.size >= 20 for p in s["parts"])
        joined = np.concatenate(s["parts"])
        assert np.unique(joined).size == joined.size  # disjoint
        assert np.isin(joined, starts).all()
    speed = next(s for s in splits if s["kind"] == "speed")
    assert speed["labels"][0].startswith("below") and speed["labels"][-1].startswith("above")
    v = [wb.data.x[p, 3].mean() for p in speed["parts"]]
    assert v == sorted(v)


def _drag_fit(wb):
    return wb.fit_model(wb.base_model.with_effects("drag"), warm=wb.baseline)


def test_drag_standing_in_for_rolling_resistance_is_flagged(benches):
    wb = benches["rolling_resistance"]
    fit = _drag_fit(wb)
    res = stand_ins(wb, fit, ["drag"], alpha=0.01)
    assert res["stand_ins"] == ["drag"]
    speed = next(t for t in res["rounds"][0]["tests"] if t["partition"] == "speed" and t["p_value"])
    assert speed["rejected"] and speed["p_value"] < 1e-6
    cda = [v[0] for v in speed["values"]]
    assert cda[0] > 1.5 * cda[-1]  # a quadratic law on a constant force: large CdA slow
    text = res["evidence"]["drag"]
    assert text.startswith("drag's CdA") and "m/s vs" in text and "(p = " in text


def test_planted_drag_is_not_a_stand_in(benches):
    wb = benches["drag"]
    fit = _drag_fit(wb)
    res = parameter_stability(wb, fit, ["drag"], alpha=0.01)
    done = [t for t in res["tests"] if t["p_value"] is not None]
    assert len(done) >= 2
    assert res["unstable"] == [] and res["evidence"] == {}
    assert all(t["p_value"] > t["threshold"] for t in done)
    # the parts agree with the planted value within their uncertainty
    speed = next(t for t in done if t["partition"] == "speed")
    for value, std in zip(speed["values"], speed["std"], strict=True):
        assert abs(value[0] - 0.75) < 4.0 * std[0]
