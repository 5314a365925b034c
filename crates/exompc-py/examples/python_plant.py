"""Close the loop with a plant written in Python: exompc's multi-stage NMPC drives a
user-written 1-DOF knee (robot shank + human shank coupled by a strap spring-damper).

Run:  python examples/python_plant.py [--steps 3000] [--payload 0.5] [--plot plant.png]

The plant here is deliberately simple (point-mass pendulums, RK4, no sensor noise); replace
`KneePlant` with your own simulator or the driver of a real robot: all the controller needs
each period is `(t, q, qd, force)` and it returns a torque within the torque and rate limits.
"""

import argparse
import math

import numpy as np

import exompc

G = 9.81


class KneePlant:
    """Robot shank and human shank (pendulums about the knee) joined by a strap."""

    def __init__(self, s: exompc.Scenario, payload_kg: float) -> None:
        r, h, st = s["robot.shank"], s["human"], s["straps"]
        self.m_r = r["mass_kg"] + payload_kg
        self.c_r = (r["mass_kg"] * r["com_m"] + payload_kg * s["robot.payload_position_m"]) / self.m_r
        self.i_r = r["inertia_kgm2"] + r["mass_kg"] * r["com_m"] ** 2 + payload_kg * s["robot.payload_position_m"] ** 2
        seg = h["shank"]
        length = seg["length_fraction"] * h["height_m"]
        self.m_h = seg["mass_fraction"] * h["body_mass_kg"]
        self.c_h = seg["com_fraction"] * length
        self.i_h = self.m_h * (seg["gyration_fraction"] * length) ** 2 + self.m_h * self.c_h ** 2
        self.k, self.c, self.ls = st["stiffness"], st["damping"], st["ls2_m"]
        self.kp, self.kd = h["kp"], h["kd"]
        self.amp = s["trajectory.one_dof_amplitude"]
        self.w = 2 * math.pi * s["trajectory.one_dof_frequency_hz"]
        self.t = 0.0
        # q_r, qd_r, q_h, qd_h: both legs start on the human's desired motion (starting the
        # human at rest while its target already moves would jolt the strap by ~17 N at once).
        q0, qd0 = self.desired(0.0)
        self.x = np.array([q0, qd0, q0, qd0])

    def desired(self, t):
        return self.amp * math.sin(self.w * t), self.amp * self.w * math.cos(self.w * t)

    def strap_force(self, x):
        return self.k * self.ls * (x[2] - x[0]) + self.c * self.ls * (x[3] - x[1])

    def deriv(self, t, x, tau_r):
        f = self.strap_force(x)
        qd_d, qdd_d = self.desired(t)
        tau_h = self.kp * (qd_d - x[2]) + self.kd * (qdd_d - x[3]) + self.m_h * G * self.c_h * math.sin(x[2])
        acc_r = (tau_r + f * self.ls - self.m_r * G * self.c_r * math.sin(x[0])) / self.i_r
        acc_h = (tau_h - f * self.ls - self.m_h * G * self.c_h * math.sin(x[2])) / self.i_h
        return np.array([x[1], acc_r, x[3], acc_h])

    def step(self, tau_r, dt, substeps=10):
        h = dt / substeps
        for _ in range(substeps):
            k1 = self.deriv(self.t, self.x, tau_r)
            k2 = self.deriv(self.t + h / 2, self.x + h / 2 * k1, tau_r)
            k3 = self.deriv(self.t + h / 2, self.x + h / 2 * k2, tau_r)
            k4 = self.deriv(self.t + h, self.x + h * k3, tau_r)
            self.x = self.x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            self.t += h


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--payload", type=float, default=0.5, help="true payload on the shank (kg)")
    ap.add_argument("--plot", help="write a figure to this file (needs matplotlib)")
    a = ap.parse_args()

    s = exompc.Scenario.default()
    ctl = exompc.MultiStage(s, dof=1)
    plant = KneePlant(s, a.payload)
    dt = s["timing.dt"]
    torque = np.zeros(1)
    log = {"t": [], "q_r": [], "q_h": [], "force": [], "torque": [], "mu": []}
    statuses = {}
    for k in range(a.steps):
        t = k * dt
        x = plant.x
        q, qd, force = x[0:1].copy(), x[1:2].copy(), np.array([plant.strap_force(x)])
        torque, status = ctl.step(t, q, qd, force, out=torque)
        statuses[status] = statuses.get(status, 0) + 1
        for key, v in (("t", t), ("q_r", x[0]), ("q_h", x[2]), ("force", force[0]),
                       ("torque", torque[0])):
            log[key].append(v)
        log["mu"].append(ctl.probabilities.copy())
        plant.step(float(torque[0]), dt)

    f = np.array(log["force"])
    err = np.degrees(np.abs(np.array(log["q_h"]) - np.array(log["q_r"])))
    mu = np.array(log["mu"])
    print(f"python plant, payload {a.payload} kg, {a.steps} steps of {dt} s")
    print(f"  RMS strap force {np.sqrt(np.mean(f ** 2)):.3f} N, max angle error {err.max():.3f} deg")
    print("  mean probabilities " + " ".join(f"{m:.3f}" for m in mu.mean(axis=0)))
    print(f"  step outcomes {statuses}")
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(3, 1, sharex=True, figsize=(7, 6))
        ax[0].plot(log["t"], np.degrees(log["q_h"]), label="human")
        ax[0].plot(log["t"], np.degrees(log["q_r"]), "--", label="robot")
        ax[0].set_ylabel("knee (deg)")
        ax[0].legend()
        ax[1].plot(log["t"], f)
        ax[1].set_ylabel("strap force (N)")
        ax[2].plot(log["t"], mu)
        ax[2].set_ylabel("probabilities")
        ax[2].set_xlabel("t (s)")
        fig.tight_layout()
        fig.savefig(a.plot, dpi=120)
        print(f"  wrote {a.plot}")


if __name__ == "__main__":
    main()
