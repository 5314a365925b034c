"""Every error is a Python exception of a documented class, never a crash of the interpreter:
bad arguments, files, memory, threads, panics, Ctrl-C and cancellation."""

import errno
import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

import exompc

SHORT = exompc.Scenario.default().replace({"timing.duration_2dof_s": 0.5})


@pytest.mark.parametrize("duration", [1e308, float("inf"), float("nan"), -1.0, 0.0])
def test_out_of_range_durations_are_value_errors(duration):
    with pytest.raises(ValueError, match=r"duration: .*timing\.duration_2dof_s"):
        exompc.simulate(duration=duration)


def test_run_too_big_for_memory_is_a_value_error_naming_the_limit():
    """An absurd run is refused before anything is allocated (it used to abort the process).

    1e6 s at dt = 0.01 s is 1e8 steps: a 33-GB trace, above the 17.2-GB (16 GiB) most one
    call plans to keep on any machine (or 80 % of the memory available, if less)."""
    with pytest.raises(exompc.ConfigError, match=r"duration: 1000000 s at timing\.dt = 0\.01 s "
                       r"is 100000000 control steps; keeping them needs about 33\.4 GB \(334 B "
                       r"per step\), more than the limit of .* GB \(.*\); pass trace=False"):
        exompc.simulate(duration=1e6)
    long = exompc.Scenario.default().replace({"timing.duration_2dof_s": 1e6})
    with pytest.raises(ValueError, match=r"timing\.duration_2dof_s: 1000000 s .*limit"):
        exompc.simulate(long)
    with pytest.raises(ValueError, match=r"scenarios\[1\]: timing\.duration_2dof_s: .*, 12 "
                       r"runs at once; .*fewer threads"):
        exompc.run_many([SHORT] + [long] * 11, threads=12)
    with pytest.raises(ValueError, match=r"cell `.*`: timing\.duration_2dof_s: .*limit"):
        exompc.envelope(long, payloads=[0.0])
    # The process is still fine.
    assert exompc.simulate(SHORT, trace=False)["steps"] == 50


def test_bad_arguments_are_value_errors():
    cases = [
        (lambda: exompc.simulate(dof=300), "dof: 300 .allowed: 1 or 2."),
        (lambda: exompc.simulate(dof=-1), "dof: -1"),
        (lambda: exompc.Controller(dof=0), "dof: 0"),
        (lambda: exompc.Simulator(dof=3), "dof: 3"),
        (lambda: exompc.run_many([SHORT], threads=0), "threads: 0 .allowed: 1 to 1024"),
        (lambda: exompc.run_many([SHORT], threads=-5), "threads: -5"),
        (lambda: exompc.run_many([SHORT], threads=10**9), "threads: 1000000000"),
        (lambda: exompc.run_many([SHORT], errors="ignore"), "errors: `ignore`"),
        (lambda: exompc.envelope(SHORT, dof=5), "dof: 5"),
        (lambda: exompc.envelope(SHORT, sets={"no.such_key": [1]}), "no.such_key"),
        (lambda: exompc.envelope(SHORT, payloads=[-1.0], controllers=["pd"]), "payload"),
        (lambda: exompc.envelope(SHORT, payloads=[0.0], controllers=["lqr"]), "lqr"),
        (lambda: exompc.montecarlo(0, {}), "draws: 0"),
        (lambda: exompc.montecarlo(2, {}, backend="dask"), "backend"),
        (lambda: exompc.scan({"timing.dt": [1.0]}, SHORT, errors="skip"), "errors"),
    ]
    for call, msg in cases:
        with pytest.raises(ValueError, match=msg):
            call()
    nested = []
    for _ in range(10_000):  # would overflow the stack if converted recursively
        nested = [nested]
    with pytest.raises(exompc.ConfigError, match="nested deeper than 16 levels"):
        SHORT.copy()["controller.np"] = nested
    with pytest.raises(exompc.ConfigError, match="TOML syntax error"):
        exompc.Scenario.from_toml("a = " + "[" * 100_000)


def test_read_only_out_array_is_a_value_error():
    ctl = exompc.MultiStage(SHORT)
    out = np.zeros(2)
    out.flags.writeable = False
    z = np.zeros(2)
    with pytest.raises(ValueError, match="out: cannot write into the array: .*not writeable"):
        ctl.step(0.0, z, z, z, out=out)
    torque, status = ctl.step(0.0, z, z, z)
    assert status == "ok" and torque.shape == (2,)


