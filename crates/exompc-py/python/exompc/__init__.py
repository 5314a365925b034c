"""exompc: multi-stage robust NMPC of a lower-limb exoskeleton, from Python.

The controllers, the closed-loop simulator and the paper's studies run in Rust (the native
module ``exompc._core``); this package adds numpy-friendly wrappers, payload sweeps, grid
scans and Monte Carlo studies on a local thread pool or on Ray.

>>> import exompc
>>> s = exompc.Scenario.default()
>>> r = exompc.simulate(s)
>>> r["rms_force_n"]            # doctest: +SKIP
{'thigh': 1.53..., 'shank': 2.44...}

Errors are Python exceptions of documented classes, never a crash of the interpreter:
``ConfigError`` (a ``ValueError``) for a bad argument, key or value (including a run too long
for the memory available), ``TypeError`` for an argument of the wrong type, ``OSError``
(``FileNotFoundError``, ``PermissionError``, ...) for files, ``RunError`` (a
``RuntimeError``) for a run that cannot complete or was cancelled, ``RuntimeError`` for a
``Controller`` used from another thread than its own, and ``KeyboardInterrupt`` when Ctrl-C
stops a long call (the process stays usable). See docs/PYTHON.md.
"""

from __future__ import annotations

import itertools
from typing import Any, Dict, Iterable, List, Literal, Mapping, Optional, Sequence, TypedDict, cast

import numpy as np

from . import _core
from ._core import (
    STATUS_NAMES,
    TRACE_COLUMNS,
    CancelToken,
    ConfigError,
    Controller,
    RunError,
    Scenario,
    Simulator,
    __version__,
    default_config_toml,
    run_many,
)
from .montecarlo import Choice, Normal, Uniform, draw_parameters, montecarlo, summary_row, write_csv

__all__ = [
    "STATUS_NAMES",
    "TRACE_COLUMNS",
    "CancelToken",
    "Choice",
    "ConfigError",
    "Controller",
    "MultiStage",
    "Nmpc",
    "Normal",
    "Pd",
    "RunError",
    "Scenario",
    "Simulator",
    "SolverChoice",
    "StepTime",
    "Summary",
    "Uniform",
    "__version__",
    "default_config_toml",
    "draw_parameters",
    "envelope",
    "montecarlo",
    "run_many",
    "scan",
    "simulate",
    "summary_row",
    "sweep",
    "table2",
    "write_csv",
]


class SolverChoice(TypedDict):
    """The summary's ``solver``: what ``[controller.sqp] qp`` and ``hessian`` resolved to for
    the NMPC solves (``"auto"`` never appears here)."""

    qp: Literal["dense", "structured"]
    hessian: Literal["gauss_newton", "structured_secant", "exact"]


class StepTime(TypedDict):
    """The summary's ``step_time_us``: controller compute time per step (µs)."""

    mean: float
    p50: float
    p99: float
    max: float


class _SummaryKeys(TypedDict):
    controller: str
    dof: int
    payload_kg: float
    duration_s: float
    steps: int
    rms_force_n: Dict[str, Optional[float]]
    delta_max_deg: Dict[str, Optional[float]]
    mean_probability: Optional[List[float]]
    step_time_us: StepTime
    limit_violations: int
    solver_failures: int
    safety: Dict[str, Any]


class Summary(_SummaryKeys, total=False):
    """A run's summary (the keys of ``exompc simulate --json``), as :func:`simulate` and
    :func:`sweep` return it: ``rms_force_n`` ``{"thigh", "shank"}`` and ``delta_max_deg``
    ``{"hip", "knee"}`` (``None`` for a joint the run has not), ``mean_probability`` (``None``
    without scenarios), ``step_time_us``, ``limit_violations``, ``solver_failures``, ``safety``
    (monitor trips and held steps); only some runs have ``scenarios`` (multi-stage: the names
    in the order of ``mean_probability``), ``solver`` (controllers with an SQP: the QP back-end
    and Hessian model they ran, :class:`SolverChoice`; not for ``pd``) and ``trace``
    (:func:`simulate` with ``trace=True``: numpy columns)."""

    scenarios: List[str]
    solver: SolverChoice
    trace: Dict[str, np.ndarray]


