"""Monte Carlo robustness studies: parameter distributions -> runs -> a table of summaries.

Every draw's parameter values are sampled up front in the calling process from one seeded
``numpy.random.Generator``, so the table depends only on ``seed`` and not on the backend, the
number of workers or the order in which runs finish. Backends:

* ``"local"``: a thread pool in this process (the simulation releases the GIL, so threads run
  in parallel on all cores);
* ``"ray"``: one Ray task per draw on the connected Ray cluster (``ray.init()`` is called with
  ``ray_address`` if Ray is not initialised yet; see docs/PYTHON.md for a real cluster).
"""

from __future__ import annotations

import concurrent.futures as cf
import math
import os
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import _core


@dataclass(frozen=True)
class Uniform:
    """Uniform on ``[low, high)``."""

    low: float
    high: float

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.high >= self.low):
            raise ValueError(f"Uniform({self.low}, {self.high}): need finite low <= high")
        return rng.uniform(self.low, self.high, n)


@dataclass(frozen=True)
class Normal:
    """Normal with mean ``mean`` and standard deviation ``std``, optionally clipped to
    ``[low, high]``."""

    mean: float
    std: float
    low: Optional[float] = None
    high: Optional[float] = None

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if not (math.isfinite(self.mean) and math.isfinite(self.std) and self.std >= 0):
            raise ValueError(f"Normal({self.mean}, {self.std}): need finite mean and std >= 0")
        x = rng.normal(self.mean, self.std, n)
        if self.low is not None or self.high is not None:
            x = np.clip(x, self.low, self.high)
        return x


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (with probabilities ``p``, default equal)."""

    values: Sequence[Any]
    p: Optional[Sequence[float]] = None

    def sample(self, rng: np.random.Generator, n: int) -> List[Any]:
        if len(self.values) == 0:
            raise ValueError("Choice: no values")
        idx = rng.choice(len(self.values), size=n, p=self.p)
        return [self.values[i] for i in idx]


Distribution = Union[Uniform, Normal, Choice, Callable[[np.random.Generator, int], Sequence[Any]]]


def summary_row(summary: Mapping[str, Any]) -> Dict[str, Any]:
    """A run's summary dict flattened to one table row (scalar columns).

    Columns: ``controller``, ``dof``, ``payload_kg``, ``duration_s``, ``steps``,
    ``rms_force_thigh_n``, ``rms_force_shank_n``, ``delta_max_hip_deg``,
    ``delta_max_knee_deg``, ``mu_1`` ... ``mu_S``, ``step_time_mean_us``, ``step_time_p50_us``,
    ``step_time_p99_us``, ``step_time_max_us``, ``limit_violations``, ``solver_failures``,
    ``error`` (``""`` for a completed run).
    """
    if "error" in summary and "controller" not in summary:
        return {"error": summary["error"]}
    row: Dict[str, Any] = {
        "controller": summary["controller"],
        "dof": summary["dof"],
        "payload_kg": summary["payload_kg"],
        "duration_s": summary["duration_s"],
        "steps": summary["steps"],
        "rms_force_thigh_n": summary["rms_force_n"]["thigh"],
        "rms_force_shank_n": summary["rms_force_n"]["shank"],
        "delta_max_hip_deg": summary["delta_max_deg"]["hip"],
        "delta_max_knee_deg": summary["delta_max_deg"]["knee"],
    }
    for i, p in enumerate(summary.get("mean_probability") or []):
        row[f"mu_{i + 1}"] = p
    st = summary["step_time_us"]
    for k in ("mean", "p50", "p99", "max"):
        row[f"step_time_{k}_us"] = st[k]
    row["limit_violations"] = summary["limit_violations"]
    row["solver_failures"] = summary["solver_failures"]
    row["error"] = ""
    return row


def _columns(rows: Sequence[Mapping[str, Any]]) -> Dict[str, np.ndarray]:
    """Rows -> dict of numpy columns (NaN for a number missing in some rows)."""
    keys: List[str] = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    out: Dict[str, np.ndarray] = {}
    for k in keys:
        vals = [r.get(k) for r in rows]
        present = [v for v in vals if v is not None]
        numeric = all(
            isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            for v in present
        )
        if numeric and present:
            if len(present) == len(vals) and all(isinstance(v, (int, np.integer)) for v in vals):
                out[k] = np.array(vals, dtype=np.int64)
            else:
                out[k] = np.array([np.nan if v is None else float(v) for v in vals])
        elif k == "error":
            out[k] = np.array(["" if v is None else str(v) for v in vals], dtype=object)
        else:
            out[k] = np.array(vals, dtype=object)
    return out


class _Progress:
    """A one-line text progress bar on stderr."""

    def __init__(self, total: int, label: str, enabled: bool) -> None:
        self.total, self.label, self.enabled = total, label, enabled
        self.done, self.start, self.last = 0, time.perf_counter(), 0.0

    def update(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        tty = sys.stderr.isatty()
        if tty and now - self.last < 0.1 and self.done < self.total:
            return
        # Not a terminal (CI logs, files): one line per 10 % instead of a redrawn bar.
        step = max(self.total // 10, 1)
        if not tty and self.done % step != 0 and self.done < self.total:
            return
        self.last = now
        el = now - self.start
        rate = self.done / el if el > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 30
        cr = "\r" if tty else ""
        fill = int(width * self.done / max(self.total, 1))
        sys.stderr.write(
            f"{cr}{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
            f"{rate:.1f} runs/s, {el:.0f} s elapsed, ETA {eta:.0f} s "
        )
        if self.done >= self.total or not tty:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _run_one(
    scenario: "_core.Scenario", dof: int, cancel: Optional["_core.CancelToken"] = None
) -> Dict[str, Any]:
    """One draw (in a worker): the flattened summary, or the error message."""
    try:
        return summary_row(_core.simulate(scenario, dof=dof, trace=False, cancel=cancel))
    except (_core.RunError, _core.ConfigError) as e:
        return {"error": str(e)}


def draw_parameters(
    draws: int, params: Mapping[str, Distribution], seed: Optional[int] = 0
) -> Dict[str, List[Any]]:
    """The sampled parameter values, ``{dotted key: [value per draw]}`` (keys in order)."""
    if not isinstance(draws, int) or isinstance(draws, bool) or draws < 1:
        raise ValueError(f"draws: {draws!r} (allowed: an integer >= 1)")
    rng = np.random.default_rng(seed)
    out: Dict[str, List[Any]] = {}
    for key, dist in params.items():
        if hasattr(dist, "sample"):
            vals = dist.sample(rng, draws)  # type: ignore[union-attr]
        elif callable(dist):
            vals = dist(rng, draws)
        else:
            raise TypeError(f"params[{key!r}]: expected Uniform/Normal/Choice or a callable(rng, n)")
        vals = list(vals)
        if len(vals) != draws:
            raise ValueError(f"params[{key!r}]: sampler returned {len(vals)} values for {draws} draws")
        out[key] = [v.item() if isinstance(v, np.generic) else v for v in vals]
    return out


def montecarlo(
    draws: int,
    params: Mapping[str, Distribution],
    scenario: Optional["_core.Scenario"] = None,
    *,
    dof: int = 2,
    controller: Optional[str] = None,
    seed: Optional[int] = 0,
    backend: str = "local",
    workers: Optional[int] = None,
    progress: bool = True,
    ray_address: Optional[str] = None,
) -> Dict[str, np.ndarray]:
    """Run a Monte Carlo study and return its table (dict of numpy columns, one row per draw).

    ``params`` maps dotted scenario keys to distributions, e.g.
    ``{"uncertainty.payload_kg": Uniform(0, 2), "human.body_mass_kg": Normal(75, 8, 50, 110)}``.
    Each draw sets those keys on a copy of ``scenario`` (default: the default scenario, with
    ``controller`` overriding ``controller.kind``) with the CLI's validation; a draw whose
    values are invalid or whose run fails keeps NaN metrics and its message in ``error``.

    Columns: ``draw``, one per parameter key, then :func:`summary_row`'s columns.
    ``pandas.DataFrame(table)`` and ``polars.DataFrame(table)`` take it directly.

    Ctrl-C raises ``KeyboardInterrupt`` within about a second: the local backend stops its
    running draws between two control steps and drops the queued ones; the Ray backend
    cancels its pending tasks.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend: {backend!r} (allowed: 'local' or 'ray')")
    if dof not in (1, 2):
        raise ValueError(f"dof: {dof!r} (allowed: 1 or 2)")
    if workers is not None and workers < 1:
        raise ValueError(f"workers: {workers!r} (allowed: >= 1)")
    base = scenario.copy() if scenario is not None else _core.Scenario.default()
    if controller is not None:
        base["controller.kind"] = controller
    values = draw_parameters(draws, params, seed)
    keys = list(values)

    scenarios: List[Optional[_core.Scenario]] = []
    rows: List[Dict[str, Any]] = []
    for i in range(draws):
        row: Dict[str, Any] = {"draw": i}
        row.update({k: values[k][i] for k in keys})
        rows.append(row)
        try:
            scenarios.append(base.replace({k: values[k][i] for k in keys}))
        except _core.ConfigError as e:
            scenarios.append(None)
            row["error"] = str(e)

    bar = _Progress(draws, f"montecarlo[{backend}]", progress)
    todo = {i: s for i, s in enumerate(scenarios) if s is not None}
    bar.update(draws - len(todo))
    results: Dict[int, Dict[str, Any]] = {}
    if backend == "local":
        n = workers or os.cpu_count() or 1
        stop = _core.CancelToken()
        pool = cf.ThreadPoolExecutor(max_workers=n)
        try:
            futs = {pool.submit(_run_one, s, dof, stop): i for i, s in todo.items()}
            for f in cf.as_completed(futs):
                results[futs[f]] = f.result()
                bar.update()
        except BaseException:
            # Ctrl-C (or any error) in this thread: the running draws stop between two
            # control steps, the queued ones are dropped.
            stop.cancel()
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
    else:
        results = _run_ray(todo, dof, bar, ray_address)
    for i, r in results.items():
        rows[i].update(r)
    return _columns(rows)


