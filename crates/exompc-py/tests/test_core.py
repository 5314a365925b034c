"""The Python package against the Rust library: same numbers, same checks, same messages."""

import copy
import csv
import json
import pathlib
import pickle
import subprocess
import threading
import time

import numpy as np
import pytest

import exompc

TIMING_FREE = ("controller", "dof", "payload_kg", "duration_s", "steps", "rms_force_n",
               "delta_max_deg", "mean_probability", "limit_violations", "solver_failures")


def cli_run(exompc_bin, tmp_path, args, toml=None):
    """`exompc simulate --json` with `args` (and a config file holding `toml`)."""
    cmd = [str(exompc_bin), "simulate", "--json", "--out", str(tmp_path / "out")] + args
    if toml is not None:
        cfg = tmp_path / "scenario.toml"
        cfg.write_text(toml)
        cmd += ["--config", str(cfg)]
    res = subprocess.run(cmd, check=True, capture_output=True, text=True)
    summary = json.loads(res.stdout)
    with open(tmp_path / "out" / "trace.csv") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], rows[1:]
    cols = {}
    for i, h in enumerate(header):
        try:
            cols[h] = np.array([r[i] for r in data], dtype=np.float64)
        except ValueError:
            cols[h] = [r[i] for r in data]
    return summary, cols


def assert_close(a, b, path=""):
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            assert_close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-12, abs=1e-12), path
    else:
        assert a == b, path


CASES = [
    ("default", [], None, {}),
    ("nmpc-1dof-payload", ["--dof", "1", "--controller", "nmpc", "--payload", "1.5"], None,
     {"dof": 1, "controller": "nmpc", "payload": 1.5}),
    ("pd-coupled-file", ["--controller", "pd", "--duration", "5"],
     "[uncertainty]\npayload_kg = 0.75\n[controller]\nnp = 4\nnc = 4\n",
     {"controller": "pd", "duration": 5.0}),
    ("msnmpc-coupled", ["--formulation", "coupled", "--duration", "5"], None,
     {"formulation": "coupled", "duration": 5.0}),
]


@pytest.mark.parametrize("name,args,toml,kwargs", CASES, ids=[c[0] for c in CASES])
def test_equals_rust_library(exompc_bin, tmp_path, name, args, toml, kwargs):
    """Summary and every trace column equal the CLI's (the Rust library) to 1e-12."""
    ref, ref_trace = cli_run(exompc_bin, tmp_path, args, toml)
    s = exompc.Scenario.from_toml(toml) if toml else exompc.Scenario.default()
    got = exompc.simulate(s, **kwargs)
    for k in TIMING_FREE:
        assert_close(got[k], ref[k], k)
    tr = got["trace"]
    joints = ["knee"] if got["dof"] == 1 else ["hip", "knee"]
    straps = ["shank"] if got["dof"] == 1 else ["thigh", "shank"]
    np.testing.assert_allclose(tr["t"], ref_trace["t"], rtol=1e-12, atol=1e-12)
    for col in ("q_robot", "qd_robot", "q_human", "qd_human", "q_desired", "torque_robot",
                "torque_human"):
        for j, name_j in enumerate(joints):
            np.testing.assert_allclose(tr[col][:, j], ref_trace[f"{col}_{name_j}"],
                                       rtol=1e-12, atol=1e-12, err_msg=col)
    for col in ("force_true", "force_measured"):
        for j, name_s in enumerate(straps):
            np.testing.assert_allclose(tr[col][:, j], ref_trace[f"{col}_{name_s}"],
                                       rtol=1e-12, atol=1e-12, err_msg=col)
    if "probabilities" in tr:
        for i in range(tr["probabilities"].shape[1]):
            np.testing.assert_allclose(tr["probabilities"][:, i], ref_trace[f"mu_{i + 1}"],
                                       rtol=1e-12, atol=1e-12)
            for j, name_j in enumerate(joints):
                np.testing.assert_allclose(tr["disturbances"][:, i, j],
                                           ref_trace[f"dist_{i + 1}_{name_j}"],
                                           rtol=1e-12, atol=1e-12)
    assert list(tr["status"]) == ref_trace["status"]
    np.testing.assert_array_equal(tr["iterations"], ref_trace["iterations"])


def test_default_rms_force_matches_cli(exompc_bin, tmp_path):
    """The issue's smoke check: `simulate(Scenario.default())['rms_force_n']` == CLI's."""
    ref, _ = cli_run(exompc_bin, tmp_path, [])
    assert exompc.simulate(exompc.Scenario.default())["rms_force_n"] == ref["rms_force_n"]


