"""Cost of calling the controller from Python: 10,000 `MultiStage.step` calls in a Python loop
against the same steps inside Rust (`simulate`'s own step timing).

Run:  python examples/bench_step.py [--steps 10000] [--repeats 3]

Both sides run the same closed loop (the Rust simulator, the default scenario, 100 s = 10,000
periods); the Python side drives `Simulator` + `MultiStage` and times only the `step` call
(argument conversion, the Rust step, the returned array and status). The issue's budget is
`2 x (Rust step time) + 2 us` per call.
"""

import argparse
import time

import numpy as np

import exompc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    s = exompc.Scenario.default().replace({"timing.duration_2dof_s": a.steps * 0.01})

    for rep in range(a.repeats):
        rust = exompc.simulate(s, trace=False)["step_time_us"]
        sim, ctl = exompc.Simulator(s), exompc.MultiStage(s)
        out = np.zeros(2)
        py_times = np.empty(sim.steps)
        clock = time.perf_counter
        for k in range(sim.steps):
            t, q, qd, f = sim.measure()
            t0 = clock()
            ctl.step(t, q, qd, f, out=out)
            py_times[k] = clock() - t0
            sim.advance(out)
        py_us = py_times * 1e6
        budget = 2 * rust["mean"] + 2.0
        print(f"run {rep + 1}: {sim.steps} steps | Rust step mean {rust['mean']:.2f} us "
              f"(p50 {rust['p50']:.2f}) | Python step mean {py_us.mean():.2f} us "
              f"(p50 {np.median(py_us):.2f}) | overhead {py_us.mean() - rust['mean']:.2f} us/call "
              f"| budget 2x+2us = {budget:.2f} us -> {'within' if py_us.mean() <= budget else 'OVER'}")


if __name__ == "__main__":
    main()
