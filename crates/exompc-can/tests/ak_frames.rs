//! AK MIT-mode frames byte for byte against an independent packer written here from the
//! vendor's published formulas (CubeMars AK manual, "MIT mode" C code):
//!
//! ```c
//! int float_to_uint(float x, float x_min, float x_max, int bits) {
//!     float span = x_max - x_min;
//!     return (int) ((x - x_min) * ((float)((1 << bits) - 1)) / span);
//! }
//! // buf[0] = p >> 8; buf[1] = p & 0xFF; buf[2] = v >> 4;
//! // buf[3] = ((v & 0xF) << 4) | (kp >> 8); buf[4] = kp & 0xFF; buf[5] = kd >> 4;
//! // buf[6] = ((kd & 0xF) << 4) | (t >> 8); buf[7] = t & 0xFF;
//! ```
//!
//! The oracle works on integers where it can: each field is assembled into one 64-bit word
//! (p:16 | v:12 | kp:12 | kd:12 | t:12) and written big-endian, instead of the byte formulas.

use exompc_can::ak::{
    pack_command, pack_reply, unpack_command, unpack_reply, AkDrive, MitCommand, MitReply,
    ENTER_MOTOR_MODE, EXIT_MOTOR_MODE, SET_ZERO,
};
use exompc_can::config::{AkJoint, AkModel, AkReplyEffort, AK_MODELS};
use exompc_can::CanId;

/// The vendor formula, with the host-side clamp of the reference code (fminf/fmaxf).
fn oracle_uint(x: f64, min: f64, max: f64, bits: u32) -> u64 {
    let x = x.max(min).min(max);
    ((x - min) * ((1u64 << bits) - 1) as f64 / (max - min)).trunc() as u64
}

fn oracle_pack(r: &AkModel, c: &MitCommand) -> [u8; 8] {
    let p = oracle_uint(c.p, -r.p_max, r.p_max, 16);
    let v = oracle_uint(c.v, -r.v_max, r.v_max, 12);
    let kp = oracle_uint(c.kp, 0.0, r.kp_max, 12);
    let kd = oracle_uint(c.kd, 0.0, r.kd_max, 12);
    let t = oracle_uint(c.t, -r.t_max, r.t_max, 12);
    let word = (p << 48) | (v << 36) | (kp << 24) | (kd << 12) | t;
    word.to_be_bytes()
}

fn model(name: &str) -> AkModel {
    AkModel::by_name(name).unwrap()
}

#[test]
fn the_model_table_has_the_required_models() {
    for (name, t_max, v_max) in [
        ("AK80-9", 18.0, 50.0),
        ("AK60-6", 15.0, 45.0),
        ("AK70-10", 25.0, 50.0),
    ] {
        let m = model(name);
        assert_eq!(
            (m.p_max, m.v_max, m.t_max, m.kp_max, m.kd_max),
            (12.5, v_max, t_max, 500.0, 5.0)
        );
    }
    assert_eq!(AK_MODELS.len(), 6);
}

