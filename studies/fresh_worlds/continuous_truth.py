"""Drive a stored run's scenario again with the multi-body truth's continuous state (Drake's
error-controlled RK3, accuracy 1e-3: the plant before the compiled discrete update became its
default), to tell a world's failure from the integration's.

Usage: python studies/fresh_worlds/continuous_truth.py RUN_DIR [--duration S] [--out DIR]
[--quick] (RUN_DIR holds the run's scenario.yaml; prints the run's summary table)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import yaml

import pcvfe_drake.systems.vehicle_plant as vehicle_plant
from pcvfe_drake.cli import main as pcvfe_main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, nargs="?", help="a stored run's folder")
    ap.add_argument("--duration", type=float, default=20.0, help="driven seconds")
    ap.add_argument("--out", type=Path, help="the new run's folder (default: a temporary one)")
    ap.add_argument("--quick", action="store_true", help="5 s")
    args = ap.parse_args(argv)
    if args.run is None:
        ap.error("give a run folder (one of a `pcvfe evaluate` folder's runs/)")
    scenario = yaml.safe_load((args.run / "scenario.yaml").read_text())
    scenario["simulator"]["integration_scheme"] = "runge_kutta3"
    real_init = vehicle_plant.VehiclePlant.__init__

    def continuous(self, *a, **kw):
        kw.setdefault("mb_integration", "continuous")
        real_init(self, *a, **kw)

    vehicle_plant.VehiclePlant.__init__ = continuous
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.yaml"
        path.write_text(yaml.safe_dump(scenario))
        out = args.out or Path(tmp) / "run"
        duration = 5.0 if args.quick else args.duration
        return pcvfe_main(["simulate", str(path), "--duration", str(duration), "--no-meshcat",
                           "--no-progress", "--out", str(out)])  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
