"""The bridged car's state stamps around its start, seen from a stand-in station.

Starts ``pcvfe vehicle-bridge SCENARIO`` on a localhost tcpq hub, records every state message's
stamp and its arrival (``time.monotonic``), answers with a zero actuation at 20 Hz from
``--first`` s after the first state on (the bridge's first command ends its hold), and prints
each driving state's delay (arrival - stamp) above the smallest delay of the held states: what
the station's watchdog judges a message's lateness by (``pcvfe_drake.hardware.playout``).

Usage: python studies/bridge_startup/stamps.py [--scenario paper_eval] [--first 4] [--run 8]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np
from pydrake.lcm import DrakeLcm

from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_eval")
    parser.add_argument("--first", type=float, default=4.0, help="hold this long [s]")
    parser.add_argument("--run", type=float, default=8.0, help="then drive this long [s]")
    args = parser.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        url = f"tcpq://127.0.0.1:{s.getsockname()[1]}"
    out = tempfile.mkdtemp(prefix="bridge_startup_")
    bridge = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pcvfe_drake.cli",
            "vehicle-bridge",
            args.scenario,
            "--lcm-url",
            url,
            "--duration",
            str(args.run),
            "--idle-stop",
            "2",
            "--quiet",
            "--out",
            out,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    port = int(url.rsplit(":", 1)[1])
    deadline = time.monotonic() + 60.0
    while True:  # the bridge starts the hub once it has imported and built its diagram
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            break
        except OSError:
            if time.monotonic() > deadline or bridge.poll() is not None:
                raise RuntimeError("the bridge's hub did not come up") from None
            time.sleep(0.5)
    lcm = DrakeLcm(url)
    rows: list[tuple[int, float]] = []
    lcm.Subscribe(
        "PCVFE_STATE",
        lambda data: rows.append((lcmt_vehicle_state.decode(data).utime, time.monotonic())),
    )
    while not rows and time.monotonic() < deadline:
        lcm.HandleSubscriptions(50)
    t0 = time.monotonic()
    next_command = t0 + args.first
    while time.monotonic() - t0 < args.first + args.run + 3 and bridge.poll() is None:
        lcm.HandleSubscriptions(5)
        now = time.monotonic()
        if now >= next_command:
            cmd = lcmt_vehicle_actuation()
            cmd.utime = cmd.state_utime = rows[-1][0]
            cmd.steer_rate, cmd.accel = 0.0, 0.0
            lcm.Publish("PCVFE_ACTUATION", cmd.encode())
            next_command = now + 0.05
    report = json.loads(bridge.communicate(timeout=60)[0].strip().splitlines()[-1])
    r = np.array(rows, float)
    stamp, arrival = r[:, 0] * 1e-6, r[:, 1]
    delay = (arrival - arrival[0]) - (stamp - stamp[0])
    start = report["started_s"]
    held = stamp < start - 1e-9
    base = delay[held].min()
    driving = delay[~held] - base
    after = stamp[~held] - start
    for k in (0, 1, 2, 5, 10, 20, 50, 100, 200, 400):
        if k < driving.size:
            print(f"driving state {k:4d} at {after[k]:6.2f} s: {1000 * driving[k]:8.1f} ms above")
    caught_up = after[np.flatnonzero(driving > 0.05)]
    result = {
        "started_s": start,
        "held_states": int(held.sum()),
        "driving_states": int(driving.size),
        "held_delay_spread_ms": 1000 * float(delay[held].max() - base),
        "first_driving_above_ms": 1000 * float(driving[0]),
        "max_above_ms": 1000 * float(driving.max()),
        "above_50ms": int((driving > 0.05).sum()),
        "last_above_50ms_s": float(caught_up[-1]) if caught_up.size else None,
        "median_above_ms": 1000 * float(np.median(driving)),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
