"""Monte Carlo studies: reproducible draws, error rows, and Ray == local."""

import pathlib

import numpy as np
import pytest

import exompc
from exompc.montecarlo import write_csv

PARAMS = {
    "uncertainty.payload_kg": exompc.Uniform(0.0, 2.0),
    "human.body_mass_kg": exompc.Normal(75.0, 8.0, 50.0, 110.0),
    "controller.kind": exompc.Choice(["msnmpc", "nmpc"]),
}
TIMES = ("step_time_mean_us", "step_time_p50_us", "step_time_p99_us", "step_time_max_us")


def short():
    return exompc.Scenario.default().replace({"timing.duration_2dof_s": 2.0})


def assert_same_table(a, b):
    assert list(a) == list(b)
    for k in a:
        if k in TIMES:
            continue
        if a[k].dtype == object:
            assert list(a[k]) == list(b[k]), k
        else:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_draws_are_seeded_and_rows_match_single_runs():
    a = exompc.draw_parameters(5, PARAMS, seed=3)
    assert a == exompc.draw_parameters(5, PARAMS, seed=3)
    assert a != exompc.draw_parameters(5, PARAMS, seed=4)
    tab = exompc.montecarlo(5, PARAMS, short(), seed=3, progress=False)
    assert list(tab["draw"]) == list(range(5))
    assert list(tab["uncertainty.payload_kg"]) == a["uncertainty.payload_kg"]
    for i in range(5):
        s = short().replace({k: v[i] for k, v in a.items()})
        one = exompc.summary_row(exompc.simulate(s, trace=False))
        assert tab["rms_force_shank_n"][i] == one["rms_force_shank_n"]
        assert tab["controller"][i] == one["controller"]
    one_worker = exompc.montecarlo(5, PARAMS, short(), seed=3, workers=1, progress=False)
    assert_same_table(tab, one_worker)


def test_invalid_draws_become_error_rows(tmp_path):
    tab = exompc.montecarlo(4, {"uncertainty.payload_kg": exompc.Choice([1.0, 30.0])},
                            short(), seed=0, progress=False)
    bad = tab["uncertainty.payload_kg"] == 30.0
    assert bad.any() and (~bad).any()
    assert all("uncertainty.payload_kg" in e for e in tab["error"][bad])
    assert all(e == "" for e in tab["error"][~bad])
    assert np.isnan(tab["rms_force_shank_n"][bad]).all()
    write_csv(tab, str(tmp_path / "t.csv"))
    assert (tmp_path / "t.csv").read_text().startswith("draw,uncertainty.payload_kg")
    with pytest.raises(ValueError, match="backend"):
        exompc.montecarlo(2, {}, backend="spark")
    with pytest.raises(ValueError, match="draws"):
        exompc.montecarlo(0, {})


def test_ray_backend_equals_local():
    """20 draws on a local Ray instance give the same table as the local backend."""
    import ray
    local = exompc.montecarlo(20, PARAMS, short(), seed=11, progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = exompc.montecarlo(20, PARAMS, short(), seed=11, backend="ray", progress=False)
    finally:
        ray.shutdown()
    assert (local["error"] == "").all()
    assert_same_table(local, remote)


def test_recorded_gaits_are_a_parameter():
    root = pathlib.Path(__file__).resolve().parents[3]
    gaits = sorted(str(p) for p in (root / "examples" / "gaits").glob("walk_*hz.csv"))
    assert len(gaits) == 3
    params = {
        "trajectory.kind": exompc.Choice(["recorded"]),
        "trajectory.file": exompc.Choice(gaits),
    }
    tab = exompc.montecarlo(3, params, short(), seed=1, progress=False)
    assert list(tab["error"]) == ["", "", ""], tab["error"]
    for i in range(3):
        s = short().replace({"trajectory.kind": "recorded", "trajectory.file": tab["trajectory.file"][i]})
        one = exompc.simulate(s, trace=False)
        assert tab["rms_force_thigh_n"][i] == one["rms_force_n"]["thigh"]
    # Different gaits give different runs.
    by_gait = {f: r for f, r in zip(tab["trajectory.file"], tab["rms_force_thigh_n"])}
    if len(by_gait) > 1:
        assert len(set(by_gait.values())) == len(by_gait)
    # A kind without its file is still refused, naming the key.
    with pytest.raises(exompc.ConfigError, match="trajectory.file"):
        short().replace({"trajectory.kind": "recorded"})
