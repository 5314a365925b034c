"""The examples run end to end (short settings) and write what they promise."""

import pathlib
import subprocess
import sys

EX = pathlib.Path(__file__).resolve().parents[1] / "examples"


def run(script, *args, cwd):
    res = subprocess.run([sys.executable, str(EX / script), *args], cwd=cwd, check=True,
                         capture_output=True, text=True)
    return res.stdout


def test_python_plant(tmp_path):
    out = run("python_plant.py", "--steps", "300", "--plot", str(tmp_path / "p.png"), cwd=tmp_path)
    assert "RMS strap force" in out and (tmp_path / "p.png").stat().st_size > 0
    assert "'ok': 300" in out


def test_table2(tmp_path):
    out = run("table2.py", "--payloads", "0,2", "--out", str(tmp_path), cwd=tmp_path)
    assert "| msnmpc | 2.00 |" in out
    for f in ("table2.md", "table2.csv", "table2.png", "trace.png"):
        assert (tmp_path / f).stat().st_size > 0


def test_montecarlo_study(tmp_path):
    out = run("montecarlo_study.py", "--draws", "6", "--out", str(tmp_path), cwd=tmp_path)
    assert "6 draws on backend local" in out and "6 completed" in out
    assert len((tmp_path / "montecarlo.csv").read_text().splitlines()) == 7
    assert (tmp_path / "montecarlo.png").stat().st_size > 0
