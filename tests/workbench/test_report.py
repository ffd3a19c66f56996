"""The diagnosis report: every picture of where the model fails, checked in a headless browser."""

from __future__ import annotations

import html as html_text
import json

import matplotlib.image as mpimg
import numpy as np
import pytest

from pcvfe_drake.models.data import prepare
from pcvfe_drake.views.browser import NO_CHROMIUM, dump_dom, find_chromium, screenshot
from pcvfe_drake.workbench import figures, synth
from pcvfe_drake.workbench.figures import CAPTIONS
from pcvfe_drake.workbench.report import diagnose, write_report

PNGS = [
    "selection_path.png",
    "error_over_log.png",
    "error_map.png",
    "regimes.png",
    "bias.png",
    "cross_correlation.png",
    "overlay.png",
    "residual_autocorr.png",
    "ranking.png",
]


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    (df,) = synth.simulate_truths(
        [synth.PLANTED["drag"][0]], duration_s=60.0, rate_hz=20.0, seed=2, substeps=2
    )
    df["terrain"] = np.where(df["t"] < 30.0, "asphalt", "gravel")
    report, wb = diagnose(prepare(df, "two contexts"), candidates=["drag", "gyro_bias"])
    out = tmp_path_factory.mktemp("rep") / "report"
    write_report(report, wb, out)
    return out, report, wb


def test_report_has_every_picture_and_the_loop(report_dir):
    out, report, _ = report_dir
    for png in PNGS:
        assert (out / png).stat().st_size > 2000, png
    saved = json.loads((out / "report.json").read_text())
    assert [s["name"] for s in saved["selected"]] == ["drag"]
    assert set(saved["verdict"]["context_bias"]) == {"asphalt", "gravel"}
    # regime bins come from the data's range and are never empty
    for kind, rows in saved["verdict"]["localisation"]["bins"].items():
        assert rows and all(r["n"] > 0 for r in rows), kind
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(PNGS)
    assert 'id="verdict"' in html and "The loop" in html
    # every figure is captioned with what to look for
    assert set(CAPTIONS) == set(PNGS)
    for png in PNGS:
        caption = html_text.escape(CAPTIONS[png])
        assert f"<b>{png}</b>: {caption}" in html and "Look for" in caption, png
    # the course map: the baseline's failures beside what remains (two panels side by side)
    height, width = mpimg.imread(out / "error_map.png").shape[:2]
    assert width > 2 * height


@pytest.mark.skipif(find_chromium() is None, reason=NO_CHROMIUM)
def test_report_renders_in_headless_chromium(report_dir, tmp_path):
    out, report, _ = report_dir
    # a copy with a probe script: the page title reports how many images decoded
    probe = (
        (out / "report.html")
        .read_text()
        .replace(
            "</body>",
            '<script>addEventListener("load",()=>{const i=[...document.images];'
            'document.title="decoded "+i.filter(x=>x.complete&&x.naturalWidth>0).length+"/"'
            "+i.length;});</script></body>",
        )
    )
    page = tmp_path / "probe.html"
    page.write_text(probe)
    chromium = find_chromium()
    dom = dump_dom(chromium, page)
    assert f"decoded {len(PNGS)}/{len(PNGS)}" in dom, dom[:300]
    assert report["verdict"]["kind"] in dom
    shot = tmp_path / "shot.png"
    assert screenshot(chromium, out / "report.html", shot, size=(1200, 2400), wait_ms=5000)
    img = mpimg.imread(shot)
    assert img.shape[0] >= 2000 and img.std() > 0.05  # a rendered page, not a blank one


def test_overlay_shows_measured_baseline_and_final_model(report_dir, tmp_path, monkeypatch):
    _, report, wb = report_dir
    drawn = {}

    def keep(fig, folder, name):
        drawn[name] = fig
        return name

    monkeypatch.setattr(figures, "_save", keep)
    figures.all_figures(report, wb, tmp_path)
    for ax in drawn["overlay.png"].axes:
        labels = [line.get_label() for line in ax.lines if not line.get_label().startswith("_")]
        if labels:
            assert labels == ["measured", "baseline", "final model (+ drag)"]
    legend = [t.get_text() for t in drawn["overlay.png"].axes[0].get_legend().get_texts()]
    assert legend == ["measured", "baseline", "final model (+ drag)"]