#[test]
fn commands_match_the_vendor_packing_byte_for_byte() {
    for m in AK_MODELS {
        let mut cases = Vec::new();
        // Edge values of every field: min, max, just inside, beyond (clamped), zero, mid.
        let edges = |lo: f64, hi: f64| {
            let span = hi - lo;
            vec![
                lo,
                hi,
                lo - 1.0,
                hi + 1.0,
                lo + span * 1e-6,
                hi - span * 1e-6,
                0.0,
                lo + span / 2.0,
                lo + span / 3.0,
            ]
        };
        for p in edges(-m.p_max, m.p_max) {
            cases.push(MitCommand {
                p,
                ..Default::default()
            });
        }
        for v in edges(-m.v_max, m.v_max) {
            cases.push(MitCommand {
                v,
                ..Default::default()
            });
        }
        for kp in edges(0.0, m.kp_max) {
            cases.push(MitCommand {
                kp,
                ..Default::default()
            });
        }
        for kd in edges(0.0, m.kd_max) {
            cases.push(MitCommand {
                kd,
                ..Default::default()
            });
        }
        for t in edges(-m.t_max, m.t_max) {
            cases.push(MitCommand {
                t,
                ..Default::default()
            });
        }
        // Mixed values from a fixed pseudo-random sequence.
        let mut x = 0x2545F4914F6CDD1Du64;
        let mut u = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..200 {
            cases.push(MitCommand {
                p: (2.0 * u() - 1.0) * m.p_max,
                v: (2.0 * u() - 1.0) * m.v_max,
                kp: u() * m.kp_max,
                kd: u() * m.kd_max,
                t: (2.0 * u() - 1.0) * m.t_max,
            });
        }
        for c in &cases {
            assert_eq!(pack_command(&m, c), oracle_pack(&m, c), "{} {c:?}", m.name);
        }
    }
}

#[test]
fn known_frames() {
    let m = model("AK80-9");
    // All zero targets and gains: mid-scale p, v, t (truncation of 32767.5, 2047.5).
    let zero = pack_command(&m, &MitCommand::default());
    assert_eq!(zero, [0x7F, 0xFF, 0x7F, 0xF0, 0x00, 0x00, 0x07, 0xFF]);
    // Full scale everywhere.
    let full = MitCommand {
        p: 12.5,
        v: 50.0,
        kp: 500.0,
        kd: 5.0,
        t: 18.0,
    };
    assert_eq!(pack_command(&m, &full), [0xFF; 8]);
    let min = MitCommand {
        p: -12.5,
        v: -50.0,
        kp: 0.0,
        kd: 0.0,
        t: -18.0,
    };
    assert_eq!(pack_command(&m, &min), [0; 8]);
    // NaN packs as the minimum, never as garbage.
    let nan = MitCommand {
        t: f64::NAN,
        ..Default::default()
    };
    assert_eq!(pack_command(&m, &nan)[6..], [0x00, 0x00]);
    assert_eq!(ENTER_MOTOR_MODE[7], 0xFC);
    assert_eq!(EXIT_MOTOR_MODE[7], 0xFD);
    assert_eq!(SET_ZERO[7], 0xFE);
    assert!(ENTER_MOTOR_MODE[..7].iter().all(|&b| b == 0xFF));
}

#[test]
fn unpacking_inverts_packing_to_within_one_step() {
    let m = model("AK70-10");
    let c = MitCommand {
        p: 1.234,
        v: -3.21,
        kp: 12.0,
        kd: 0.4,
        t: 7.77,
    };
    let back = unpack_command(&m, &pack_command(&m, &c));
    let step = |lo: f64, hi: f64, bits: u32| (hi - lo) / ((1u64 << bits) - 1) as f64;
    assert!((back.p - c.p).abs() <= step(-12.5, 12.5, 16));
    assert!((back.v - c.v).abs() <= step(-50.0, 50.0, 12));
    assert!((back.kp - c.kp).abs() <= step(0.0, 500.0, 12));
    assert!((back.kd - c.kd).abs() <= step(0.0, 5.0, 12));
    assert!((back.t - c.t).abs() <= step(-25.0, 25.0, 12));
    // Reply: id, p16, v12, effort12, temperature, error; the oracle builds it from fields.
    let r = MitReply {
        motor_id: 3,
        p: -2.0,
        v: 10.0,
        effort: -4.0,
        temperature: Some(41),
        error: Some(0),
    };
    let bytes = pack_reply(&m, &r);
    let p = oracle_uint(-2.0, -12.5, 12.5, 16);
    let v = oracle_uint(10.0, -50.0, 50.0, 12);
    let e = oracle_uint(-4.0, -25.0, 25.0, 12);
    let word = (p << 24) | (v << 12) | e;
    let mut want = [0u8; 8];
    want[0] = 3;
    want[1..6].copy_from_slice(&word.to_be_bytes()[3..8]);
    want[6] = 41;
    assert_eq!(bytes, want);
    let d = unpack_reply(&m, &bytes).unwrap();
    assert_eq!((d.motor_id, d.temperature, d.error), (3, Some(41), Some(0)));
    assert!((d.p + 2.0).abs() <= step(-12.5, 12.5, 16));
    // A 6-byte reply (older firmware) has no temperature or error; shorter is refused.
    let six = unpack_reply(&m, &bytes[..6]).unwrap();
    assert_eq!((six.temperature, six.error), (None, None));
    assert!(unpack_reply(&m, &bytes[..5]).is_none());
}

