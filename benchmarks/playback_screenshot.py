"""Open a run's ``playback.html`` in headless Chromium and take a screenshot.

Checks that the standalone Meshcat playback renders the scene with no server: it screenshots the
playback and, as the baseline, an empty Meshcat page saved the same way, and reports the share
of pixels that differ (the ground texture, course, car and trail make most of the view differ).
Without ``--html`` it first simulates a short run of the default scenario (15 s) with Meshcat
into a temporary folder. Skipped, with the reason in the JSON, when Chromium is absent (Debian:
``apt-get install -y chromium``).

Usage: python benchmarks/playback_screenshot.py [--quick] [--html PATH] [--out PNG]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
]


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def screenshot(chromium: str, html: Path, png: Path, size=(1280, 800), wait_ms=10000) -> bool:
    """Screenshot ``html`` into ``png`` with headless Chromium; True on success."""
    with tempfile.TemporaryDirectory(prefix="pcvfe_chromium_") as profile:
        cmd = [
            chromium,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={size[0]},{size[1]}",
            f"--virtual-time-budget={wait_ms}",
            f"--screenshot={png}",
            html.resolve().as_uri(),
        ]
        try:
            subprocess.run(cmd, capture_output=True, timeout=120, check=False)
        except subprocess.TimeoutExpired:
            return False
    return png.is_file() and png.stat().st_size > 0


def empty_meshcat_html(path: Path) -> Path:
    """A standalone Meshcat page with no scene, the baseline of the comparison."""
    from pydrake.geometry import Meshcat, MeshcatParams

    params = MeshcatParams()
    params.host = "localhost"
    path.write_text(Meshcat(params).StaticHtml())
    return path


def simulate_playback(folder: Path, duration_s: float) -> Path:
    """Run the default scenario briefly with Meshcat; returns its playback.html."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from pcvfe_drake.diagrams.run_simulation import RunFolder, run_simulation
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    params = MeshcatParams()
    params.host = "localhost"
    scenario = load_scenario("paper_sim").with_run_length(duration_s=duration_s)
    run = RunFolder(folder)
    run_simulation(scenario, run, meshcat=Meshcat(params), progress=False)
    return run.playback


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="(same run; kept for run_all)")
    parser.add_argument("--html", type=Path, default=None, help="playback.html to open")
    parser.add_argument("--out", type=Path, default=None, help="where to save the screenshot")
    parser.add_argument("--duration", type=float, default=15.0, help="simulated s without --html")
    args = parser.parse_args()

    chromium = find_chromium()
    if chromium is None:
        reason = "chromium not found (Debian: apt-get install -y chromium)"
        print(f"skipped: {reason}")
        print(json.dumps({"benchmark": "playback_screenshot", "skipped": True, "reason": reason}))
        return 0
    with tempfile.TemporaryDirectory(prefix="pcvfe_playback_") as tmp:
        tmp = Path(tmp)
        html = args.html
        if html is None:
            print(f"simulating {args.duration:.0f} s of paper_sim with Meshcat ...", flush=True)
            html = simulate_playback(tmp / "run", args.duration)
        if not html.is_file():
            raise FileNotFoundError(f"--html {html}: no such file")
        shot = args.out or tmp / "playback.png"
        base = tmp / "empty.png"
        print(f"screenshot of {html} ...", flush=True)
        ok = screenshot(chromium, html, shot)
        ok_base = screenshot(chromium, empty_meshcat_html(tmp / "empty.html"), base)
        out = {"benchmark": "playback_screenshot", "skipped": False, "html": str(html)}
        out["html_bytes"] = html.stat().st_size
        out["screenshot_ok"] = bool(ok and ok_base)
        if ok and ok_base:
            a = cv2.imread(str(shot)).astype(np.int16)
            b = cv2.imread(str(base)).astype(np.int16)
            differ = np.any(np.abs(a - b) > 12, axis=2)
            out["pixels_differing_from_empty_page"] = float(differ.mean())
            out["renders_scene"] = bool(differ.mean() > 0.2)
            if args.out:
                out["screenshot"] = str(args.out)
        print(f"  {out}", flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