def simulate(
    scenario: Optional[Scenario] = None,
    *,
    controller: Optional[str] = None,
    payload: Optional[float] = None,
    dof: int = 2,
    duration: Optional[float] = None,
    formulation: Optional[str] = None,
    trace: bool = True,
    cancel: Optional[CancelToken] = None,
) -> Summary:
    """Run one closed-loop experiment; return its summary dict (+ ``"trace"`` columns).

    The summary (:class:`Summary`) has the keys of ``exompc simulate --json``
    (``rms_force_n``, ``delta_max_deg``, ``mean_probability``, ``step_time_us``,
    ``limit_violations``, ``solver_failures``, ``safety``; ``solver``, e.g.
    ``{"qp": "dense", "hessian": "structured_secant"}``, for a controller with an SQP;
    ...). ``trace`` (unless ``trace=False``) maps column names to numpy
    arrays with one row per control step: ``t``, ``q_robot``, ``qd_robot``, ``q_human``,
    ``qd_human``, ``q_desired``, ``torque_robot``, ``torque_prev``, ``torque_human``,
    ``force_true``, ``force_measured`` (shape ``(steps, dof)``), ``probabilities``
    ``(steps, S)`` and ``disturbances`` ``(steps, S, dof)`` for the multi-stage controller,
    ``status`` (strings), ``status_code``, ``iterations``, ``step_time_us``,
    ``within_limits``. The GIL is released while the simulation runs.

    Raises ``ConfigError`` (a ``ValueError``) for a bad argument, or a run whose trace would
    not fit in 80 % of the available memory (the message names the limit; ``trace=False``
    needs 16 B per step); ``RunError`` if the plant diverges or ``cancel`` (a
    :class:`CancelToken`) is cancelled; ``KeyboardInterrupt`` on Ctrl-C (within about 50 ms).
    """
    raw = _core.simulate(
        scenario,
        controller=controller,
        payload=payload,
        dof=dof,
        duration=duration,
        formulation=formulation,
        trace=trace,
        cancel=cancel,
    )
    out = cast(Summary, raw)
    tr = out.get("trace")
    if tr is not None:
        codes = tr.pop("status")
        tr["status_code"] = codes
        tr["status"] = np.asarray(STATUS_NAMES)[codes]
    return out


class MultiStage(Controller):
    """The multi-stage robust NMPC (paper §3.2): ``MultiStage(scenario, dof=2)``."""

    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: Literal[1, 2] = 2, supervised: bool = True) -> "MultiStage":
        return super().__new__(cls, scenario, "msnmpc", dof=dof, supervised=supervised)


class Nmpc(Controller):
    """The non-robust NMPC on the nominal model (paper §3.1): ``Nmpc(scenario, dof=2)``."""

    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: Literal[1, 2] = 2, supervised: bool = True) -> "Nmpc":
        return super().__new__(cls, scenario, "nmpc", dof=dof, supervised=supervised)


class Pd(Controller):
    """The baseline PD on the estimated human intent: ``Pd(scenario, dof=2)``."""

    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: Literal[1, 2] = 2, supervised: bool = True) -> "Pd":
        return super().__new__(cls, scenario, "pd", dof=dof, supervised=supervised)


def sweep(
    scenario: Optional[Scenario] = None,
    payloads: Iterable[float] = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0),
    controllers: Sequence[str] = ("nmpc", "msnmpc"),
    *,
    dof: int = 2,
    threads: Optional[int] = None,
    cancel: Optional[CancelToken] = None,
) -> List[Summary]:
    """Every payload x controller run of ``scenario`` in parallel (like ``exompc sweep``).

    Returns one summary dict (:class:`Summary`, without ``trace``) per run, payload-major in
    the order given, then controllers.
    Ctrl-C raises ``KeyboardInterrupt``; ``cancel`` stops it from another thread (``RunError``).
    """
    base = scenario if scenario is not None else Scenario.default()
    runs = []
    for p in payloads:
        for c in controllers:
            runs.append(base.replace({"uncertainty.payload_kg": float(p), "controller.kind": c}))
    return cast(List[Summary], run_many(runs, dof=dof, threads=threads, cancel=cancel))


