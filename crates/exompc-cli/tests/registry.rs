//! Every entry of the library's controller registry (`exompc::scenario::controllers`) runs
//! through `simulate`, `sweep` and `plot` with nothing but its registry entry: the command
//! line accepts its name, folders and summaries carry it, tables and figures show its label.

mod common;

use common::{exompc, fresh_dir, stderr};
use exompc::scenario::controllers;

fn summary_controller(dir: &std::path::Path) -> String {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["controller"].as_str().unwrap().to_string()
}

#[test]
fn every_registered_controller_runs_through_simulate_sweep_and_plot() {
    let all = controllers();
    assert!(all.len() >= 3);
    for c in &all {
        let dir = fresh_dir(&format!("simulate_{}", c.name()));
        let out = exompc(&[
            "simulate",
            "--controller",
            c.name(),
            "--dof",
            "1",
            "--duration",
            "0.5",
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}: {}", c.name(), stderr(&out));
        assert_eq!(summary_controller(&dir), c.name());
    }

    let names: Vec<&str> = all.iter().map(|c| c.name()).collect();
    let dir = fresh_dir("sweep_all");
    let out = exompc(&[
        "sweep",
        "--controllers",
        &names.join(","),
        "--payloads",
        "0,1",
        "--duration",
        "0.5",
        "--quiet",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let table = std::fs::read_to_string(dir.join("table2.md")).unwrap();
    for c in &all {
        for p in ["0kg", "1kg"] {
            let run = dir.join(format!("{}_{p}", c.name()));
            assert!(run.join("trace.csv").is_file(), "{}", run.display());
            assert_eq!(summary_controller(&run), c.name());
        }
        assert!(
            table.contains(&format!("{} RMS F thigh (N)", c.label)),
            "{table}"
        );
    }

    let out = exompc(&["plot", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));
    for fig in ["compare_1kg.svg", "compare_0kg.svg", "payload_sweep.svg"] {
        let svg = std::fs::read_to_string(dir.join(fig)).unwrap();
        for c in &all {
            assert!(
                svg.contains(c.label),
                "{fig} has no legend entry {}",
                c.label
            );
        }
    }
}
