"""Where in a terrain visit PC-VFE loses its time to the oracle: per terrain, the seconds lost on
the visit's first SPLIT seconds and in all, at the same arc length as the oracle's lap of the
same seed (``pcvfe_drake.evaluation.entry_latency.terrain_lag`` with ``splits_s``).

Input: a ``pcvfe evaluate`` folder with ``runs/<scenario>__pcvfe__sNNN`` and
``runs/<scenario>__oracle__sNNN`` (e.g. ``paper_claim3`` or an experiment with both sources).

Usage: python studies/speed_gap/lag_split.py DIR [--split 8] [--split 20]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pcvfe_drake.evaluation.entry_latency import terrain_lag


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--split", type=float, action="append", default=None)
    args = ap.parse_args()
    splits = args.split or [8.0, 20.0]
    per: dict[str, list[dict]] = {}
    for run in sorted((args.root / "runs").glob("*__pcvfe__*")):
        ref = run.with_name(run.name.replace("__pcvfe__", "__oracle__"))
        if ref.is_dir():
            for visit in terrain_lag(run, ref, splits)["visits"]:
                per.setdefault(visit["terrain"], []).append(visit)
    result = {}
    for terrain, visits in sorted(per.items()):
        n = len(visits)
        entry = {"visits": n, "lost_s": round(sum(v["lag_s"] for v in visits) / n, 3)}
        for key in visits[0]["lag_first_s"]:
            entry[f"lost_first_{key}_s"] = round(sum(v["lag_first_s"][key] for v in visits) / n, 3)
        result[terrain] = entry
        cut = ", ".join(
            f"first {k} s {entry[f'lost_first_{k}_s']:.2f}" for k in visits[0]["lag_first_s"]
        )
        print(f"{terrain:14s} {n:3d} visits: lost {entry['lost_s']:.2f} s per visit ({cut})")
    print(json.dumps({"study": "speed_gap.lag_split", "root": str(args.root), "terrains": result}))


if __name__ == "__main__":
    main()
