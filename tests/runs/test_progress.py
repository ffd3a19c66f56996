"""The progress helper: a plain line every few percent off a terminal, tqdm's bar on one."""

from __future__ import annotations

import io

import pytest

from pcvfe_drake.progress import LineProgress, progress_bar


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_off_a_terminal_prints_a_line_per_step_without_carriage_returns():
    out = io.StringIO()
    bar = progress_bar(total=1000, desc="runs", unit="run", stream=out, every_percent=10)
    assert isinstance(bar, LineProgress)
    for _ in range(1000):
        bar.update(1)
    bar.close()
    text = out.getvalue()
    lines = text.splitlines()
    assert "\r" not in text
    assert len(lines) == 10  # 10 %, 20 %, ..., 100 %; close adds nothing after 100 %
    assert lines[0].startswith("runs: 10 % (100/1000 run)")
    assert lines[-1].startswith("runs: 100 % (1000/1000 run)")


def test_iterating_counts_shows_the_postfix_and_closes_with_a_final_line():
    out = io.StringIO()
    bar = progress_bar(range(7), desc="logs", stream=out, every_percent=50)
    seen = []
    for i in bar:
        seen.append(i)
        bar.set_postfix_str(f"last={i}")
    assert seen == list(range(7))
    lines = out.getvalue().splitlines()
    # 50 % is crossed at 4 of 7 (57 %), 100 % at 7 of 7
    assert [ln.split(",")[0] for ln in lines] == ["logs: 57 % (4/7 it)", "logs: 100 % (7/7 it)"]
    assert lines[0].endswith("last=3") and lines[-1].endswith("last=6")


def test_float_totals_and_a_partial_run_end_with_the_count_reached():
    out = io.StringIO()
    with progress_bar(total=120.0, unit="s sim", stream=out) as bar:
        bar.update(7.5)
        bar.update(1.0)
        assert bar.n == pytest.approx(8.5)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("6 % (8/120 s sim)")  # crossed 5 % (6 s) at 7.5 s
    assert lines[-1].startswith("7 % (8/120 s sim)")  # the close: where it stopped


def test_on_a_terminal_it_is_tqdm():
    from tqdm import tqdm

    bar = progress_bar(total=3, stream=_Tty(), bar_format="{n}")
    assert isinstance(bar, tqdm)
    bar.close()


def test_bad_step_is_refused():
    with pytest.raises(ValueError, match="every_percent"):
        LineProgress(total=3, every_percent=0)
