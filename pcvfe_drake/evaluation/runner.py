"""Running an experiment's runs on Dask (``dask.distributed``) and storing each as it finishes.

:func:`open_client` gives a ``distributed.Client``: on a ``LocalCluster`` that it starts on this
machine (one single-threaded worker process per run slot, bound to 127.0.0.1), or on an existing
scheduler given by address (``tcp://host:8786``). :func:`run_sweep` submits every pending run as
one task (one diagram simulation per task, ``pcvfe_drake.diagrams.evaluate_run.run_one``) and
writes each result into the :class:`~pcvfe_drake.evaluation.store.ResultStore` the moment it
arrives, with a progress bar of runs done / failed and the time left. A run that raises on its
worker comes back as failed (the task catches it); a task lost with its worker (killed, out of
memory, beyond Dask's retries) is recorded as failed too, with Dask's error. Ctrl-C cancels what
is still queued; everything finished is already on disk.

This module imports no pydrake (the task function is imported only when a sweep starts).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from pcvfe_drake.evaluation.experiment import RunSpec
from pcvfe_drake.evaluation.store import ResultStore


@dataclass
class SweepStats:
    """What one call of :func:`run_sweep` did."""

    submitted: int = 0
    done: int = 0
    failed: int = 0
    skipped: int = 0
    """Runs already done in the store (resume)."""
    interrupted: bool = False
    wall_s: float = 0.0
    task_wall_s: list[float] = field(default_factory=list)
    """Time each finished task spent on its worker [s]."""
    record_s: list[float] = field(default_factory=list)
    """Time the client spent storing each result [s]."""
    failures: list[tuple[str, str]] = field(default_factory=list)
    """(run_id, error) of each failed run."""


def default_workers() -> int:
    """Worker processes of the local cluster: one per CPU this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def open_client(
    workers: int | None = None,
    scheduler: str | None = None,
    *,
    processes: bool = True,
    memory_limit: str | float | None = "auto",
) -> Iterator[Any]:
    """A Dask client: on ``scheduler`` (an address) or on a new LocalCluster of ``workers``.

    The local cluster has single-threaded workers (a run is one diagram simulation; Dask's
    nanny also pins the BLAS/OpenMP threads to 1), listens on 127.0.0.1 only (its HTTP
    endpoints too) and has no dashboard. ``processes=False`` keeps the workers as threads of
    this process (tests).
    """
    from distributed import Client, LocalCluster

    if scheduler is not None and workers is not None:
        raise ValueError("give either --workers (a local cluster) or --scheduler, not both")
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(
                f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({exc}); start one "
                "with `dask scheduler` and check the address (tcp://HOST:8786)"
            ) from exc
        try:
            yield client
        finally:
            client.close()
        return
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"--workers must be >= 1, got {n}")
    kwargs: dict[str, Any] = {
        "n_workers": n,
        "threads_per_worker": 1,
        "processes": processes,
        # Dask's HTTP endpoints (health, metrics; no dashboard without bokeh) on loopback only.
        "dashboard_address": "127.0.0.1:0",
        "worker_dashboard_address": "127.0.0.1:0",
    }
    if processes:
        kwargs.update(host="127.0.0.1", memory_limit=memory_limit)
    with LocalCluster(**kwargs) as cluster:
        try:
            with Client(cluster) as client:
                yield client
        finally:
            # Every result is stored by now; a worker whose interpreter takes longer than the
            # nanny's fixed 4 s to finish (pydrake's teardown on a loaded machine) is killed,
            # which loses nothing: say nothing about it on our own shutdown.
            quiet = _DropMessage("still alive after")
            logging.getLogger("distributed.nanny").addFilter(quiet)
            try:
                cluster.close()
            finally:
                logging.getLogger("distributed.nanny").removeFilter(quiet)


class _DropMessage(logging.Filter):
    """Drops log records whose message contains ``text``."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    def filter(self, record: logging.LogRecord) -> bool:
        return self.text not in record.getMessage()


def _default_task() -> Callable[[dict], dict]:
    from pcvfe_drake.diagrams.evaluate_run import run_one

    return run_one


def run_sweep(
    specs: Sequence[RunSpec],
    store: ResultStore,
    client,
    *,
    task: Callable[[dict], dict] | None = None,
    progress: bool = True,
    on_result: Callable[[dict, dict], None] | None = None,
) -> SweepStats:
    """Run the pending ``specs`` on ``client``; store each result as it arrives.

    Returns the counts; failed runs are in ``stats.failures`` and in the store.
    """
    import uuid

    from distributed import as_completed

    task = task or _default_task()
    todo = store.pending(specs)
    stats = SweepStats(skipped=len(specs) - len(todo))
    if not todo:
        return stats
    t0 = time.perf_counter()
    by_key: dict[str, dict] = {}
    futures = []
    tag = uuid.uuid4().hex[:8]
    for spec in todo:
        d = spec.to_dict()
        key = f"pcvfe-run-{spec.run_id}-{spec.spec_hash}-{tag}"
        by_key[key] = d
        futures.append(client.submit(task, d, key=key, pure=False))
    stats.submitted = len(futures)
    bar = None
    if progress:
        from pcvfe_drake.progress import progress_bar

        bar = progress_bar(total=len(futures), unit="run", desc="runs", smoothing=0.0)
        bar.set_postfix_str(f"done=0 failed=0 skipped={stats.skipped}")
    pending = as_completed(futures)
    try:
        for future in pending:
            spec_d = by_key[future.key]
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - a lost task is a failed run, not a crash
                result = {
                    "run_id": spec_d["run_id"],
                    "status": "failed",
                    "error": f"{type(exc).__name__}: {exc} (the task did not return: its "
                    "worker died or Dask gave up on it)",
                }
            r0 = time.perf_counter()
            store.record(spec_d, result)
            stats.record_s.append(time.perf_counter() - r0)
            if result.get("task_wall_s") is not None:
                stats.task_wall_s.append(float(result["task_wall_s"]))
            if result["status"] == "done":
                stats.done += 1
            else:
                stats.failed += 1
                stats.failures.append((spec_d["run_id"], result.get("error", "")))
            if on_result is not None:
                on_result(spec_d, result)
            future.release()
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(
                    f"done={stats.done} failed={stats.failed} skipped={stats.skipped}"
                )
    except KeyboardInterrupt:
        stats.interrupted = True
        client.cancel([f for f in futures if not f.done()])
    finally:
        if bar is not None:
            bar.close()
        stats.wall_s = time.perf_counter() - t0
    return stats
