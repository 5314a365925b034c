//! Tests of the CLI's I/O helpers (`exompc_cli::io`).

use exompc::config::{Channel, Experiment, FaultKind, HumanSegment, Link};
use exompc_cli::io::{
    closest, ensure_out_dir, levenshtein, parse_scenario, write_atomic, AtomicWriter,
};
use std::io::Write;

mod common;

use common::empty_dir as scratch_dir;

fn entries(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn empty_file_is_the_default() {
    assert_eq!(parse_scenario("").unwrap(), Experiment::default());
}

#[test]
fn partial_override_changes_only_named_fields() {
    let s = parse_scenario(
        "[human.thigh]\nmass_fraction = 0.11\n[robot.shank]\nmass_kg = 1.5\n[controller]\nkind = \"nmpc\"\nnp = 10\n[timing]\ndt = 1\n",
    )
    .unwrap();
    let mut expected = Experiment::default();
    expected.human.thigh = HumanSegment {
        mass_fraction: 0.11,
        ..HumanSegment::WINTER_THIGH
    };
    expected.robot.shank = Link {
        mass: 1.5,
        ..Link::ROBOT_SHANK
    };
    expected.controller.kind = exompc::config::ControllerKind::NMPC;
    expected.controller.np = 10;
    expected.timing.dt = 1.0;
    assert_eq!(s, expected);
}

#[test]
fn fault_events_and_optional_keys_parse() {
    let s = parse_scenario(
        "[controller.sqp]\nmax_time_us = 5000\n\n[[faults.events]]\nkind = \"spike\"\nchannel = \"f2\"\nstart_s = 2.0\nduration_s = 0.05\nmagnitude = 40.0\n\n[[faults.events]]\nkind = \"dropout\"\nchannel = \"qd1\"\nstart_s = 5\nduration_s = 0.1\n",
    )
    .unwrap();
    assert_eq!(s.controller.sqp.max_time_us, Some(5000));
    assert_eq!(s.faults.events.len(), 2);
    assert_eq!(
        (s.faults.events[0].kind, s.faults.events[0].channel),
        (FaultKind::Spike, Channel::F2)
    );
    assert_eq!(s.faults.events[1].magnitude, 0.0);
    // A scenario with events and options round-trips through TOML.
    let text = toml::to_string_pretty(&s).unwrap();
    assert_eq!(parse_scenario(&text).unwrap(), s);
}

#[test]
fn levenshtein_and_closest() {
    assert_eq!(levenshtein("", "abc"), 3);
    assert_eq!(levenshtein("kitten", "sitting"), 3);
    assert_eq!(levenshtein("mass_kg", "mass_kg"), 0);
    assert_eq!(
        closest("masss_kg", &["length_m", "mass_kg", "com_m"]),
        Some("mass_kg")
    );
    assert_eq!(closest("x", &[]), None);
}

#[test]
fn write_atomic_replaces_file_and_leaves_no_temp() {
    let dir = scratch_dir("atomic");
    let path = dir.join("out.txt");
    write_atomic(&path, b"first").unwrap();
    write_atomic(&path, b"second").unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "second");
    assert_eq!(entries(&dir), vec!["out.txt"]);
}

#[test]
fn atomic_writer_renames_on_finish_and_cleans_up_on_drop() {
    let dir = scratch_dir("writer");
    let path = dir.join("trace.csv");
    let mut w = AtomicWriter::create(&path).unwrap();
    writeln!(w, "t,q1").unwrap();
    writeln!(w, "0,0.1").unwrap();
    assert!(!path.exists(), "destination must not appear before finish");
    w.finish().unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "t,q1\n0,0.1\n");

    let other = dir.join("abandoned.csv");
    {
        let mut w = AtomicWriter::create(&other).unwrap();
        writeln!(w, "partial").unwrap();
    }
    assert!(!other.exists());
    assert_eq!(entries(&dir), vec!["trace.csv"]);

    // Works with csv::Writer as the streaming sink.
    let csv_path = dir.join("table.csv");
    let mut c = csv::Writer::from_writer(AtomicWriter::create(&csv_path).unwrap());
    c.write_record(["a", "b"]).unwrap();
    c.into_inner()
        .map_err(|e| e.into_error())
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(std::fs::read_to_string(&csv_path).unwrap(), "a,b\n");
}

#[test]
fn ensure_out_dir_creates_and_rejects_files() {
    let dir = scratch_dir("outdir");
    let nested = dir.join("a/b/c");
    ensure_out_dir(&nested).unwrap();
    assert!(nested.is_dir());
    let file = dir.join("plain");
    std::fs::write(&file, "x").unwrap();
    let err = ensure_out_dir(&file).unwrap_err();
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains("plain"), "{err}");
}

#[test]
fn set_and_get_keys_by_dotted_path() {
    use exompc_cli::io::{get_key, parse_value, set_key};
    let s = Experiment::default();
    let t = set_key(&s, "robot.payload_position_m", parse_value("0.43")).unwrap();
    assert_eq!(t.robot.payload_position_m, 0.43);
    assert_eq!(
        get_key(&t, "robot.payload_position_m").unwrap(),
        Some(toml::Value::Float(0.43))
    );
    let t = set_key(&t, "uncertainty.filter_window", parse_value("9")).unwrap();
    assert_eq!(t.uncertainty.filter_window, 9);
    // An integer is accepted for a float field; a bare word is a string.
    let t = set_key(&t, "uncertainty.payload_kg", parse_value("2")).unwrap();
    assert_eq!(t.uncertainty.payload_kg, 2.0);
    let t = set_key(&t, "multistage.formulation", parse_value("coupled")).unwrap();
    assert_eq!(
        get_key(&t, "multistage.formulation").unwrap(),
        Some(toml::Value::String("coupled".into()))
    );
    // Unknown key: closest name suggested; out of range: the field and its range.
    let e = set_key(&s, "robot.payload_positon_m", parse_value("0.4")).unwrap_err();
    assert!(e.contains("payload_position_m"), "{e}");
    let e = set_key(&s, "robot.payload_position_m", parse_value("-1")).unwrap_err();
    assert!(e.contains("robot.payload_position_m"), "{e}");
    let e = set_key(&s, "uncertainty.filter_window", parse_value("fast")).unwrap_err();
    assert!(e.contains("uncertainty.filter_window"), "{e}");
    let e = get_key(&s, "robot.mass").unwrap_err();
    assert!(e.contains("unknown key `mass`"), "{e}");
    assert!(set_key(&s, "", parse_value("1")).is_err());
}
