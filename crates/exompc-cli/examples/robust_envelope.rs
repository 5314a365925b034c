//! Measurement harness for the controller across the operating envelope (issue "Robust across
//! the operating envelope"): every cell (one change from the default at a time) × payloads
//! 0-3 kg × {MS-NMPC, NMPC}, in parallel, printing RMS strap forces, the fraction of strap-force
//! power above 3 Hz, the last/first 2-s RMS ratio and the share of steps on the torque limit.
//!
//! ```text
//! cargo run --release -p exompc-cli --example robust_envelope -- [--set key=value]... [--json FILE]
//! ```
//! `--set` applies to every run (both controllers) before the cell's own change, e.g.
//! `--set controller.method=paper` measures the paper's method; `--ms-set` to the MS-NMPC runs
//! only.

use exompc::config::{ControllerKind, Experiment};
use exompc::scenario::{run_experiment, OneDof, TwoDof};
use exompc::sim::{high_frequency_fraction, rms, Recorder, StepRecord};
use exompc_cli::io::{parse_value, set_key};
use rayon::prelude::*;

/// Per-run measurements of one strap force channel set.
#[derive(Clone, Debug, Default, serde::Serialize)]
struct RunStats {
    rms: Vec<f64>,
    hf_fraction: Vec<f64>,
    growth: Vec<f64>,
    saturated: f64,
    violations: u64,
}

#[derive(Default)]
struct Log<const N: usize> {
    force: Vec<[f64; N]>,
    sat: usize,
    viol: u64,
    tmax: f64,
}

impl<const N: usize> Recorder<N> for Log<N> {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        let mut f = [0.0; N];
        for (a, v) in f.iter_mut().enumerate() {
            *v = r.force_true[a];
        }
        self.force.push(f);
        if r.torque_robot.iter().any(|t| t.abs() >= self.tmax - 1e-6) {
            self.sat += 1;
        }
        if !r.within_limits {
            self.viol += 1;
        }
        Ok(())
    }
}

fn stats<const N: usize>(log: &Log<N>, dt: f64) -> RunStats {
    let n = log.force.len();
    let w = (2.0 / dt).round() as usize;
    let mut st = RunStats {
        saturated: log.sat as f64 / n.max(1) as f64,
        violations: log.viol,
        ..Default::default()
    };
    for a in 0..N {
        let x: Vec<f64> = log.force.iter().map(|f| f[a]).collect();
        // The envelope classifier's measures (RMS, DFT power share above 3 Hz).
        st.rms.push(rms(&x));
        st.hf_fraction.push(high_frequency_fraction(&x, dt, 3.0));
        st.growth.push(rms(&x[n - w..]) / rms(&x[..w]).max(1e-9));
    }
    st
}

fn run(s: &Experiment, dof: usize) -> Result<RunStats, String> {
    let dt = s.timing.dt;
    if dof == 1 {
        let mut log = Log::<1> {
            tmax: s.controller.torque_max,
            ..Default::default()
        };
        run_experiment::<OneDof, 1>(s, &mut [&mut log]).map_err(|e| e.to_string())?;
        Ok(stats(&log, dt))
    } else {
        let mut log = Log::<2> {
            tmax: s.controller.torque_max,
            ..Default::default()
        };
        run_experiment::<TwoDof, 2>(s, &mut [&mut log]).map_err(|e| e.to_string())?;
        Ok(stats(&log, dt))
    }
}

/// An envelope cell: name, DOF, and the (key, value) changes from the default.
type EnvelopeCell = (String, usize, Vec<(&'static str, &'static str)>);

fn cells() -> Vec<EnvelopeCell> {
    let mut c: Vec<EnvelopeCell> = vec![("default".into(), 2, vec![])];
    for p in ["0.10", "0.30", "0.43"] {
        c.push((
            format!("payload_pos {p}"),
            2,
            vec![("robot.payload_position_m", p)],
        ));
    }
    for w in ["1", "3", "7", "9"] {
        c.push((
            format!("filter {w}"),
            2,
            vec![("uncertainty.filter_window", w)],
        ));
    }
    for f in ["0.6", "1.1", "1.3"] {
        c.push((
            format!("freq {f}"),
            2,
            vec![("trajectory.base_frequency_hz", f)],
        ));
    }
    c.push((
        "straps x0.5".into(),
        2,
        vec![("straps.stiffness", "468.75"), ("straps.damping", "46.85")],
    ));
    c.push((
        "straps x2".into(),
        2,
        vec![("straps.stiffness", "1875.0"), ("straps.damping", "187.4")],
    ));
    c.push((
        "human small".into(),
        2,
        vec![
            ("human.height_m", "1.5"),
            ("human.body_mass_kg", "50.0"),
            ("human.final_body_mass_kg", "60.0"),
        ],
    ));
    c.push((
        "human large".into(),
        2,
        vec![
            ("human.height_m", "1.9"),
            ("human.body_mass_kg", "95.0"),
            ("human.final_body_mass_kg", "110.0"),
        ],
    ));
    c.push((
        "robot heavy".into(),
        2,
        vec![
            ("robot.thigh.mass_kg", "4.0"),
            ("robot.thigh.inertia_kgm2", "0.07"),
            ("robot.shank.mass_kg", "2.5"),
            ("robot.shank.inertia_kgm2", "0.036"),
        ],
    ));
    c.push((
        "1dof pos 0.43".into(),
        1,
        vec![("robot.payload_position_m", "0.43")],
    ));
    c.push((
        "1dof filter 9".into(),
        1,
        vec![("uncertainty.filter_window", "9")],
    ));
    c
}