@pytest.mark.parametrize("kind,dof", [("msnmpc", 2), ("nmpc", 2), ("pd", 2), ("msnmpc", 1)])
def test_step_loop_matches_simulate(kind, dof):
    """Simulator + Controller.step in a Python loop reproduce simulate() step for step."""
    s = exompc.Scenario.default().replace({"controller.kind": kind, "timing.duration_2dof_s": 8.0,
                                           "timing.duration_1dof_s": 8.0})
    ref = exompc.simulate(s, dof=dof)["trace"]
    sim = exompc.Simulator(s, dof=dof)
    ctl = exompc.Controller(s, dof=dof)
    assert sim.steps == len(ref["t"])
    statuses = []
    for k in range(sim.steps):
        t, q, qd, f = sim.measure()
        assert t == ref["t"][k]
        np.testing.assert_array_equal(q, ref["q_robot"][k])
        np.testing.assert_array_equal(f, ref["force_measured"][k])
        torque, status = ctl.step(t, q, qd, f)
        np.testing.assert_array_equal(torque, ref["torque_robot"][k], err_msg=f"step {k}")
        if kind == "msnmpc":
            np.testing.assert_array_equal(ctl.probabilities, ref["probabilities"][k])
            np.testing.assert_array_equal(ctl.disturbances, ref["disturbances"][k])
        statuses.append(status)
        sim.advance(torque)
    assert statuses == list(ref["status"])


def test_reset_restarts_the_controller():
    s = exompc.Scenario.default()
    ctl = exompc.MultiStage(s)

    def run():
        sim, out = exompc.Simulator(s), []
        for _ in range(200):
            torque, _ = ctl.step(*sim.measure())
            sim.advance(torque)
            out.append(torque)
        return np.array(out)

    first = run()
    assert not np.allclose(ctl.probabilities, 1 / 3)
    ctl.reset()
    np.testing.assert_array_equal(ctl.probabilities, [1 / 3] * 3)
    np.testing.assert_array_equal(run(), first)


def test_controller_objects():
    s = exompc.Scenario.default()
    ms = exompc.MultiStage(s)
    assert isinstance(ms, exompc.Controller) and ms.name == "msnmpc" and ms.dof == 2
    assert ms.probabilities.shape == (3,) and ms.disturbances.shape == (3, 2)
    pd = exompc.Pd(s, dof=1)
    assert pd.name == "pd" and pd.probabilities is None and pd.disturbances is None
    assert exompc.Nmpc(s).name == "nmpc"
    assert exompc.Controller(s).name == s["controller.kind"]
    # out= writes in place and returns the same array
    out = np.zeros(2)
    sim = exompc.Simulator(s)
    torque, status = ms.step(*sim.measure(), out=out)
    assert torque is out and status == "ok" and np.any(out != 0)
    # a non-finite measurement is rejected by the supervisor; the torque stays in limits
    torque, status = ms.step(0.01, np.array([np.nan, 0.0]), np.zeros(2), np.zeros(2))
    assert status == "bad_measurement"
    assert np.all(np.isfinite(torque)) and np.all(np.abs(torque) <= s["controller.torque_max"])


def test_trace_columns_and_summary():
    r = exompc.simulate(duration=2.0)
    tr = r["trace"]
    n = r["steps"]
    assert n == 200 and tr["t"].shape == (n,) and tr["q_robot"].shape == (n, 2)
    assert tr["probabilities"].shape == (n, 3) and tr["disturbances"].shape == (n, 3, 2)
    assert tr["status"].dtype.kind == "U" and set(tr["status"]) <= set(exompc.STATUS_NAMES)
    assert tr["within_limits"].dtype == np.bool_ and tr["within_limits"].all()
    np.testing.assert_allclose(tr["probabilities"].sum(axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.mean(tr["force_true"] ** 2, axis=0)),
                               [r["rms_force_n"]["thigh"], r["rms_force_n"]["shank"]], rtol=1e-12)
    assert "trace" not in exompc.simulate(duration=1.0, trace=False)


def test_trace_keys_are_the_column_tables():
    # One table (the library's sim::trace::TRACE_COLUMNS) names the CSV columns, these keys and
    # the docs' column table: a key added here only, or there only, fails.
    keys = {c["python"] for c in exompc.TRACE_COLUMNS if c["python"]}
    tr = exompc.simulate(duration=0.5)["trace"]
    assert set(tr) == keys | {"status_code"}
    tr = exompc.simulate(duration=0.5, controller="nmpc")["trace"]
    assert set(tr) == keys - {"probabilities", "disturbances"} | {"status_code"}
    for c in exompc.TRACE_COLUMNS:
        assert c["per"] in {"step", "joint", "strap", "scenario", "scenario_joint"} and c["unit"]


