//! The trace's one column table (`sim::trace::TRACE_COLUMNS`): the CSV header as users read it,
//! rows that put each value under its column, and the docs' table generated from it.

use exompc::control::StepStatus;
use exompc::model::JointState;
use exompc::sim::trace::{columns_markdown, csv_header, csv_row};
use exompc::sim::StepRecord;
use nalgebra::SVector;

/// The 2-DOF header with three scenarios, written out by hand (the format users parse).
#[test]
fn the_csv_header_is_the_documented_one() {
    let keys: Vec<String> = ["1", "2", "3"].map(String::from).to_vec();
    let mut want = vec!["t".to_string()];
    for j in ["hip", "knee"] {
        for c in [
            "q_robot",
            "qd_robot",
            "q_human",
            "qd_human",
            "q_desired",
            "torque_robot",
            "torque_human",
        ] {
            want.push(format!("{c}_{j}"));
        }
    }
    for s in ["thigh", "shank"] {
        want.push(format!("force_true_{s}"));
        want.push(format!("force_measured_{s}"));
    }
    for k in &keys {
        want.push(format!("mu_{k}"));
    }
    for k in &keys {
        for j in ["hip", "knee"] {
            want.push(format!("dist_{k}_{j}"));
        }
    }
    want.extend(["status", "iterations", "step_us"].map(String::from));
    assert_eq!(csv_header(2, &keys), want);
    let one = csv_header(1, &[]);
    assert_eq!(one.len(), 1 + 7 + 2 + 3);
    assert_eq!(&one[1..3], ["q_robot_knee", "qd_robot_knee"]);
}

/// Every value lands under its own column (distinct values per field).
#[test]
fn rows_put_each_value_under_its_column() {
    let v = |a: f64| SVector::<f64, 2>::new(a, a + 0.5);
    let p = [0.25, 0.75];
    let d = [v(20.0), v(30.0)];
    let r = StepRecord {
        k: 7,
        t: 0.07,
        robot: JointState {
            q: v(1.0),
            qd: v(2.0),
        },
        human: JointState {
            q: v(3.0),
            qd: v(4.0),
        },
        desired: v(5.0),
        torque_robot: v(6.0),
        torque_prev: v(99.0),
        torque_human: v(7.0),
        force_true: v(8.0),
        force_measured: v(9.0),
        probabilities: Some(&p),
        disturbances: Some(&d),
        status: StepStatus::MonitorTripped,
        iterations: 4,
        step_time_us: 12.5,
        within_limits: true,
    };
    let keys = ["a".to_string(), "b".to_string()];
    let header = csv_header(2, &keys);
    let mut line = String::new();
    csv_row(&r, keys.len(), &mut line);
    assert!(line.ends_with('\n'));
    let cells: Vec<&str> = line.trim_end().split(',').collect();
    assert_eq!(cells.len(), header.len());
    let at = |name: &str| cells[header.iter().position(|h| h == name).unwrap()];
    assert_eq!(at("t"), "0.07");
    assert_eq!(at("q_robot_hip"), "1");
    assert_eq!(at("qd_robot_knee"), "2.5");
    assert_eq!(at("q_human_knee"), "3.5");
    assert_eq!(at("qd_human_hip"), "4");
    assert_eq!(at("q_desired_knee"), "5.5");
    assert_eq!(at("torque_robot_hip"), "6");
    assert_eq!(at("torque_human_knee"), "7.5");
    assert_eq!(at("force_true_thigh"), "8");
    assert_eq!(at("force_measured_shank"), "9.5");
    assert_eq!(at("mu_b"), "0.75");
    assert_eq!(at("dist_a_knee"), "20.5");
    assert_eq!(at("dist_b_hip"), "30");
    assert_eq!(at("status"), "monitor_tripped");
    assert_eq!(at("iterations"), "4");
    assert_eq!(at("step_us"), "12.5");
    // Without scenario values the scenario columns are NaN.
    let r = StepRecord {
        probabilities: None,
        disturbances: None,
        ..r
    };
    line.clear();
    csv_row(&r, keys.len(), &mut line);
    let cells: Vec<&str> = line.trim_end().split(',').collect();
    assert_eq!(
        cells[header.iter().position(|h| h == "mu_a").unwrap()],
        "NaN"
    );
}

const DOC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/REPRODUCING.md");

/// docs/REPRODUCING.md and the byte range of its column table (between the markers).
fn docs_table() -> (String, std::ops::Range<usize>) {
    let doc = std::fs::read_to_string(DOC).unwrap();
    let (begin, end) = (
        "<!-- trace-columns:begin -->\n",
        "<!-- trace-columns:end -->",
    );
    let a = doc.find(begin).expect("begin marker") + begin.len();
    let b = doc.find(end).expect("end marker");
    (doc, a..b)
}

/// docs/REPRODUCING.md's column table is the generated one.
#[test]
fn the_docs_column_table_is_generated_from_the_table() {
    let (doc, table) = docs_table();
    assert_eq!(
        &doc[table],
        columns_markdown(),
        "regenerate the table: cargo test -p exompc --test trace_columns -- --ignored"
    );
}

/// Writes the generated table into docs/REPRODUCING.md (run with `--ignored`).
#[test]
#[ignore]
fn write_the_docs_column_table() {
    let (doc, t) = docs_table();
    let new = format!("{}{}{}", &doc[..t.start], columns_markdown(), &doc[t.end..]);
    std::fs::write(DOC, new).unwrap();
}
