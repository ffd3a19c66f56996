"""One results folder of tables from two: a stored experiment, with the runs of a second
folder (a subset of its grid, run again on changed code) in place of the same runs.

    python studies/probe_stiffness/merge.py BASE_DIR NEW_DIR OUT_DIR

Copies ``runs``, ``laps``, ``contexts`` and ``failures`` of ``BASE_DIR``, drops every row whose
``run_id`` ``NEW_DIR`` holds, appends ``NEW_DIR``'s rows, and writes the four tables to
``OUT_DIR`` (tables only: no drive logs, no report). The study scripts that read tables
(``studies/generalization/targets.py``) then score the whole grid with the new runs. A frozen
study script.
Last stdout line: one JSON object (rows replaced per table).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

TABLES = ("runs", "laps", "contexts", "failures")


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    base, new, out = (Path(a) for a in argv)
    out.mkdir(parents=True, exist_ok=True)
    replaced_ids = set(pd.read_parquet(new / "runs.parquet")["run_id"])
    counts = {}
    for name in TABLES:
        old = pd.read_parquet(base / f"{name}.parquet")
        fresh = pd.read_parquet(new / f"{name}.parquet")
        kept = old[~old["run_id"].isin(replaced_ids)]
        counts[name] = {"dropped": int(len(old) - len(kept)), "added": int(len(fresh))}
        merged = pd.concat([kept, fresh], ignore_index=True) if len(fresh) else kept
        merged.to_parquet(out / f"{name}.parquet", index=False)
        print(f"{name}: {counts[name]['dropped']} rows dropped, {counts[name]['added']} added")
    print(json.dumps(counts))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
