"""Type stubs of the ``exompc`` package."""

from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence

import numpy as np

from ._core import (
    STATUS_NAMES as STATUS_NAMES,
    CancelToken as CancelToken,
    ConfigError as ConfigError,
    Controller as Controller,
    RunError as RunError,
    Scenario as Scenario,
    Simulator as Simulator,
    __version__ as __version__,
    default_config_toml as default_config_toml,
    run_many as run_many,
)
from .montecarlo import (
    Choice as Choice,
    Normal as Normal,
    Uniform as Uniform,
    draw_parameters as draw_parameters,
    montecarlo as montecarlo,
    summary_row as summary_row,
    write_csv as write_csv,
)

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
) -> Dict[str, Any]: ...

class MultiStage(Controller):
    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: int = 2, supervised: bool = True) -> MultiStage: ...

class Nmpc(Controller):
    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: int = 2, supervised: bool = True) -> Nmpc: ...

class Pd(Controller):
    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: int = 2, supervised: bool = True) -> Pd: ...

def sweep(
    scenario: Optional[Scenario] = None,
    payloads: Iterable[float] = ...,
    controllers: Sequence[str] = ...,
    *,
    dof: int = 2,
    threads: Optional[int] = None,
    cancel: Optional[CancelToken] = None,
) -> List[Dict[str, Any]]: ...
def scan(
    grid: Mapping[str, Iterable[Any]],
    scenario: Optional[Scenario] = None,
    *,
    dof: int = 2,
    threads: Optional[int] = None,
    errors: str = "return",
    cancel: Optional[CancelToken] = None,
) -> Dict[str, np.ndarray]: ...
def table2(rows: Sequence[Mapping[str, Any]]) -> str: ...

def envelope(
    scenario: Optional[Scenario] = None,
    *,
    sets: Optional[Mapping[str, Iterable[Any]]] = None,
    payloads: Optional[Sequence[float]] = None,
    controllers: Optional[Sequence[str]] = None,
    dof: int = 2,
    monitors: bool = True,
    cancel: Optional[CancelToken] = None,
) -> Dict[str, Any]: ...