def test_file_errors_are_os_errors(tmp_path):
    s = SHORT.copy()
    with pytest.raises(FileNotFoundError) as e:
        exompc.Scenario.load(tmp_path / "missing.toml")
    assert e.value.errno == errno.ENOENT and e.value.filename == str(tmp_path / "missing.toml")
    assert "cannot read scenario file" in str(e.value)
    with pytest.raises(IsADirectoryError):
        exompc.Scenario.load(tmp_path)
    with pytest.raises(FileNotFoundError, match="cannot save scenario to"):
        s.save(tmp_path / "no" / "such" / "folder.toml")
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError):
        s.save(tmp_path / "file" / "s.toml")
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[timing]\n")
    with pytest.raises(exompc.ConfigError, match="not UTF-8"):
        exompc.Scenario.load(bad)
    with pytest.raises(exompc.ConfigError, match="/dev/zero: larger than 16 MiB"):
        exompc.Scenario.load("/dev/zero")
    # A read-only folder: PermissionError (as root, where permissions do not bind, a
    # file system that refuses new files stands in).
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        target = ro / "s.toml" if os.geteuid() != 0 else "/sys/exompc-test.toml"
        with pytest.raises(OSError) as e:
            s.save(target)
        assert e.value.errno in (errno.EACCES, errno.EPERM, errno.EROFS), e.value
        if os.geteuid() != 0:
            assert isinstance(e.value, PermissionError)
        assert os.listdir(ro) == [], "no temporary file left behind"
    finally:
        ro.chmod(0o755)
    s.save(tmp_path / "ok.toml")
    assert exompc.Scenario.load(tmp_path / "ok.toml") == s
    assert sorted(os.listdir(tmp_path)) == ["bad.toml", "file", "ok.toml", "ro"]


def test_diverged_run_is_a_run_error():
    """A plant step too long for RK4 diverges: RunError (a RuntimeError) with the time."""
    s = SHORT.replace({"timing.dt": 0.2, "timing.plant_substeps": 1,
                       "timing.duration_2dof_s": 10.0})
    with pytest.raises(exompc.RunError, match="diverged at t = 0.8 s"):
        exompc.simulate(s, trace=False)
    with pytest.raises(RuntimeError, match=r"run 1: the simulated plant diverged"):
        exompc.run_many([SHORT, s])
    rows = exompc.run_many([SHORT, s], errors="return")
    assert rows[0]["steps"] == 50 and "diverged" in rows[1]["error"]


def test_rust_panic_is_a_runtime_error():
    """A Rust panic (a bug) reaches Python as RuntimeError, with the GIL held or inside a run."""
    for in_run in (False, True):
        with pytest.raises(RuntimeError, match="internal error in exompc .*: boom"):
            exompc._core._raise_panic("boom", in_run=in_run)
    assert exompc.simulate(SHORT, trace=False)["steps"] == 50


def test_controller_from_another_thread_raises_runtime_error():
    ctl = exompc.MultiStage(SHORT)
    sim = exompc.Simulator(SHORT)
    caught, measured = [], []

    def other():
        try:
            ctl.step(*sim.measure())
        except BaseException as e:  # noqa: BLE001 - the test records whatever comes
            caught.append(e)
        measured.append(sim.measure()[0])  # a Simulator may be shared between threads
        per_thread = exompc.MultiStage(SHORT)  # a controller of its own works
        measured.append(per_thread.step(*exompc.Simulator(SHORT).measure())[1])

    th = threading.Thread(target=other, name="worker-1")
    th.start()
    th.join()
    assert len(caught) == 1 and type(caught[0]) is RuntimeError, caught
    assert "belongs to the thread that created it (thread \"MainThread\")" in str(caught[0])
    assert measured[1] == "ok"
    assert ctl.step(*sim.measure())[1] == "ok"  # still usable from its own thread
    assert ctl.name == "msnmpc" and ctl.probabilities.shape == (3,)