def scan(
    grid: Mapping[str, Iterable[Any]],
    scenario: Optional[Scenario] = None,
    *,
    dof: int = 2,
    threads: Optional[int] = None,
    errors: Literal["raise", "return"] = "return",
    cancel: Optional[CancelToken] = None,
) -> Dict[str, np.ndarray]:
    """Envelope scan: every combination of the dotted-key values in ``grid``, run in parallel.

    ``scan({"uncertainty.payload_kg": [0, 1, 2], "human.body_mass_kg": [60, 80]})`` returns a
    table (dict of numpy columns, one row per combination) with the grid keys and the
    flattened summaries (see :func:`summary_row`). A run that fails (e.g. diverges) gets NaN
    metrics and its message in the ``error`` column unless ``errors="raise"``.
    """
    base = scenario if scenario is not None else Scenario.default()
    keys = list(grid)
    combos = list(itertools.product(*(list(grid[k]) for k in keys)))
    if errors not in ("raise", "return"):
        raise ValueError(f"errors: {errors!r} (allowed: 'raise' or 'return')")
    rows: List[Dict[str, Any]] = []
    runs: List[Scenario] = []
    valid: List[int] = []
    for i, c in enumerate(combos):
        rows.append(dict(zip(keys, c)))
        try:
            runs.append(base.replace(dict(zip(keys, c))))
            valid.append(i)
        except ConfigError as e:
            if errors == "raise":
                raise
            rows[i]["error"] = str(e)
    for i, r in zip(valid, run_many(runs, dof=dof, threads=threads, errors=errors, cancel=cancel)):
        rows[i].update(summary_row(r))
    return _table(rows)


def envelope(
    scenario: Optional[Scenario] = None,
    *,
    sets: Optional[Mapping[str, Iterable[Any]]] = None,
    payloads: Optional[Sequence[float]] = None,
    controllers: Optional[Sequence[str]] = None,
    dof: int = 2,
    monitors: bool = True,
    cancel: Optional[CancelToken] = None,
) -> Dict[str, Any]:
    """The operating-envelope scan of ``exompc envelope`` (docs/ROBUSTNESS.md).

    Without ``sets`` the standard envelope runs; ``sets={"uncertainty.filter_window": [1, 5, 9]}``
    scans the Cartesian product of the given dotted-key values instead. Every run is classified
    (stable / limit_cycle / growing / saturating) and every cell judged (MS-NMPC against NMPC).
    Returns the content of ``envelope.json`` as a dict: ``grid``, ``runs``, ``verdicts``.
    ``monitors=False`` scans the bare controller (safety monitors out of reach).
    Ctrl-C raises ``KeyboardInterrupt``; ``cancel`` stops it from another thread (``RunError``).
    """
    import json

    specs = [f"{k}={','.join(_toml_value(v) for v in vals)}" for k, vals in (sets or {}).items()]
    text = _core.envelope_json(
        scenario,
        sets=specs,
        payloads=None if payloads is None else [float(p) for p in payloads],
        controllers=None if controllers is None else list(controllers),
        dof=dof,
        monitors=monitors,
        cancel=cancel,
    )
    return json.loads(text)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return v
    return repr(v)


def table2(rows: Sequence[Mapping[str, Any]]) -> str:
    """The paper's Table 2 (RMS strap forces, max angle errors) as Markdown from summaries."""
    lines = [
        "| controller | payload (kg) | RMS F thigh (N) | RMS F shank (N) | max dq hip (deg) | max dq knee (deg) |",
        "|---|---|---|---|---|---|",
    ]
    f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    for r in rows:
        lines.append(
            f"| {r['controller']} | {r['payload_kg']:.2f} | {f(r['rms_force_n']['thigh'])} | "
            f"{f(r['rms_force_n']['shank'])} | {f(r['delta_max_deg']['hip'])} | "
            f"{f(r['delta_max_deg']['knee'])} |"
        )
    return "\n".join(lines)


def _table(rows: Sequence[Mapping[str, Any]]) -> Dict[str, np.ndarray]:
    from .montecarlo import _columns

    return _columns(rows)
