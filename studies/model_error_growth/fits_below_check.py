"""PC-VFE's fits and handed frictions of contexts whose true friction lies below the car's
checked friction, over stored experiments.

    python studies/model_error_growth/fits_below_check.py DIR [DIR ...] [--below 0.31] [--min-s 15]

Reads each experiment's ``contexts.parquet`` (source ``pcvfe``, fitted contexts driven at least
``--min-s`` seconds) and prints, per band of true friction, the relative error of the final fit
and of the handed friction; a JSON object last.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--below", type=float, default=0.31)
    ap.add_argument("--min-s", type=float, default=15.0)
    args = ap.parse_args()
    frames = []
    for d in args.dirs:
        df = pd.read_parquet(Path(d) / "contexts.parquet")
        keep = (df.source == "pcvfe") & df.fitted & (df.true_mu < args.below)
        frames.append(df[keep & (df.time_in_context_s >= args.min_s)].assign(experiment=d))
    df = pd.concat(frames)
    df["fit_rel"] = (df.mu_hat - df.true_mu) / df.true_mu
    df["handed_rel"] = (df.handed_mu - df.true_mu) / df.true_mu
    bands = pd.cut(df.true_mu, [0.0, 0.2, 0.26, args.below])
    table = df.groupby(bands, observed=True)[["fit_rel", "handed_rel"]].agg(
        ["count", "median", "min", "max"]
    )
    print(table.round(3).to_string())
    out = {}
    for band, part in df.groupby(bands, observed=True):
        out[str(band)] = {
            "pairs": int(len(part)),
            "fit_rel_median": round(float(part.fit_rel.median()), 3),
            "fit_rel_max": round(float(part.fit_rel.max()), 3),
            "handed_rel_median": round(float(part.handed_rel.median()), 3),
        }
    print(json.dumps({"study": "model_error_growth.fits_below_check", "bands": out}))


if __name__ == "__main__":
    main()
