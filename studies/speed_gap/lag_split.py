"""Where in a terrain visit PC-VFE loses its time to the oracle: per terrain, the seconds lost on
the visit's first SPLIT seconds and after them, at the same arc length as the oracle's lap of the
same seed (``pcvfe_drake.evaluation.entry_latency.terrain_lag``'s measure, cut in two).

Input: a ``pcvfe evaluate`` folder with ``runs/<scenario>__pcvfe__sNNN`` and
``runs/<scenario>__oracle__sNNN`` (e.g. ``paper_claim3`` or an experiment with both sources).

Usage: python studies/speed_gap/lag_split.py DIR [--split 8] [--split 20]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pcvfe_drake.evaluation.entry_latency import _progress_m, read_run
from pcvfe_drake.runs import drive_metrics


def lags(run: Path, reference: Path, splits: list[float]) -> list[dict]:
    """Per terrain visit of ``run``: seconds lost to ``reference`` before each split and after."""
    (_, log, course), (_, ref, _) = read_run(run), read_run(reference)
    p, t = _progress_m(log, course), log["t"].to_numpy(float)
    p_ref, t_ref = _progress_m(ref, course), ref["t"].to_numpy(float)
    keep = np.concatenate([[True], np.diff(p_ref) > 0])
    p_ref, t_ref = np.maximum.accumulate(p_ref[keep]), t_ref[keep]

    def lost(i: int, j: int) -> float:
        return float(
            (t[j] - t[i]) - (np.interp(p[j], p_ref, t_ref) - np.interp(p[i], p_ref, t_ref))
        )

    out = []
    for a, b, name in drive_metrics._visits(log["terrain"].astype(str).to_numpy(), ()):
        b = min(b, len(t) - 1)
        if p[b] > p_ref[-1]:
            continue
        row = {"terrain": name, "visit_s": float(t[b] - t[a]), "lost_s": lost(a, b)}
        for split in splits:
            m = min(a + int(np.searchsorted(t[a : b + 1], t[a] + split)), b)
            row[f"lost_first_{split:g}_s"] = lost(a, m)
        out.append(row)
    return out


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
            for row in lags(run, ref, splits):
                per.setdefault(row["terrain"], []).append(row)
    result = {}
    for terrain, rows in sorted(per.items()):
        n = len(rows)
        entry = {"visits": n, "lost_s": sum(r["lost_s"] for r in rows) / n}
        for split in splits:
            k = f"lost_first_{split:g}_s"
            entry[k] = sum(r[k] for r in rows) / n
        result[terrain] = {k: round(v, 3) if isinstance(v, float) else v for k, v in entry.items()}
        cut = ", ".join(f"first {s:g} s {entry[f'lost_first_{s:g}_s']:.2f}" for s in splits)
        print(f"{terrain:14s} {n:3d} visits: lost {entry['lost_s']:.2f} s per visit ({cut})")
    print(json.dumps({"study": "speed_gap.lag_split", "root": str(args.root), "terrains": result}))


if __name__ == "__main__":
    main()
