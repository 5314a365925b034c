//! `exompc run --config` with CiA 402 drives on the in-process virtual bus: a short closed loop
//! writes the trace and summary with the CAN section; bad CiA 402 keys exit 2 naming the key.

use std::path::{Path, PathBuf};

mod common;
use common::{exompc, fresh_dir, scratch, stderr};

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/can-cia402-virtual.toml")
}

/// `exompc run` for 1 s on the example with `from` replaced by `to`, written to `name`.
fn run_edited(name: &str, from: &str, to: &str) -> std::process::Output {
    let text = std::fs::read_to_string(example()).unwrap();
    assert!(text.contains(from), "{from}");
    let f = scratch(name);
    std::fs::write(&f, text.replacen(from, to, 1)).unwrap();
    exompc(&[
        "run",
        "--config",
        f.to_str().unwrap(),
        "--duration",
        "1",
        "--out",
        fresh_dir(&format!("{name}-out")).to_str().unwrap(),
    ])
}

#[test]
fn run_closes_the_loop_over_virtual_cia402_drives() {
    let out = fresh_dir("cia402-run");
    let o = exompc(&[
        "run",
        "--config",
        example().to_str().unwrap(),
        "--payload",
        "2",
        "--duration",
        "1",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["completed"], true);
    let can = &s["can"];
    assert_eq!(can["driver"], "cia402");
    assert_eq!(can["stats"]["protective_stops"], 0);
    assert!(can["stats"]["samples"].as_u64().unwrap() >= 95);
    assert_eq!(can["stops"].as_array().unwrap().len(), 0);
    assert!(out.join("trace.csv").is_file());
}

#[test]
fn bad_cia402_keys_exit_2_naming_the_key() {
    for (from, to, want) in [
        (
            "node_id = 2",
            "node_id = 1",
            "robot.joints.knee.node_id: 1 is also robot.joints.hip.node_id",
        ),
        (
            "mode = \"cst\"                # cyclic",
            "mode = \"csp\"                # cyclic",
            "unknown variant `csp`",
        ),
        (
            "driver = \"canopen\"",
            "driver = \"canopen\"\ncob_id = 5",
            "robot.force_sensors[0].cob_id: 5 is out of range (allowed 385..=1407)",
        ),
    ] {
        let o = run_edited("bad-cia402.toml", from, to);
        assert_eq!(o.status.code(), Some(2), "{to}: {}", stderr(&o));
        assert!(stderr(&o).contains(want), "{to}: {}", stderr(&o));
    }
}

/// The CiA 402 robot opens the hardware transports as the AK robot does: an slcan port that
/// cannot be opened is named (exit 1), and SocketCAN in a build without the feature is refused
/// saying how to build it (exit 2); in a build with it, an interface that cannot be opened is
/// named. (slcan needs a Unix serial port.)
#[cfg(unix)]
#[test]
fn cia402_drives_open_the_hardware_transports() {
    let virt = "[robot.bus]\ntransport = \"virtual\"";
    let run = |name: &str, bus: &str| run_edited(name, virt, bus);
    let o = run(
        "cia402-slcan.toml",
        "[robot.bus]\ntransport = \"slcan\"\nport = \"/nonexistent/exompc-tty\"",
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("opening the slcan port /nonexistent/exompc-tty (robot.bus.port)"),
        "{e}"
    );
    let o = run(
        "cia402-socketcan.toml",
        "[robot.bus]\ntransport = \"socketcan\"\ninterface = \"exo-no-can0\"",
    );
    let e = stderr(&o);
    #[cfg(not(all(target_os = "linux", feature = "socketcan")))]
    {
        assert_eq!(o.status.code(), Some(2), "{e}");
        assert!(
            e.contains("robot.bus.transport") && e.contains("feature"),
            "{e}"
        );
    }
    #[cfg(all(target_os = "linux", feature = "socketcan"))]
    {
        assert_ne!(o.status.code(), Some(0), "{e}");
        assert!(e.contains("SocketCAN interface exo-no-can0"), "{e}");
    }
}
