"""A Monte Carlo robustness study of the default controller: random payload, body mass,
human stiffness and strap stiffness; a table of summaries and a figure.

Run locally:       python examples/montecarlo_study.py --draws 1000
On a Ray cluster:  python examples/montecarlo_study.py --draws 1000 --backend ray --address auto
On a local Ray:    python examples/montecarlo_study.py --draws 1000 --backend ray --local-ray 2

Writes OUT/montecarlo.csv and OUT/montecarlo.png.
"""

import argparse
import os
import time

import numpy as np

import exompc

PARAMS = {
    "uncertainty.payload_kg": exompc.Uniform(0.0, 2.0),
    "human.body_mass_kg": exompc.Normal(72.0, 10.0, 45.0, 110.0),
    "human.kp": exompc.Uniform(300.0, 500.0),
    "straps.stiffness": exompc.Normal(937.5, 90.0, 600.0, 1300.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--backend", choices=["local", "ray"], default="local")
    ap.add_argument("--address", help="Ray cluster address (e.g. auto or ray://host:10001)")
    ap.add_argument("--local-ray", type=int, metavar="CPUS",
                    help="start a local Ray instance with this many CPUs")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/py-montecarlo")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)

    if a.backend == "ray" and a.local_ray:
        import ray

        ray.init(num_cpus=a.local_ray, include_dashboard=False)
    start = time.perf_counter()
    tab = exompc.montecarlo(a.draws, PARAMS, seed=a.seed, backend=a.backend,
                            ray_address=a.address)
    wall = time.perf_counter() - start
    exompc.write_csv(tab, os.path.join(a.out, "montecarlo.csv"))

    ok = tab["error"] == ""
    f = tab["rms_force_shank_n"][ok]
    d = tab["delta_max_knee_deg"][ok]
    print(f"{a.draws} draws on backend {a.backend}: {wall:.1f} s wall, {ok.sum()} completed, "
          f"{(~ok).sum()} failed")
    print(f"  RMS shank force  median {np.median(f):.3f} N, p95 {np.percentile(f, 95):.3f} N, "
          f"max {f.max():.3f} N")
    print(f"  max knee error   median {np.median(d):.3f} deg, p95 {np.percentile(d, 95):.3f} deg, "
          f"max {d.max():.3f} deg")
    print(f"  limit violations {int(tab['limit_violations'][ok].sum())}, "
          f"solver failures {int(tab['solver_failures'][ok].sum())}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    p = tab["uncertainty.payload_kg"][ok]
    sc = ax[0].scatter(p, f, c=tab["human.body_mass_kg"][ok], s=8, cmap="viridis")
    fig.colorbar(sc, ax=ax[0], label="body mass (kg)")
    ax[0].set(xlabel="payload (kg)", ylabel="RMS shank strap force (N)")
    ax[1].scatter(p, d, s=8)
    ax[1].set(xlabel="payload (kg)", ylabel="max knee angle error (deg)")
    ax[2].hist(f, bins=40)
    ax[2].set(xlabel="RMS shank strap force (N)", ylabel="draws")
    fig.suptitle(f"Monte Carlo, {a.draws} draws, default controller (msnmpc)")
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "montecarlo.png"), dpi=120)
    print(f"wrote {a.out}/montecarlo.csv and montecarlo.png")


if __name__ == "__main__":
    main()
