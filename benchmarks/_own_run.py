"""A run folder for a benchmark given none: one ``pcvfe simulate`` of a scenario, seed 0.

Not a benchmark itself (``run_all`` and the benchmark-script test skip ``_``-prefixed files);
imported by the benchmarks that read saved runs and make their own when given no folder.
"""

from __future__ import annotations

from pathlib import Path


def make_run(out: Path, scenario: str, duration_s: float | None = None) -> Path:
    """One run of ``scenario``, seed 0, no Meshcat, into ``out`` (``duration_s``: only its
    first seconds; None: the scenario's length). Raises SystemExit if the simulation fails."""
    from pcvfe_drake.cli import main as pcvfe

    cmd = ["simulate", scenario, "--seed", "0", "--no-meshcat", "--out", str(out)]
    cmd += ["--duration", f"{duration_s:g}"] if duration_s is not None else []
    print("making a run: pcvfe " + " ".join(cmd), flush=True)
    if pcvfe(cmd) != 0:
        raise SystemExit("pcvfe simulate failed")
    return out