def test_summary_keys_are_the_typed_dict():
    # exompc.Summary types the summary: a key the library adds (or drops) without the TypedDict
    # fails here; `solver` holds one of the values its Literal types allow.
    from typing import get_args, get_type_hints

    required, optional = exompc.Summary.__required_keys__, exompc.Summary.__optional_keys__
    choice = get_type_hints(exompc.SolverChoice)
    for kind, solver in (("msnmpc", True), ("nmpc", True), ("pd", False)):
        r = exompc.simulate(duration=0.2, controller=kind)
        assert required <= set(r) <= required | optional, kind
        assert ("solver" in r) == solver, kind
        if solver:
            assert set(r["solver"]) == set(choice)
            for k, v in r["solver"].items():
                assert v in get_args(choice[k]), (kind, k, v)
    assert set(exompc.Summary.__annotations__) | set(exompc._SummaryKeys.__annotations__) \
        >= set(TIMING_FREE)


def test_bad_values_raise_naming_the_field():
    s = exompc.Scenario.default()
    cases = [
        ("uncertainty.payload_kg", -1.0, "uncertainty.payload_kg"),
        ("uncertainty.payload_kg", float("nan"), "uncertainty.payload_kg"),
        ("controller.np", 0, "controller.np"),
        ("controller.np", 2.5, "controller.np"),
        ("timing.dt", "fast", "timing.dt"),
        ("controller.kind", "lqr", "controller.kind"),
        ("uncertainty.payloadkg", 1.0, "did you mean `payload_kg`"),
        ("robot.thigh.mass_kg", [1, 2], "robot.thigh.mass_kg"),
    ]
    for key, value, needle in cases:
        with pytest.raises(exompc.ConfigError, match=needle.replace(".", r"\.").replace("`", ".")):
            s[key] = value
        assert s == exompc.Scenario.default(), "a failed set leaves the scenario unchanged"
    with pytest.raises(ValueError, match="payload: .*uncertainty.payload_kg"):
        exompc.simulate(payload=-2.0)
    with pytest.raises(ValueError, match="duration: .*timing.duration_2dof_s"):
        exompc.simulate(duration=-1.0)
    with pytest.raises(ValueError, match="controller: .*controller.kind"):
        exompc.simulate(controller="lqr")
    with pytest.raises(ValueError, match="dof: 3"):
        exompc.simulate(dof=3)
    with pytest.raises(exompc.ConfigError, match="human.height_m: expected a number"):
        exompc.Scenario.from_toml("[human]\nheight_m = 'tall'\n")
    with pytest.raises(FileNotFoundError, match="cannot read scenario file"):
        exompc.Scenario.load("/nonexistent/scenario.toml")
    with pytest.raises(exompc.ConfigError, match="controller.kind"):
        exompc.Controller(s, "lqr")


def test_wrong_shapes_and_dtypes_raise():
    ctl = exompc.MultiStage()
    z = np.zeros(2)
    bad = [
        (np.zeros(3), ValueError, r"q: expected shape \(2,\), got \(3,\)"),
        (np.zeros((2, 1)), ValueError, r"q: expected shape \(2,\), got \(2, 1\)"),
        (np.zeros(2, dtype=np.int64), TypeError, "q: expected a float64 array"),
        (np.zeros(2, dtype=np.float32), TypeError, "q: expected a float64 array"),
        ([0.0, 0.0, 0.0], ValueError, "q: expected 2 values, got 3"),
        ([0.0, "a"], TypeError, r"q\[1\]: expected a number"),
        ("00", TypeError, "q: expected a float64 numpy array"),
        (None, TypeError, "q: expected"),
    ]
    for q, exc, msg in bad:
        with pytest.raises(exc, match=msg):
            ctl.step(0.0, q, z, z)
    with pytest.raises(ValueError, match="force: expected shape"):
        ctl.step(0.0, z, z, np.zeros(1))
    with pytest.raises(ValueError, match=r"out: expected shape \(2,\)"):
        ctl.step(0.0, z, z, z, out=np.zeros(3))
    with pytest.raises(TypeError, match="out: expected a float64"):
        ctl.step(0.0, z, z, z, out=np.zeros(2, dtype=np.int32))
    with pytest.raises(ValueError, match="torque: expected shape"):
        exompc.Simulator().advance(np.zeros(1))
    # accepted forms: lists, non-contiguous float64 views, a scalar for 1-DOF
    ctl.step(0.0, [0.0, 0.1], np.zeros(4)[::2], (0.0, 0.0))
    exompc.Pd(dof=1).step(0.0, 0.1, [0.0], np.zeros(1))


def test_gil_released_during_run():
    """A second Python thread keeps running while simulate() runs in Rust."""
    stamps = []
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            stamps.append(time.perf_counter())
            time.sleep(0)

    th = threading.Thread(target=spin)
    th.start()
    try:
        time.sleep(0.01)
        t0 = time.perf_counter()
        exompc.simulate(duration=40.0, trace=False)
        t1 = time.perf_counter()
    finally:
        stop.set()
        th.join()
    mid = [x for x in stamps if t0 + 0.25 * (t1 - t0) < x < t0 + 0.75 * (t1 - t0)]
    # With the GIL held for the whole run the thread could not record anything mid-run.
    assert len(mid) > 10, f"{len(mid)} samples of the second thread during the run"