fn joint(dir: i64, ratio: f64, zero: f64) -> AkJoint {
    AkJoint {
        can_id: 2,
        model: "AK80-9".into(),
        reply_id: 0,
        gear_ratio: ratio,
        direction: dir,
        zero_offset_rad: zero,
        torque_limit_nm: Some(20.0),
        reply_effort: AkReplyEffort::Torque,
        torque_per_amp: None,
        p_max: None,
        v_max: None,
        t_max: None,
        kp_max: None,
        kd_max: None,
    }
}

#[test]
fn the_drive_maps_joint_and_motor_sides() {
    let m = model("AK80-9");
    let mut d = AkDrive::new(&joint(-1, 2.0, 0.5)).unwrap();
    // 10 N·m at the joint through a 2:1 transmission, reversed: −5 N·m at the motor, kp = kd = 0.
    let f = d.torque_frame(10.0);
    assert_eq!(f.id(), CanId::Standard(2));
    let c = unpack_command(&m, f.data().try_into().unwrap());
    assert!((c.t + 5.0).abs() < 0.01 && c.kp == 0.0 && c.kd == 0.0);
    assert_eq!(
        f.data(),
        &oracle_pack(
            &m,
            &MitCommand {
                t: -5.0,
                ..Default::default()
            }
        )
    );
    // Limited at the joint's 20 N·m (motor −10 N·m), non-finite → 0.
    let c = unpack_command(&m, d.torque_frame(99.0).data().try_into().unwrap());
    assert!((c.t + 10.0).abs() < 0.01);
    let c = unpack_command(&m, d.torque_frame(f64::NAN).data().try_into().unwrap());
    assert!(c.t.abs() < 0.01);
    // Reply of motor 2 on ID 0: q = −p/2 + 0.5.
    let r = pack_reply(
        &m,
        &MitReply {
            motor_id: 2,
            p: 1.0,
            v: 4.0,
            effort: 3.0,
            temperature: Some(30),
            error: Some(0),
        },
    );
    let rf = exompc_can::CanFrame::standard(0, &r).unwrap();
    let j = d.decode(&rf).unwrap();
    // Within one quantisation step (the reading is dithered within the step).
    assert!((j.q - 0.0).abs() < 1e-3, "{j:?}");
    assert!((j.qd + 2.0).abs() < 0.03);
    assert!((j.torque + 6.0).abs() < 0.03);
    // The dither: repeated identical replies do not give identical readings, and stay within
    // the step above the packed value.
    let again = d.decode(&rf).unwrap();
    assert_ne!(again.qd.to_bits(), j.qd.to_bits());
    let step_v = 100.0 / 4095.0 / 2.0;
    for _ in 0..100 {
        let x = d.decode(&rf).unwrap();
        let base = -unpack_reply(&m, &r).unwrap().v / 2.0;
        assert!(x.qd <= base + 1e-12 && x.qd >= base - step_v - 1e-12);
    }
    // Another motor's reply, or another ID, is not this drive's.
    let other = exompc_can::CanFrame::standard(0, &[3, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert!(d.decode(&other).is_none());
    let wrong_id = exompc_can::CanFrame::standard(5, &r).unwrap();
    assert!(d.decode(&wrong_id).is_none());
}
