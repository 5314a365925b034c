"""Reproduce the paper's Table 2 (RMS strap forces and maximum angle errors of the NMPC and
the multi-stage NMPC over payloads) and draw it with matplotlib.

Run:  python examples/table2.py [--payloads 0,0.5,1,1.5,2] [--out out/py-table2]

Writes OUT/table2.md, OUT/table2.csv and OUT/table2.png (RMS force and max angle error vs
payload), plus OUT/trace.png: the default run's angles, strap forces and probabilities.
"""

import argparse
import os

import numpy as np

import exompc
from exompc.montecarlo import _columns, summary_row, write_csv


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--payloads", default="0,0.5,1,1.5,2")
    ap.add_argument("--out", default="out/py-table2")
    a = ap.parse_args()
    payloads = [float(p) for p in a.payloads.split(",")]
    os.makedirs(a.out, exist_ok=True)

    s = exompc.Scenario.default()
    rows = exompc.sweep(s, payloads, ["nmpc", "msnmpc"])
    md = exompc.table2(rows)
    print(md)
    with open(os.path.join(a.out, "table2.md"), "w") as f:
        f.write(md + "\n")
    write_csv(_columns([summary_row(r) for r in rows]), os.path.join(a.out, "table2.csv"))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for ctl, style in (("nmpc", "o--"), ("msnmpc", "s-")):
        r = [x for x in rows if x["controller"] == ctl]
        p = [x["payload_kg"] for x in r]
        ax[0].plot(p, [x["rms_force_n"]["thigh"] for x in r], style, label=f"{ctl} thigh")
        ax[0].plot(p, [x["rms_force_n"]["shank"] for x in r], style, label=f"{ctl} shank")
        ax[1].plot(p, [x["delta_max_deg"]["hip"] for x in r], style, label=f"{ctl} hip")
        ax[1].plot(p, [x["delta_max_deg"]["knee"] for x in r], style, label=f"{ctl} knee")
    ax[0].set(xlabel="payload (kg)", ylabel="RMS strap force (N)", title="Table 2: interaction force")
    ax[1].set(xlabel="payload (kg)", ylabel="max |q_H - q_R| (deg)", title="Table 2: angle error")
    for x in ax:
        x.grid(alpha=0.3)
        x.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "table2.png"), dpi=120)

    tr = exompc.simulate(s)["trace"]
    fig, ax = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
    ax[0].plot(tr["t"], np.degrees(tr["q_human"]), label=["human hip", "human knee"])
    ax[0].plot(tr["t"], np.degrees(tr["q_robot"]), "--", label=["robot hip", "robot knee"])
    ax[0].set_ylabel("angle (deg)")
    ax[0].legend(fontsize=8, ncol=2)
    ax[1].plot(tr["t"], tr["force_true"], label=["thigh", "shank"])
    ax[1].set_ylabel("strap force (N)")
    ax[1].legend(fontsize=8)
    ax[2].plot(tr["t"], tr["probabilities"], label=[f"mu{i + 1}" for i in range(3)])
    ax[2].set(ylabel="probability", xlabel="t (s)")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "trace.png"), dpi=120)
    print(f"wrote {a.out}/table2.md, table2.csv, table2.png, trace.png")


if __name__ == "__main__":
    main()
