//! `[robot]` keys of CiA 402 joints and CANopen force nodes: parsed, defaulted, and every bad
//! value named by its key with the allowed range.

use exompc_can::config::{ForceSensor, HardwareConfig, Joint};

const GOOD: &str = r#"
[bus]
transport = "virtual"

[joints.hip]
driver = "cia402"
node_id = 1
rated_torque_nm = 0.5
gear_ratio = 50
torque_limit_nm = 20

[joints.knee]
driver = "cia402"
node_id = 2
rated_torque_nm = 0.5
gear_ratio = 50
direction = -1
torque_limit_nm = 20
mode = "pt"
velocity_unit = "counts_per_s"

[[force_sensors]]
driver = "canopen"
node_id = 10
scale = 0.01
"#;

fn parse(text: &str) -> Result<HardwareConfig, String> {
    let t: toml::Table = text.parse().map_err(|e| format!("{e}"))?;
    HardwareConfig::from_table(t).map_err(|e| e.to_string())
}

fn with(from: &str, to: &str) -> String {
    assert!(GOOD.contains(from), "{from}");
    GOOD.replacen(from, to, 1)
}

#[test]
fn cia402_joints_and_canopen_force_nodes_parse_with_defaults() {
    let c = parse(GOOD).unwrap();
    let Joint::Cia402(hip) = &c.joints.hip else {
        panic!("hip")
    };
    assert_eq!(hip.heartbeat_ms, 50.0);
    assert_eq!(hip.counts_per_rev, 4096.0);
    assert_eq!(hip.master_node_id, 127);
    let m = hip
        .master_config(std::time::Duration::from_millis(10))
        .unwrap();
    assert_eq!(m.max_torque_per_mille(), 800, "20 N·m of 0.5 × 50");
    assert_eq!(
        m.master_heartbeat.unwrap().1,
        std::time::Duration::from_millis(50)
    );
    let ForceSensor::Canopen(f) = &c.force_sensors[0] else {
        panic!("force")
    };
    assert_eq!(f.tpdo_cob_id(), 0x18A);
    assert!(f.configure);
}

#[test]
fn bad_values_name_their_key_and_range() {
    let cases = [
        ("node_id = 2", "node_id = 0", "robot.joints.knee.node_id: 0 is out of range (allowed 1..=127)"),
        ("node_id = 2", "node_id = 1", "robot.joints.knee.node_id: 1 is also robot.joints.hip.node_id"),
        ("node_id = 10", "node_id = 2", "robot.force_sensors[0].node_id: 2 is also robot.joints.knee.node_id"),
        ("direction = -1", "direction = 2", "robot.joints.knee.direction: 2 is not allowed (allowed: 1 or -1)"),
        ("rated_torque_nm = 0.5\ngear_ratio = 50\ntorque_limit_nm = 20", "rated_torque_nm = 0.0001\ngear_ratio = 50\ntorque_limit_nm = 20", "robot.joints.hip.rated_torque_nm: 0.0001 is out of range (allowed 0.001..=1000)"),
        ("torque_limit_nm = 20\nmode", "torque_limit_nm = 900\nmode", "robot.joints.knee.torque_limit_nm: 900 N·m is more than 32.767 × the rated joint torque 25 N·m"),
        ("mode = \"pt\"", "mode = \"pv\"", "unknown variant `pv`"),
        ("scale = 0.01", "scale = 0", "robot.force_sensors[0].scale: 0 is out of range"),
        ("scale = 0.01", "scale = 0.01\ncob_id = 0x100", "robot.force_sensors[0].cob_id: 256 is out of range (allowed 385..=1407)"),
        ("scale = 0.01", "scale = 0.01\nheartbeat_ms = 200", "robot.force_sensors[0].heartbeat_timeout_ms: 150 ms is not more than heartbeat_ms = 200 ms"),
        ("mode = \"pt\"", "mode = \"pt\"\nmaster_node_id = 2", "robot.joints.knee.master_node_id: 2 is the drive's own node_id"),
        ("mode = \"pt\"", "mode = \"pt\"\nspeed = 1", "unknown field `speed`"),
    ];
    for (from, to, want) in cases {
        let e = parse(&with(from, to)).unwrap_err();
        assert!(e.contains(want), "{to}: {e}");
    }
}
