"""Open a run's ``playback.html`` in headless Chromium and take a screenshot.

Checks that the standalone Meshcat playback renders the scene with no server: it screenshots the
playback and, as the baseline, an empty Meshcat page saved the same way, and reports the share
of pixels that differ (the ground texture, course, car and trail make most of the view differ).
Without ``--html`` it first simulates a short run of the default scenario (15 s, so the feature
cloud of the 10 s re-clustering exists) with Meshcat into a temporary folder, and then checks
each debugging layer (``/pcvfe/plan``, ``friction_circle``, ``camera``, ``features``): the
playback is saved twice with the camera aimed at the layer, once as is and once with the layer
hidden, and the share of pixels that differ between the two screenshots says whether the layer
renders (``layers.<name>.pixels_differing``, ``renders`` above ``LAYER_MIN_SHARE``). The
recording is set to stop on its last frame, so the screenshot shows the end of the run. Skipped,
with the reason in the JSON, when Chromium is absent (Debian: ``apt-get install -y chromium``).

Usage: python validation/playback_screenshot.py [--quick] [--html PATH] [--out PNG] [--out-dir DIR]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np

from pcvfe_drake.views.browser import find_chromium, screenshot


def empty_meshcat_html(path: Path) -> Path:
    """A standalone Meshcat page with no scene, the baseline of the comparison."""
    from pydrake.geometry import Meshcat, MeshcatParams

    params = MeshcatParams()
    params.host = "localhost"
    path.write_text(Meshcat(params).StaticHtml())
    return path


LAYER_MIN_SHARE = 0.002  # share of the screenshot's pixels a layer must change
# Where to look from, relative to the point looked at [m]: south of it and above.
CAMERA_BACK = {"features": (0.0, -45.0, 25.0), "plan": (0.0, -16.0, 12.0)}
CAMERA_BACK_DEFAULT = (0.0, -28.0, 16.0)
LAYER_ANCHOR = {
    "plan": "/pcvfe/friction_circle",  # the car's position (plus the circle's offset)
    "friction_circle": "/pcvfe/friction_circle",
    "camera": "/pcvfe/camera",
    "features": "/pcvfe/features/current",
}


def simulate_playback(folder: Path, duration_s: float, scenario_name: str = "paper_sim"):
    """Run a scenario briefly with Meshcat; returns (playback.html, the Meshcat)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from pcvfe_drake.diagrams.run_simulation import RunFolder, run_simulation
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    params = MeshcatParams()
    params.host = "localhost"
    meshcat = Meshcat(params)
    scenario = load_scenario(scenario_name).with_run_length(duration_s=duration_s)
    run = RunFolder(folder)
    run_simulation(scenario, run, meshcat=meshcat, progress=False)
    return run.playback, meshcat


def aimed_html(meshcat, layer: str, hidden: bool) -> str:
    """The playback, stopping on its last frame, with the camera aimed at ``layer`` (hidden or
    not)."""
    from pydrake.geometry import MeshcatAnimation

    from pcvfe_drake.systems.meshcat_layer import packed_translation

    recording = meshcat.get_mutable_recording()
    recording.set_loop_mode(MeshcatAnimation.LoopMode.kLoopOnce)
    recording.set_clamp_when_finished(True)
    meshcat.PublishRecording()
    target = packed_translation(meshcat, LAYER_ANCHOR[layer])
    if target is None:
        target = np.zeros(3)
    if layer == "plan":
        target = target - [-7.0, 0.0, 9.0]  # the car, under the friction circle
    back = np.array(CAMERA_BACK.get(layer, CAMERA_BACK_DEFAULT))
    meshcat.SetCameraPose(target + back, target)
    meshcat.SetProperty(f"/pcvfe/{layer}", "visible", not hidden)
    try:
        return meshcat.StaticHtml()
    finally:
        meshcat.SetProperty(f"/pcvfe/{layer}", "visible", True)


def differing_share(a_png: Path, b_png: Path) -> float:
    """Share of pixels that differ (any channel by more than 12 of 255) between two PNGs."""
    a = cv2.imread(str(a_png)).astype(np.int16)
    b = cv2.imread(str(b_png)).astype(np.int16)
    return float(np.any(np.abs(a - b) > 12, axis=2).mean())


def check_layers(chromium: str, meshcat, folder: Path, keep: Path | None) -> dict:
    """Per layer: screenshots with and without it; the share of pixels it changes."""
    from pcvfe_drake.diagrams.debug_layers import LAYERS

    out = {}
    for layer in LAYERS:
        shots = {}
        for hidden in (False, True):
            html = folder / f"{layer}_{'without' if hidden else 'with'}.html"
            html.write_text(aimed_html(meshcat, layer, hidden))
            png = (keep or folder) / f"{layer}_{'without' if hidden else 'with'}.png"
            ok = any(screenshot(chromium, html, png, wait_ms=25000) for _ in range(2))
            shots[hidden] = png if ok else None
        if shots[False] is None or shots[True] is None:
            out[layer] = {"screenshot_ok": False}
            continue
        share = differing_share(shots[False], shots[True])
        out[layer] = {
            "screenshot_ok": True,
            "pixels_differing": share,
            "renders": bool(share > LAYER_MIN_SHARE),
        }
        print(f"  {layer}: {100 * share:.2f} % of the pixels", flush=True)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="(same run; kept for run_all)")
    parser.add_argument("--html", type=Path, default=None, help="playback.html to open")
    parser.add_argument("--out", type=Path, default=None, help="where to save the screenshot")
    parser.add_argument("--duration", type=float, default=15.0, help="simulated s without --html")
    parser.add_argument("--scenario", default="paper_sim", help="scenario without --html")
    parser.add_argument("--out-dir", type=Path, default=None, help="keep the layer screenshots")
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
        meshcat = None
        if html is None:
            print(f"simulating {args.duration:.0f} s of {args.scenario} with Meshcat ...")
            html, meshcat = simulate_playback(tmp / "run", args.duration, args.scenario)
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
        if meshcat is not None:
            print("each debugging layer, with and without it ...", flush=True)
            if args.out_dir:
                args.out_dir.mkdir(parents=True, exist_ok=True)
            out["layers"] = check_layers(chromium, meshcat, tmp, args.out_dir)
            out["layers_render"] = all(v.get("renders", False) for v in out["layers"].values())
        else:
            out["layers_skipped"] = "--html given: the layers are checked on a fresh run only"
        print(f"  {out}", flush=True)
    out["target"] = (
        "the playback renders the scene and every debugging layer (skipped: no Chromium)"
    )
    if not out.get("skipped"):
        out["passed"] = bool(out.get("renders_scene")) and bool(out.get("layers_render", True))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