def _run_ray(
    todo: Mapping[int, "_core.Scenario"],
    dof: int,
    bar: _Progress,
    ray_address: Optional[str],
) -> Dict[int, Dict[str, Any]]:
    try:
        import ray
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("backend='ray' needs Ray: pip install 'ray>=2.9'") from e
    if not ray.is_initialized():
        ray.init(address=ray_address)
    remote = ray.remote(num_cpus=1)(_run_one)
    # Scenarios travel as TOML text (Scenario pickles through it).
    refs = {remote.remote(s, dof): i for i, s in todo.items()}
    results: Dict[int, Dict[str, Any]] = {}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=min(len(pending), 16), timeout=1.0)
            for ref, value in zip(done, ray.get(done)):
                results[refs[ref]] = value
                bar.update()
    except BaseException:
        # Ctrl-C: the tasks not finished yet are cancelled (a running one gets its own
        # KeyboardInterrupt and stops between two control steps).
        for ref in pending:
            ray.cancel(ref)
        raise
    return results


def write_csv(table: Mapping[str, np.ndarray], path: str) -> None:
    """Writes a table (dict of equal-length columns) as CSV."""
    import csv

    keys = list(table)
    n = len(next(iter(table.values()))) if keys else 0
    tmp = f"{path}.tmp.{os.getpid()}"
    try:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(keys)
            for i in range(n):
                w.writerow([_cell(table[k][i]) for k in keys])
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _cell(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return v
