"""A results page written from stored experiments, not copied by hand
(``pcvfe evaluate --report DIR --results-page docs/results.md``; no pydrake).

Each experiment folder (``pcvfe_drake.evaluation.store``) becomes one section of the page: what
was run (the command that made it, when, the experiment as run: scenarios, sources and their
overrides, seeds, run length), the package versions it recorded, the table per scenario (every
metric as the mean over seeds with its 95 % interval, and the paired difference of mean speed to
the reference source), and, where the runs were made on several worlds (any ``world`` column of
the runs table), each source's median and worst world: a scenario named per world
(``NAME@WORLD``) makes one table over its worlds. A section sits between two marker
comments that name the experiment's folder, so updating the page from one folder replaces that
section and keeps the others: the page is the sum of the stored runs it was written from.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.evaluation.report import WORLD_COLUMN, ci_text, fmt_number, scenario_groups
from pcvfe_drake.evaluation.stats import LEVEL, paired_differences
from pcvfe_drake.evaluation.store import ResultStore
from pcvfe_drake.evaluation.tables import METRICS

TITLE = "# Results"
INTRO = (
    "Generated from stored experiment folders by `pcvfe evaluate --report DIR --results-page "
    "PAGE`; do not edit by hand: rerun the command of a section to reproduce it, then the line "
    "above to rewrite it. Cells are means over seeds with their "
    f"{LEVEL:.0%} confidence interval (Student t) in brackets; differences are paired by seed."
)
BEGIN = "<!-- results: {key} -->"
END = "<!-- end results: {key} -->"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def _sources(exp: dict, runs: pd.DataFrame) -> list[str]:
    named = [s.get("name") for s in exp.get("sources") or []]
    present = list(dict.fromkeys(runs["source"]))
    return [s for s in named if s in present] + [s for s in present if s not in named]


def _world(per_world: pd.DataFrame, world) -> str:
    r = per_world.loc[world]
    return (
        f"{world}: {fmt_number(r['mean_speed_mps'])} m/s, "
        f"{fmt_number(r['failures'])} failures per run"
    )


def _world_rows(runs: pd.DataFrame, sources: list[str]) -> list[list[str]]:
    """Per source: the median and the worst world (by failures per run, then mean speed)."""
    rows = []
    for src in sources:
        mine = runs[runs["source"] == src]
        if mine.empty:
            continue
        per_world = (
            mine.groupby(WORLD_COLUMN)[["failures", "mean_speed_mps"]]
            .mean(numeric_only=True)
            .sort_values(["failures", "mean_speed_mps"], ascending=[False, True])
        )
        worst = per_world.index[0]
        by_speed = per_world.sort_values("mean_speed_mps")
        median = by_speed.index[len(by_speed) // 2]  # the upper middle of an even count

        rows.append([src, str(len(per_world)), _world(per_world, median), _world(per_world, worst)])
    return rows


def _settings(exp: dict) -> list[str]:
    length = (
        f"{exp['duration_s']:g} s per run"
        if exp.get("duration_s")
        else f"{exp.get('laps') or 'the scenario’s'} lap(s) per run"
    )
    seeds = int(exp.get("seeds") or 0)
    first = int(exp.get("first_seed") or 0)
    lines = [
        f"- scenarios: {', '.join(str(s) for s in exp.get('scenarios') or [])}; seeds "
        f"{first}-{first + seeds - 1}; {length}",
    ]
    if exp.get("overrides"):
        lines.append(f"- overrides of every run: `{exp['overrides']}`")
    for s in exp.get("sources") or []:
        what = f"`{s.get('overrides')}`" if s.get("overrides") else "no overrides"
        lines.append(f"- source **{s.get('name')}**: {s.get('description') or ''} ({what})")
    return lines


def _versions(env: dict, runs: pd.DataFrame) -> list[str]:
    client = env.get("client_versions") or {}
    lines = []
    if client:
        text = ", ".join(f"{k} {v}" for k, v in client.items())
        lines.append(f"- client: {text}")
    workers = sorted(set(runs["versions"].astype(str)) - {""}) if "versions" in runs else []
    for w in workers:
        lines.append(f"- workers: {w}")
    return lines or ["- (no versions recorded)"]


def experiment_section(root: str | Path, page: str | Path = "PAGE") -> tuple[str, str]:
    """``(key, markdown)`` of one stored experiment; the key is its folder as given, ``page``
    the page it is written to (named in the command that rewrites the section)."""
    store = ResultStore(root)
    if not store.exists():
        raise FileNotFoundError(f"{store.root}: no runs.parquet (not a pcvfe evaluate folder)")
    runs = store.table("runs")
    exp, env = store.experiment_dict(), store.environment()
    done = runs[runs["status"] == "done"]
    sources = _sources(exp, runs)
    ref = exp.get("reference") if exp.get("reference") in sources else sources[0]
    name = exp.get("name") or store.root.name
    key = Path(root).as_posix()
    out = [f"## {name}", ""]
    if exp.get("description"):
        out += [str(exp["description"]), ""]
    command = env.get("command") or "(not recorded)"
    when = env.get("started_utc") or "(not recorded)"
    out += [
        f"Made by `{command}` (started {when}). This section was written by "
        f"`pcvfe evaluate --report {key} --results-page {Path(page).as_posix()}` from the "
        f"tables in `{key}` (that command's output folder; its `runs/` of drive logs need not "
        "be kept).",
        "",
        f"{len(runs)} runs, {len(done)} done, {len(runs) - len(done)} failed as runs. "
        f"Settings as run:",
        "",
        *_settings(exp),
        "",
        "Versions recorded:",
        "",
        *_versions(env, runs),
    ]
    metrics = [
        m
        for m in METRICS
        if m.column in done.columns and np.isfinite(done[m.column].astype(float)).any()
    ]
    groups = scenario_groups(done)
    for sc in sorted(groups.unique()):
        here = done[groups == sc]
        out += ["", f"### {sc}", ""]
        header = ["source", "runs"]
        header += [f"{m.label}{f' [{m.unit}]' if m.unit else ''}" for m in metrics]
        rows = []
        by = ("seed", WORLD_COLUMN) if WORLD_COLUMN in here.columns else ("seed",)
        diffs = paired_differences(here, "mean_speed_mps", ref, by=by)
        for src in sources:
            r = here[here["source"] == src]
            if r.empty:
                continue
            rows.append([src, str(len(r))] + [ci_text(r[m.column].astype(float)) for m in metrics])
        if len(sources) > 1:
            header.append(f"speed minus {ref} [m/s]")
            for row in rows:
                d = diffs[diffs["source"] == row[0]]["diff"]
                row.append("" if row[0] == ref else ci_text(d))
        out += _table(header, rows)
        if WORLD_COLUMN in here.columns and here[WORLD_COLUMN].nunique() > 1:
            out += ["", f"Per {WORLD_COLUMN} (means over its seeds):", ""]
            out += _table(
                ["source", f"{WORLD_COLUMN}s", f"median {WORLD_COLUMN}", f"worst {WORLD_COLUMN}"],
                _world_rows(here, sources),
            )
    return key, "\n".join(out)


def page_folders(page: str | Path) -> list[str]:
    """The experiment folders a results page was written from, in its order."""
    return list(_sections(Path(page).read_text()))


def _sections(text: str) -> dict[str, str]:
    found = {}
    for m in re.finditer(r"<!-- results: (.+?) -->\n(.*?)\n<!-- end results: \1 -->", text, re.S):
        found[m.group(1)] = m.group(2)
    return found


def update_results_page(page: str | Path, roots: Sequence[str | Path]) -> Path:
    """Write or update ``page`` with a section per experiment folder of ``roots`` (existing
    sections of other folders are kept, in their order; new ones are appended)."""
    page = Path(page)
    sections = _sections(page.read_text()) if page.is_file() else {}
    for root in roots:
        key, body = experiment_section(root, page)
        sections[key] = body
    parts = [TITLE, "", INTRO, ""]
    for key, body in sections.items():
        parts += [BEGIN.format(key=key), body, END.format(key=key), ""]
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text("\n".join(parts))
    return page
