"""Hardware-in-the-loop rehearsal in two processes over a localhost tcpq hub: `pcvfe
vehicle-bridge` (the simulated car) and `pcvfe simulate --hardware` (the pipeline on the LCM
station). Every message stays on 127.0.0.1; both processes end by themselves (bounded)."""

import json
import socket
import subprocess
import sys

import pandas as pd


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pcvfe(*args):
    # -X faulthandler: a native crash prints every thread's Python stack to stderr, which the
    # assertions show (the station once died with SIGSEGV after connecting, stack unknown)
    return [sys.executable, "-X", "faulthandler", "-m", "pcvfe_drake.cli", *args]


def test_pipeline_drives_the_bridged_car_in_another_process(tmp_path):
    url = f"tcpq://127.0.0.1:{free_port()}"
    bridge = subprocess.Popen(
        pcvfe(
            "vehicle-bridge",
            "--lcm-url",
            url,
            "--duration",
            "30",
            "--idle-stop",
            "2",
            "--quiet",
            "--out",
            str(tmp_path / "bridge"),
        ),  # fmt: skip
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        station = subprocess.run(
            pcvfe(
                "simulate",
                "--hardware",
                "--lcm-url",
                url,
                "--duration",
                "4",
                "--no-meshcat",
                "--no-progress",
                "--out",
                str(tmp_path / "run"),
            ),  # fmt: skip
            capture_output=True,
            text=True,
            timeout=240,
        )
        out, _ = bridge.communicate(timeout=120)
    finally:
        if bridge.poll() is None:
            bridge.kill()
            bridge.wait(timeout=10)
    assert station.returncode == 0, station.stdout + station.stderr
    assert bridge.returncode == 0, out
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["ground_truth"] is False
    state = summary["station_status"]["streams"]["state"]
    # The stream flows (how many of the 100 Hz messages a loaded machine keeps up with is a
    # throughput figure: benchmarks/hardware_rehearsal.py measures it, a test must not time it).
    assert summary["station_status"]["source"] == "lcm" and state["accepted"] > 0
    log = pd.read_csv(tmp_path / "run" / "drive_log.csv")
    assert len(log) > 20 and log["mu_true"].isna().all()
    report = json.loads(out.strip().splitlines()[-1])
    assert report["actuation"]["accepted"] >= 20  # the pipeline's commands reached the car
    assert report["latency"]["n"] > 0 and report["latency"]["median_ms"] < 500
    truth = pd.read_csv(tmp_path / "bridge" / "truth.csv")
    # The bridge held the car while the station booted: it starts at the scenario's 3 m/s when
    # the first command comes, not braked to a crawl by its watchdog.
    assert report["started_s"] > 0 and truth["t"].iloc[0] >= report["started_s"]
    assert truth["v"].iloc[0] > 2.8
    # The car the station saw is the car the bridge simulated.
    last = log.iloc[-1]
    near = truth.iloc[(truth["t"] - truth["t"].iloc[-1]).abs().argsort()[:1]]
    assert near["v"].iloc[0] >= 0.0 and last["v"] >= 0.0