def test_cancel_token_stops_a_run_from_another_thread():
    token = exompc.CancelToken()
    assert not token.cancelled
    timer = threading.Timer(0.2, token.cancel)
    timer.start()
    try:
        with pytest.raises(exompc.RunError, match="cancelled"):
            exompc.simulate(duration=1e5, trace=False, cancel=token)
    finally:
        timer.cancel()
    assert token.cancelled and repr(token) == "CancelToken(cancelled=True)"
    with pytest.raises(exompc.RunError, match="run_many: cancelled"):
        exompc.run_many([SHORT, SHORT], cancel=token)
    with pytest.raises(exompc.RunError, match="envelope: cancelled"):
        exompc.envelope(SHORT, payloads=[0.0], cancel=token)
    assert exompc.simulate(SHORT, trace=False, cancel=exompc.CancelToken())["steps"] == 50


CHILD = textwrap.dedent(
    """
    import sys, time
    import exompc

    long = exompc.Scenario.default().replace({"timing.duration_2dof_s": 2e4})
    calls = {
        "simulate": lambda: exompc.simulate(long, trace=False),
        "sweep": lambda: exompc.sweep(long, payloads=[0.0, 1.0], controllers=["msnmpc"]),
        "montecarlo": lambda: exompc.montecarlo(
            8, {"uncertainty.payload_kg": exompc.Uniform(0.0, 2.0)}, long, progress=False),
        "envelope": lambda: exompc.envelope(long, payloads=[0.0]),
    }
    for name, call in calls.items():
        try:
            print("ready", name, flush=True)
            call()
            print("finished", name, flush=True)
        except KeyboardInterrupt:
            print("caught KeyboardInterrupt", name, flush=True)
    r = exompc.simulate(duration=0.5, trace=False)
    print("short call ok", r["steps"], flush=True)
    """
)


def test_ctrl_c_interrupts_long_calls_and_leaves_the_process_usable():
    """SIGINT during simulate / sweep / montecarlo / envelope (runs of 2e4 s: minutes each if
    not interrupted) raises KeyboardInterrupt; a short call afterwards runs normally."""
    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    lines: "queue.Queue[str]" = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(x.strip()) for x in proc.stdout],
                              daemon=True)
    reader.start()
    seen = []

    def next_line():
        try:
            seen.append(lines.get(timeout=60))
        except queue.Empty:
            pytest.fail(f"no answer from the child within 60 s; so far {seen}")
        return seen[-1]

    try:
        for name in ("simulate", "sweep", "montecarlo", "envelope"):
            assert next_line() == f"ready {name}", seen
            time.sleep(0.5)  # well inside the Rust call
            proc.send_signal(signal.SIGINT)
            assert next_line() == f"caught KeyboardInterrupt {name}", seen
        assert next_line() == "short call ok 50", seen
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


RAY_CHILD = textwrap.dedent(
    """
    import ray
    import exompc

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    long = exompc.Scenario.default().replace({"timing.duration_2dof_s": 2e4})
    try:
        print("ready", flush=True)
        exompc.montecarlo(4, {"uncertainty.payload_kg": exompc.Uniform(0.0, 2.0)}, long,
                          backend="ray", progress=False)
        print("finished", flush=True)
    except KeyboardInterrupt:
        print("caught KeyboardInterrupt", flush=True)
    short = exompc.Scenario.default().replace({"timing.duration_2dof_s": 0.5})
    t = exompc.montecarlo(2, {"uncertainty.payload_kg": exompc.Uniform(0.0, 2.0)}, short,
                          backend="ray", progress=False)
    print("ray usable", list(t["error"]) == ["", ""], flush=True)
    ray.shutdown()
    """
)


def test_ctrl_c_interrupts_a_ray_study_and_leaves_ray_usable():
    """SIGINT during a Ray Monte Carlo of long runs raises KeyboardInterrupt (the pending
    tasks are cancelled); a short study on the same Ray instance afterwards completes."""
    pytest.importorskip("ray")
    proc = subprocess.Popen([sys.executable, "-c", RAY_CHILD], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    lines: "queue.Queue[str]" = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(x.strip()) for x in proc.stdout],
                              daemon=True)
    reader.start()
    seen = []

    def next_line():
        try:
            seen.append(lines.get(timeout=120))
        except queue.Empty:
            pytest.fail(f"no answer from the child within 120 s; so far {seen}")
        return seen[-1]

    try:
        assert next_line() == "ready", seen
        time.sleep(3.0)  # the tasks are running in the Ray workers
        proc.send_signal(signal.SIGINT)
        assert next_line() == "caught KeyboardInterrupt", seen
        assert next_line() == "ray usable True", seen
        assert proc.wait(timeout=120) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
