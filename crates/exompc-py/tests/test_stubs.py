"""The type stubs are the one place of the Python signatures: mypy's stubtest compares them
with the installed package (the native module's text signatures and ``__all__``, and the
Python wrappers), so a function, argument or default added on one side only fails here."""

import subprocess
import sys

import pytest


def test_stubs_match_the_runtime(tmp_path):
    pytest.importorskip("mypy", reason="mypy is needed for stubtest (.ci/run installs it)")
    r = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "--ignore-disjoint-bases", "exompc"],
        capture_output=True,
        text=True,
        cwd=tmp_path,  # the installed package, not a source folder
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Success" in r.stdout, r.stdout
