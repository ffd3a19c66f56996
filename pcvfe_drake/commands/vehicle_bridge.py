"""``pcvfe vehicle-bridge``: the simulated car and camera behind LCM, as a separate process.

Run it, then the pipeline against it in another terminal (``pcvfe simulate --hardware``): the
hardware-in-the-loop rehearsal of docs/hardware.md. pydrake is imported inside :func:`run`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

from pcvfe_drake.runs.scenario import DEFAULT_SCENARIO

HUB_IDLE_EXIT_S = 3.0
"""The local hub ends this many seconds after its last client (bridge or station) left."""


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "vehicle-bridge",
        help="the simulated car and camera behind LCM (rehearse the hardware station)",
        description=(
            "Run the simulated vehicle (plant and downward camera of SCENARIO) as the vehicle "
            "side of the LCM interface: it publishes the state (100 Hz) and camera frames and "
            "applies the actuation it receives, braking when none arrives. Like a car on a test "
            "rig it stands at its initial state (publishing it) until the station's first "
            "command arrives, at most hardware.first_command_timeout_s. With the default "
            "URL (tcpq://127.0.0.1:7700) it starts a localhost LCM hub first, so nothing "
            "leaves the machine. Then run `pcvfe simulate SCENARIO --hardware` in another "
            "terminal. Prints the latency from each state message to the actuation computed "
            "after it; writes truth.csv and bridge.json with --out."
        ),
    )
    parser.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO)
    parser.add_argument("--lcm-url", default=None, help="LCM URL (default: the scenario's bus)")
    parser.add_argument(
        "--hub",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="start a localhost tcpq hub (default: when the URL is tcpq://127.0.0.1:PORT)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated seconds of driving, from the first command (default: scenario's)",
    )
    parser.add_argument(
        "--idle-stop",
        type=float,
        default=None,
        help="stop once the station has sent nothing for this many seconds after it started",
    )
    parser.add_argument(
        "--realtime-rate", type=float, default=None, help="pace (default: the scenario's, 1.0)"
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for truth.csv, bridge.json")
    parser.add_argument(
        "--priority",
        type=_priority_arg,
        default=0,
        metavar="N",
        help="run the bridge's loop at Linux SCHED_FIFO priority N (1-99; default 0: ordinary "
        "scheduling; the local hub it starts inherits it): in a rehearsal the bridge stands in "
        "for the car's own hardware, which the station computer's load never slows down. Needs "
        "root, CAP_SYS_NICE or an rtprio limit (docs/hardware.md)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.set_defaults(func=run)


def _priority_arg(text: str) -> int:
    from pcvfe_drake.hardware.scheduling import priority_problem

    try:
        value = int(text)
    except ValueError:
        value = text
    problem = priority_problem(value, "--priority")
    if problem:
        raise argparse.ArgumentTypeError(problem.removeprefix("--priority="))
    return value


def with_lcm_url(scenario, url: str | None):
    """``scenario`` with its hardware bus's URL replaced by ``url`` (None: unchanged)."""
    if url is None:
        return scenario
    if "://" not in url:
        raise ValueError(f"--lcm-url {url!r} is not an LCM URL (e.g. tcpq://127.0.0.1:7700)")
    hw = scenario.hardware
    buses = dict(hw.lcm_buses)
    buses[hw.bus] = dataclasses.replace(buses[hw.bus], lcm_url=url)
    return dataclasses.replace(scenario, hardware=dataclasses.replace(hw, lcm_buses=buses))


def local_hub_port(url: str) -> int | None:
    """The port of a ``tcpq://127.0.0.1:PORT`` (or localhost) URL, else None."""
    if not url.startswith("tcpq://"):
        return None
    host, _, port = url[len("tcpq://") :].partition(":")
    if host not in ("127.0.0.1", "localhost"):
        return None
    return int(port.split("?")[0] or 7700)


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.diagrams.run_vehicle_bridge import run_vehicle_bridge
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.hardware.latency import format_latency
    from pcvfe_drake.hardware.scheduling import control_priority
    from pcvfe_drake.hardware.tcpq_hub import HubProcess, hub_listening

    scenario = with_lcm_url(load_scenario(args.scenario), args.lcm_url)
    hw = scenario.hardware
    url = hw.lcm_buses[hw.bus].lcm_url
    duration = args.duration if args.duration is not None else scenario.stop_time_s()
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {duration}")
    port = local_hub_port(url)
    want_hub = args.hub if args.hub is not None else port is not None
    if want_hub and port is None:
        raise ValueError(f"--hub needs a tcpq://127.0.0.1:PORT URL, not {url!r}")
    # Raised before the hub starts, so that the hub (the network, in a rehearsal) inherits it;
    # a refused priority stops here, before anything runs.
    with control_priority(args.priority, "--priority", children_inherit=True):
        hub, note = None, ""
        if want_hub and hub_listening(port):
            note = " (the local hub already running there)"
        elif want_hub:
            # Detached, ending by itself once its last client left: a station still connected when
            # the bridge ends must not lose its hub (the LCM C library aborts the station then).
            hub = HubProcess(port, idle_exit_s=HUB_IDLE_EXIT_S, detach=True)
            note = " (local hub)"
        try:
            print(f"vehicle bridge: {scenario.name} on {url}{note}")
            print(f"  state -> {hw.state_channel}, camera -> {hw.image_channel}, "
                  f"actuation <- {hw.actuation_channel}")  # fmt: skip

            def progress(t, recorder):
                if not args.quiet and abs(t - round(t / 5.0) * 5.0) < 1e-6:
                    print(f"  t={t:6.1f} s  {format_latency(recorder.summary())}", flush=True)

            result = run_vehicle_bridge(
                scenario,
                duration_s=duration,
                out_dir=args.out,
                realtime_rate=args.realtime_rate,
                idle_stop_s=args.idle_stop,
                progress=progress,
            )
        finally:
            if hub is not None:
                hub.release()
    print(format_latency(result.latency))
    print(json.dumps(result.to_dict()))
    return 130 if result.stopped_because == "interrupted" else 0