fn apply(mut s: Experiment, kvs: &[(String, String)]) -> Result<Experiment, String> {
    // Apply in order; a key may need a companion (e.g. mass then final mass), so retry once.
    let mut pending: Vec<&(String, String)> = kvs.iter().collect();
    for _ in 0..3 {
        let mut next = Vec::new();
        for kv in pending {
            match set_key(&s, &kv.0, parse_value(&kv.1)) {
                Ok(n) => s = n,
                Err(_) => next.push(kv),
            }
        }
        if next.is_empty() {
            return Ok(s);
        }
        pending = next;
    }
    Err(format!("could not apply {pending:?}"))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut global = Vec::new();
    let mut ms_only = Vec::new();
    let mut json_out = None;
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--set" => {
                let (k, v) = args[i + 1].split_once('=').expect("--set key=value");
                global.push((k.to_string(), v.to_string()));
                i += 2;
            }
            "--ms-set" => {
                let (k, v) = args[i + 1].split_once('=').expect("--ms-set key=value");
                ms_only.push((k.to_string(), v.to_string()));
                i += 2;
            }
            "--json" => {
                json_out = Some(args[i + 1].clone());
                i += 2;
            }
            other => panic!("unknown argument {other}"),
        }
    }
    let payloads = [0.0, 1.0, 2.0, 3.0];
    let mut jobs = Vec::new();
    for (ci, (_, dof, kv)) in cells().iter().enumerate() {
        for &p in &payloads {
            for kind in [ControllerKind::MSNMPC, ControllerKind::NMPC] {
                let mut all = global.clone();
                if kind == ControllerKind::MSNMPC {
                    all.extend(ms_only.iter().cloned());
                }
                all.extend(kv.iter().map(|(k, v)| (k.to_string(), v.to_string())));
                all.push(("uncertainty.payload_kg".into(), format!("{p:.1}")));
                let k = if kind == ControllerKind::NMPC {
                    "nmpc"
                } else {
                    "msnmpc"
                };
                all.push(("controller.kind".into(), k.into()));
                jobs.push((ci, *dof, p, kind, all));
            }
        }
    }
    let start = std::time::Instant::now();
    let results: Vec<_> = jobs
        .par_iter()
        .map(|(ci, dof, p, kind, kv)| {
            let r = apply(Experiment::default(), kv).and_then(|s| run(&s, *dof));
            (*ci, *p, *kind, r)
        })
        .collect();
    let cells = cells();
    println!(
        "| cell | kg | MS rms th/sh | MS hf | MS growth | MS sat | NMPC rms th/sh | verdict |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let (mut unstable, mut worse, mut big, mut total) = (0, 0, 0, 0);
    let mut out = Vec::new();
    for (ci, (name, _, _)) in cells.iter().enumerate() {
        for &p in &payloads {
            let get = |k: ControllerKind| {
                results
                    .iter()
                    .find(|r| r.0 == ci && r.1 == p && r.2 == k)
                    .map(|r| r.3.clone())
                    .unwrap()
            };
            let (ms, nm) = (get(ControllerKind::MSNMPC), get(ControllerKind::NMPC));
            total += 1;
            match (&ms, &nm) {
                (Ok(m), Ok(n)) => {
                    let hf = m.hf_fraction.iter().cloned().fold(0.0, f64::max);
                    let gr = m.growth.iter().cloned().fold(0.0, f64::max);
                    let is_unstable = hf >= 0.25 || gr > 1.5 || m.violations > 0;
                    let tol = if p == 0.0 { 1.1 } else { 1.0 };
                    let is_worse = m.rms.iter().zip(&n.rms).any(|(a, b)| *a > tol * b);
                    let is_big = m.rms.iter().any(|v| *v >= 20.0) && m.saturated <= 0.05;
                    unstable += is_unstable as usize;
                    worse += is_worse as usize;
                    big += is_big as usize;
                    let fmt = |v: &[f64]| {
                        v.iter()
                            .map(|x| format!("{x:.2}"))
                            .collect::<Vec<_>>()
                            .join("/")
                    };
                    let mut verdict = Vec::new();
                    if is_unstable {
                        verdict.push("UNSTABLE");
                    }
                    if is_worse {
                        verdict.push("worse");
                    }
                    if is_big {
                        verdict.push(">=20N");
                    }
                    println!(
                        "| {name} | {p} | {} | {} | {} | {:.3} | {} | {} |",
                        fmt(&m.rms),
                        fmt(&m.hf_fraction),
                        fmt(&m.growth),
                        m.saturated,
                        fmt(&n.rms),
                        if verdict.is_empty() {
                            "ok".to_string()
                        } else {
                            verdict.join(" ")
                        }
                    );
                    out.push(
                        serde_json::json!({"cell": name, "payload_kg": p, "msnmpc": m, "nmpc": n}),
                    );
                }
                _ => println!("| {name} | {p} | error {ms:?} {nm:?} |"),
            }
        }
    }
    println!(
        "\ncells {total}: unstable {unstable}, worse than NMPC {worse}, >= 20 N (unsaturated) {big}; wall {:.1} s",
        start.elapsed().as_secs_f64()
    );
    if let Some(f) = json_out {
        std::fs::write(f, serde_json::to_string_pretty(&out).unwrap()).unwrap();
    }
}
