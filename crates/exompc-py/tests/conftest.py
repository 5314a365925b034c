"""Shared fixtures: the Rust CLI binary used as the reference for the Python results."""

import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def exompc_bin() -> pathlib.Path:
    """The `exompc` CLI (the Rust library's own driver): $EXOMPC_BIN or target/release/exompc.

    Build it with `cargo build --release -p exompc-cli` (`.ci/run` does).
    """
    p = pathlib.Path(os.environ.get("EXOMPC_BIN", ROOT / "target" / "release" / "exompc"))
    if not p.is_file():
        pytest.fail(f"the exompc CLI is needed as the reference and was not found at {p}; "
                    "build it with `cargo build --release -p exompc-cli` or set EXOMPC_BIN")
    return p
