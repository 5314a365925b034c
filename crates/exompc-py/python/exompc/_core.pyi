"""Type stubs of the native module ``exompc._core`` (re-exported by ``exompc``)."""

from os import PathLike
from typing import Any, Dict, List, Literal, Mapping, Optional, Sequence, Tuple, TypeVar, Union, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "STATUS_NAMES",
    "TRACE_COLUMNS",
    "CancelToken",
    "ConfigError",
    "Controller",
    "RunError",
    "Scenario",
    "Simulator",
    "__version__",
    "_raise_panic",
    "default_config_toml",
    "envelope_json",
    "run_many",
    "simulate",
]

_C = TypeVar("_C", bound="Controller")

__version__: str
STATUS_NAMES: List[str]
TRACE_COLUMNS: List[Dict[str, Optional[str]]]

_FloatVec = Union[npt.NDArray[np.float64], Sequence[float], float]
_Status = Literal["ok", "max_iterations", "max_time", "solver_failed", "bad_measurement", "monitor_tripped"]

class ConfigError(ValueError):
    """A scenario value, key or argument is invalid (or a run too long for the memory
    available); the message names the field and its allowed range or the limit."""

class RunError(RuntimeError):
    """A run could not complete (the simulated plant diverged) or was cancelled."""

@final
class CancelToken:
    """Stops the long calls it is passed to (``cancel=``) between two control steps, from any
    thread; they raise ``RunError``. A cancelled token stays cancelled."""

    def __init__(self) -> None: ...
    def cancel(self) -> None: ...
    @property
    def cancelled(self) -> bool: ...

@final
class Scenario:
    """A complete, validated scenario; keys are dotted paths such as ``"uncertainty.payload_kg"``."""

    def __new__(cls, toml: Optional[str] = None) -> Scenario: ...
    @staticmethod
    def default() -> Scenario: ...
    @staticmethod
    def load(path: Union[str, PathLike[str]]) -> Scenario: ...
    @staticmethod
    def from_toml(text: str) -> Scenario: ...
    def to_toml(self) -> str: ...
    def save(self, path: Union[str, PathLike[str]]) -> None: ...
    def get(self, key: str) -> Any: ...
    def set(self, key: str, value: Any) -> None: ...
    def replace(self, updates: Optional[Mapping[str, Any]] = None, **kwargs: Any) -> Scenario: ...
    def keys(self) -> List[str]: ...
    def to_dict(self) -> Dict[str, Any]: ...
    def validate(self) -> None: ...
    def copy(self) -> Scenario: ...
    def __copy__(self) -> Scenario: ...
    def __deepcopy__(self, memo: Any) -> Scenario: ...
    def __getitem__(self, key: str, /) -> Any: ...
    def __setitem__(self, key: str, value: Any, /) -> None: ...
    def __eq__(self, other: object, /) -> bool: ...

class Controller:
    """A feedback controller of the scenario with one ``step`` call per control period.

    Bound to the thread that created it: a call from another thread raises ``RuntimeError``.
    """

    def __new__(
        cls: type[_C],
        scenario: Optional[Scenario] = None,
        kind: Optional[Literal["pd", "nmpc", "msnmpc"]] = None,
        *,
        dof: Literal[1, 2] = 2,
        supervised: bool = True,
    ) -> _C: ...
    def step(
        self,
        t: float,
        q: _FloatVec,
        qd: _FloatVec,
        force: _FloatVec,
        out: Optional[npt.NDArray[np.float64]] = None,
    ) -> Tuple[npt.NDArray[np.float64], _Status]: ...
    def reset(self) -> None: ...
    @property
    def name(self) -> str: ...
    @property
    def dof(self) -> int: ...
    @property
    def scenario(self) -> Scenario: ...
    @property
    def probabilities(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def disturbances(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def previous_torque(self) -> npt.NDArray[np.float64]: ...

@final
class Simulator:
    """The simulated plant and sensor chain, to close the loop from Python (thread-safe)."""

    def __new__(cls, scenario: Optional[Scenario] = None, *, dof: Literal[1, 2] = 2) -> Simulator: ...
    @property
    def steps(self) -> int: ...
    @property
    def dt(self) -> float: ...
    @property
    def t(self) -> float: ...
    def measure(
        self,
    ) -> Tuple[float, npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    def advance(self, torque: _FloatVec) -> None: ...
    def state(self) -> Dict[str, Any]: ...

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
def run_many(
    scenarios: Sequence[Scenario],
    *,
    dof: int = 2,
    threads: Optional[int] = None,
    errors: Literal["raise", "return"] = "raise",
    cancel: Optional[CancelToken] = None,
) -> List[Dict[str, Any]]: ...
def default_config_toml() -> str: ...
def envelope_json(
    scenario: Optional[Scenario] = None,
    *,
    sets: Sequence[str] = ...,
    payloads: Optional[Sequence[float]] = None,
    controllers: Optional[Sequence[str]] = None,
    dof: int = 2,
    monitors: bool = True,
    cancel: Optional[CancelToken] = None,
) -> str: ...
def _raise_panic(message: str, in_run: bool = False) -> None:
    """Internal: raises a Rust panic to test that it arrives as ``RuntimeError``."""
