use super::*;

const EXAMPLE: &str = r#"
[timing]
dt = 0.01

[robot]
viscous_friction = 0.001

[robot.bus]
transport = "virtual"

[robot.joints.hip]
driver = "ak"
can_id = 1
model = "AK80-9"

[robot.joints.knee]
driver = "ak"
can_id = 2
model = "ak80-9"
direction = -1

[robot.thigh]
mass_kg = 1.0

[[robot.force_sensors]]
driver = "raw"
can_id = 0x300
channels = [
  { strap = "thigh", byte = 0, scale = 0.01 },
  { strap = "shank", byte = 2, scale = 0.01 },
]
"#;

fn parse(text: &str) -> Result<HardwareConfig, ConfigError> {
    let (_, hw) = split_hardware(text)?;
    HardwareConfig::from_table(hw.unwrap())
}

#[test]
fn the_hardware_tables_split_off_and_parse() {
    let (kept, hw) = split_hardware(EXAMPLE).unwrap();
    assert_eq!(kept.lines().count(), EXAMPLE.lines().count());
    assert!(kept.contains("viscous_friction") && kept.contains("[robot.thigh]"));
    assert!(!kept.contains("transport") && !kept.contains("AK80-9"));
    let cfg = HardwareConfig::from_table(hw.unwrap()).unwrap();
    assert!(matches!(cfg.bus, BusConfig::Virtual(ref v) if v.bitrate == 1_000_000));
    let Joint::Ak(knee) = &cfg.joints.knee else {
        panic!("the knee is an AK motor")
    };
    assert_eq!(knee.direction, -1);
    assert_eq!(knee.ranges().unwrap().t_max, 18.0);
    assert_eq!(knee.joint_torque_limit(), 18.0);
    assert_eq!(cfg.safety, SafetyConfig::default());
    let (_, none) = split_hardware("[robot]\nviscous_friction = 0.001\n").unwrap();
    assert!(none.is_none());
}

fn with(from: &str, to: &str) -> String {
    assert!(EXAMPLE.contains(from), "{from}");
    EXAMPLE.replacen(from, to, 1)
}

#[test]
fn bad_values_name_the_key_and_the_range() {
    let cases = [
        (
            with("can_id = 1\n", "can_id = 200\n"),
            "robot.joints.hip.can_id",
            "1..=127",
        ),
        (
            with("can_id = 2\n", "can_id = 1\n"),
            "robot.joints.knee.can_id",
            "also",
        ),
        (
            with("model = \"AK80-9\"", "model = \"AK99\""),
            "robot.joints.hip.model",
            "AK60-6",
        ),
        (
            with("direction = -1", "direction = 2"),
            "robot.joints.knee.direction",
            "1 or -1",
        ),
        (
            with("direction = -1", "torque_limit_nm = 30.0"),
            "robot.joints.knee.torque_limit_nm",
            "0..=18",
        ),
        (
            with("direction = -1", "gear_ratio = 0.0"),
            "robot.joints.knee.gear_ratio",
            "0.1..=100",
        ),
        (
            with(
                "transport = \"virtual\"",
                "transport = \"slcan\"\nport = \"/dev/x\"\nbitrate = 300000",
            ),
            "robot.bus.bitrate",
            "slcan bit rate",
        ),
        (
            with(
                "transport = \"virtual\"",
                "transport = \"virtual\"\nloss = 0.9",
            ),
            "robot.bus.loss",
            "0..=0.5",
        ),
        (
            with("byte = 2,", "byte = 7,"),
            "robot.force_sensors[0].channels[1].byte",
            "end of an 8-byte frame",
        ),
        (
            with("strap = \"shank\"", "strap = \"thigh\""),
            "robot.force_sensors[0]",
            "again",
        ),
        (
            with(
                "[robot.joints.hip]\n",
                "[robot.safety]\nreply_timeout_ms = 0.0\n\n[robot.joints.hip]\n",
            ),
            "robot.safety.reply_timeout_ms",
            "1..=1000",
        ),
        (
            with("transport = \"virtual\"", "transport = \"usb\""),
            "robot",
            "usb",
        ),
        (with("direction = -1", "directon = -1"), "robot", "directon"),
        (
            with(
                "driver = \"ak\"\ncan_id = 1",
                "driver = \"canopen\"\ncan_id = 1",
            ),
            "robot",
            "canopen",
        ),
    ];
    for (text, key, needle) in cases {
        let e = parse(&text).expect_err(key);
        assert_eq!(e.key, key, "{e}");
        assert!(e.to_string().contains(needle), "{e} lacks {needle}");
    }
    let inline = "[robot]\nbus = { transport = \"virtual\" }\n";
    let e = split_hardware(inline).unwrap_err();
    assert_eq!(e.key, "robot.bus");
}

#[test]
fn raw_force_channels_round_trip() {
    let c = ForceChannel {
        strap: Strap::Thigh,
        byte: 1,
        bytes: 2,
        signed: true,
        big_endian: false,
        scale: 0.01,
        offset_n: 0.5,
    };
    let mut d = [0u8; 8];
    c.encode(-12.34, &mut d);
    assert_eq!(&d[1..3], &(-1284i16).to_le_bytes());
    assert!((c.decode(&d).unwrap() + 12.34).abs() < 0.006);
    let be = ForceChannel {
        big_endian: true,
        signed: false,
        bytes: 4,
        byte: 4,
        ..c.clone()
    };
    be.encode(1000.0, &mut d);
    assert_eq!(&d[4..8], &99_950u32.to_be_bytes());
    assert_eq!(be.decode(&d).unwrap(), 1000.0);
    assert_eq!(c.decode(&d[..2]), None);
    // Saturation at the width.
    c.encode(1e9, &mut d);
    assert_eq!(&d[1..3], &i16::MAX.to_le_bytes());
}