def test_scenario_io_roundtrip(tmp_path):
    s = exompc.Scenario.default()
    s["uncertainty.payload_kg"] = 1.25
    s["multistage.formulation"] = "coupled"
    s["controller.sqp.max_time_us"] = 500
    p = tmp_path / "s.toml"
    s.save(p)
    assert exompc.Scenario.load(p) == s
    assert exompc.Scenario.from_toml(s.to_toml()) == s
    assert pickle.loads(pickle.dumps(s)) == s
    assert copy.deepcopy(s) == s and s.copy() == s
    assert exompc.Scenario() == exompc.Scenario.default()
    assert s["uncertainty.payload_kg"] == 1.25 and s.get("multistage.formulation") == "coupled"
    assert exompc.Scenario.default()["controller.sqp.max_time_us"] is None
    assert s.to_dict()["uncertainty"]["payload_kg"] == 1.25
    keys = s.keys()
    assert "uncertainty.payload_kg" in keys and "controller.sqp.max_iterations" in keys
    for k in keys:
        s.set(k, s.get(k))  # every key round-trips through get/set
    r = s.replace({"uncertainty.payload_kg": 0.5}, **{"controller.np": 4})
    assert r["uncertainty.payload_kg"] == 0.5 and r["controller.np"] == 4
    assert s["uncertainty.payload_kg"] == 1.25
    s["uncertainty.payload_kg"] = np.float64(0.25)
    s["controller.nc"] = np.int64(2)
    assert s["uncertainty.payload_kg"] == 0.25 and s["controller.nc"] == 2
    assert exompc.default_config_toml().startswith("# exompc scenario")


def test_sweep_and_scan_match_single_runs():
    s = exompc.Scenario.default().replace({"timing.duration_2dof_s": 3.0})
    rows = exompc.sweep(s, payloads=[0.0, 1.0], controllers=["nmpc", "msnmpc"])
    assert [(r["payload_kg"], r["controller"]) for r in rows] == [
        (0.0, "nmpc"), (0.0, "msnmpc"), (1.0, "nmpc"), (1.0, "msnmpc")]
    one = exompc.simulate(s, controller="msnmpc", payload=1.0, trace=False)
    for k in TIMING_FREE:
        assert rows[3][k] == one[k]
    assert "| msnmpc | 1.00 |" in exompc.table2(rows)
    tab = exompc.scan({"uncertainty.payload_kg": [0.0, 2.0], "timing.dt": [0.01, -1.0]}, s)
    assert list(tab["uncertainty.payload_kg"]) == [0.0, 0.0, 2.0, 2.0]
    assert list(tab["error"] != "") == [False, True, False, True]
    assert np.isnan(tab["rms_force_shank_n"][1]) and np.isfinite(tab["rms_force_shank_n"][0])
    with pytest.raises(exompc.ConfigError, match="timing.dt"):
        exompc.scan({"timing.dt": [-1.0]}, s, errors="raise")


def test_envelope_matches_the_cli(exompc_bin, tmp_path):
    """The envelope scan from Python equals `exompc envelope` on the same grid."""
    s = exompc.Scenario.default()
    s["timing.duration_2dof_s"] = 4.0
    s["controller.method"] = "paper"
    env = exompc.envelope(
        s, sets={"uncertainty.filter_window": [1, 9]}, payloads=[1.0]
    )
    cfg = tmp_path / "short.toml"
    s.save(str(cfg))
    subprocess.run(
        [exompc_bin, "envelope", "--quiet", "--config", str(cfg), "--set",
         "uncertainty.filter_window=1,9", "--payloads", "1", "--out", str(tmp_path / "env")],
        check=True, capture_output=True,
    )
    cli = json.loads((tmp_path / "env" / "envelope.json").read_text())
    assert [v["cell"] for v in env["verdicts"]] == [v["cell"] for v in cli["verdicts"]]
    assert len(env["runs"]) == 4
    for a, b in zip(env["runs"], cli["runs"]):
        assert a["stability"] == b["stability"]
        assert a["summary"]["rms_force_n"] == b["summary"]["rms_force_n"]
    # filter window 1 passes, 9 fails with the paper's method.
    passes = [v["verdict"]["pass"] for v in env["verdicts"]]
    assert passes == [True, False], passes
    with pytest.raises(exompc.ConfigError, match="payload_positon"):
        exompc.envelope(s, sets={"robot.payload_positon_m": [0.1]}, payloads=[0.0])
