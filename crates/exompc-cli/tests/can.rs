//! `exompc run --config` / `virtual-robot --config` with the CAN hardware tables of `[robot]`:
//! the example config is accepted by `simulate`, bad hardware values exit 2 naming the key and
//! the range, a short run closes the loop over the in-process virtual bus, and `run` drives a
//! separate `virtual-robot` process through an slcan pseudo-terminal. Runs are short (1-2 s
//! of real time).

mod common;

use common::{empty_dir, exompc, stderr};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const EXAMPLE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../examples/can-virtual.toml"
);

fn example_text() -> String {
    std::fs::read_to_string(EXAMPLE).unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn simulate_reads_the_can_example() {
    let dir = empty_dir("sim");
    let out = dir.join("out");
    let o = exompc(&[
        "simulate",
        "--config",
        EXAMPLE,
        "--duration",
        "0.5",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("summary.json").exists());
}

#[test]
fn bad_hardware_values_exit_2_naming_the_key_and_range() {
    let dir = empty_dir("bad");
    let text = example_text();
    for (from, to, key, range) in [
        (
            "can_id = 1\n",
            "can_id = 300\n",
            "robot.joints.hip.can_id",
            "1..=127",
        ),
        (
            "model = \"AK80-9\"",
            "model = \"AK81-9\"",
            "robot.joints.hip.model",
            "AK70-10",
        ),
        (
            "reply_timeout_ms = 30.0",
            "reply_timeout_ms = 0.1",
            "robot.safety.reply_timeout_ms",
            "1..=1000",
        ),
        (
            "transport = \"virtual\"",
            "transport = \"serial\"",
            "robot",
            "serial",
        ),
    ] {
        let f = write(&dir, "bad.toml", &text.replacen(from, to, 1));
        for cmd in ["run", "simulate"] {
            let o = exompc(&[
                cmd,
                "--config",
                f.to_str().unwrap(),
                "--out",
                dir.join("o").to_str().unwrap(),
            ]);
            assert_eq!(o.status.code(), Some(2), "{cmd} {key}: {}", stderr(&o));
            let e = stderr(&o);
            assert!(e.contains(key) && e.contains(range), "{cmd}: {e}");
        }
    }
    // SocketCAN in a build without the feature: refused, saying how to build it.
    #[cfg(not(feature = "socketcan"))]
    {
        let f = write(
            &dir,
            "socketcan.toml",
            &text
                .replacen(
                    "transport = \"virtual\"",
                    "transport = \"socketcan\"\ninterface = \"can0\"",
                    1,
                )
                .replacen("device_latency_us = 100\n", "", 1),
        );
        let o = exompc(&[
            "run",
            "--config",
            f.to_str().unwrap(),
            "--out",
            dir.join("o").to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("robot.bus.transport") && stderr(&o).contains("feature"));
    }
    // --payload only for virtual devices.
    let f = write(
        &dir,
        "slcan.toml",
        &text
            .replacen(
                "transport = \"virtual\"",
                "transport = \"slcan\"\nport = \"/dev/null\"",
                1,
            )
            .replacen("device_latency_us = 100\n", "", 1),
    );
    let o = exompc(&["run", "--config", f.to_str().unwrap(), "--payload", "2"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--payload"), "{}", stderr(&o));
}

fn summary(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// `exompc run --config CONFIG ARGS --duration 1 --out OUT --quiet` over the virtual bus: it
/// succeeds with no limit violation, no protective stop and a sample every period; the summary.
fn run_one_second(config: &str, args: &[&str], out: &Path) -> Value {
    let mut a = vec!["run", "--config", config];
    a.extend_from_slice(args);
    a.extend(["--duration", "1", "--out", out.to_str().unwrap(), "--quiet"]);
    let o = exompc(&a);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(out);
    assert_eq!(s["counters"]["limit_violations"], 0);
    assert_eq!(s["can"]["stats"]["protective_stops"], 0);
    assert!(s["can"]["stats"]["samples"].as_u64().unwrap() >= 95);
    s
}

#[test]
fn run_closes_the_loop_over_the_virtual_bus() {
    let dir = empty_dir("virtual");
    let out = dir.join("out");
    let s = run_one_second(EXAMPLE, &["--payload", "2"], &out);
    assert!(s["can"]["bus_load"]["fraction"].as_f64().unwrap() > 0.1);
    assert_eq!(s["can"]["rms_force_true_n"].as_array().unwrap().len(), 2);
    let trace = std::fs::read_to_string(out.join("trace.csv")).unwrap();
    assert!(trace.lines().count() > 95);
}

/// One joint (`--dof 1`: the knee) with its strap forces on two raw nodes of their own: the
/// virtual leg serves every node, the loop runs without a stop.
#[test]
fn run_drives_one_joint_with_two_force_nodes() {
    let dir = empty_dir("dof1");
    let two_nodes = example_text().replacen(
        r#"channels = [
  { strap = "thigh", byte = 0, bytes = 4, scale = 0.001 },
  { strap = "shank", byte = 4, bytes = 4, scale = 0.001 },
]"#,
        r#"channels = [{ strap = "thigh", byte = 0, bytes = 4, scale = 0.001 }]

[[robot.force_sensors]]
driver = "raw"
can_id = 0x301
rate_hz = 500.0
channels = [{ strap = "shank", byte = 0, bytes = 4, scale = 0.001 }]"#,
        1,
    );
    assert_ne!(
        two_nodes,
        example_text(),
        "the example's force node changed"
    );
    let f = write(&dir, "two.toml", &two_nodes);
    let out = dir.join("out");
    let s = run_one_second(f.to_str().unwrap(), &["--dof", "1"], &out);
    assert_eq!(s["can"]["rms_force_true_n"].as_array().unwrap().len(), 1);
}

#[test]
#[cfg(unix)]
fn run_drives_a_virtual_robot_process_over_an_slcan_pty() {
    let dir = empty_dir("pty");
    let mut child = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(["virtual-robot", "--config", EXAMPLE, "--duration", "20"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let pty = lines.next().unwrap().unwrap();
    assert!(pty.starts_with("/dev/"), "{pty}");
    let cfg = write(
        &dir,
        "slcan.toml",
        &example_text()
            .replacen(
                "transport = \"virtual\"",
                &format!("transport = \"slcan\"\nport = \"{pty}\""),
                1,
            )
            .replacen("device_latency_us = 100\n", "", 1),
    );
    let out = dir.join("out");
    let o = exompc(&[
        "run",
        "--config",
        cfg.to_str().unwrap(),
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    let _ = child.kill();
    let _ = child.wait();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out);
    assert_eq!(s["counters"]["limit_violations"], 0);
    assert_eq!(s["can"]["stats"]["protective_stops"], 0);
    assert!(
        s["can"]["stats"]["samples"].as_u64().unwrap() >= 90,
        "{}",
        s["can"]
    );
    assert!(s["robot"].as_str().unwrap().contains("slcan"));
}
