//! Bad numeric input, table-driven (issue 33 item 3): every flag of the offline commands and
//! every numeric scenario key, given an out-of-range, huge or non-finite value, is rejected
//! with exit code 2 and one message naming what the user typed (the flag, or the key and the
//! file) and the allowed range.

mod common;

use common::{exompc, fresh_dir, stderr};
use exompc::config::{Allowed, Limit, KEYS};

#[test]
fn every_numeric_flag_out_of_range_exits_2_naming_flag_and_range() {
    let gait = fresh_dir("bad_flags_gait.csv");
    let mut csv = String::from("t_s,hip_rad,knee_rad\n");
    for (i, t) in ["0", "0.01", "0.02", "0.03", "1e308"].iter().enumerate() {
        csv += &format!("{t},0.{i},-0.2\n");
    }
    std::fs::write(&gait, csv).unwrap();
    let g = gait.to_str().unwrap();
    let out = fresh_dir("bad_flags_out");
    let o = out.to_str().unwrap();
    // (arguments, what the message must name, the allowed range it must state)
    let cases: &[(&[&str], &str, &str)] = &[
        (
            &["simulate", "--duration", "1e308"],
            "--duration 1e308",
            "[0.01, 1000000] s",
        ),
        (
            &["simulate", "--duration", "nan"],
            "--duration NaN",
            "[0.01, 1000000]",
        ),
        (
            &["simulate", "--duration", "-1"],
            "--duration -1",
            ">= 0.01",
        ),
        (
            &["simulate", "--payload", "1e308"],
            "--payload 1e308",
            "[0, 20] kg",
        ),
        (
            &["simulate", "--payload=-inf"],
            "--payload -inf",
            "[0, 20] kg",
        ),
        // A value starting with a hyphen after a space is the flag's value, not another flag.
        (
            &["simulate", "--payload", "-inf"],
            "--payload -inf",
            "[0, 20] kg",
        ),
        (
            &["simulate", "--duration", "-inf"],
            "--duration -inf",
            ">= 0.01",
        ),
        (&["simulate", "--dof", "3"], "--dof", "1..=2"),
        (
            &["simulate", "--gait", g],
            "line 6, column 1 (t_s)",
            "±10000000 s",
        ),
        (
            &["sweep", "--duration", "1e308"],
            "--duration 1e308",
            "[0.01, 1000000] s",
        ),
        (
            &["sweep", "--payloads", "0,1e308"],
            "--payloads",
            "±1000 kg",
        ),
        (&["sweep", "--payloads", "0,25"], "--payloads", "[0, 20]"),
        (&["sweep", "--payloads", "0:0:1"], "--payloads", "> 0"),
        (&["soak", "--hours", "1e308"], "--hours 1e308", "(0, 100] h"),
        (&["soak", "--hours", "-1"], "--hours -1", "(0, 100] h"),
        (&["soak", "--hours", "nan"], "--hours NaN", "(0, 100] h"),
        (&["soak", "--payload", "21"], "--payload 21", "[0, 20] kg"),
        (
            &["soak", "--payload", "-inf"],
            "--payload -inf",
            "[0, 20] kg",
        ),
        (
            &["soak", "--trace-every", "-1"],
            "--trace-every",
            "0..=1000000000",
        ),
        (
            &["envelope", "--payloads", "5000"],
            "--payloads",
            "±1000 kg",
        ),
        (&["envelope", "--dof", "0"], "--dof", "1..=2"),
        (&["bench", "--steps", "0"], "--steps", "1..=10000000"),
        (
            &["bench", "--steps", "100000000000"],
            "--steps",
            "1..=10000000",
        ),
        (
            &["gait", "export", "--rate", "1e308"],
            "--rate 1e308",
            "[1, 100000] Hz",
        ),
        (
            &["gait", "export", "--rate", "-5"],
            "--rate -5",
            "[1, 100000] Hz",
        ),
        (
            &["gait", "export", "--duration", "-1"],
            "--duration -1",
            "> 0 s",
        ),
        (&["gait", "export", "--dof", "3"], "--dof", "1..=2"),
    ];
    for (args, names, range) in cases {
        let mut a: Vec<&str> = args.to_vec();
        if a[0] != "bench" {
            a.extend(["--out", o]);
        }
        let r = exompc(&a);
        let err = stderr(&r);
        assert_eq!(r.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(names), "{args:?} must name `{names}`: {err}");
        assert!(err.contains(range), "{args:?} must state `{range}`: {err}");
        assert!(!out.exists(), "{args:?} created {}", out.display());
    }
}

/// Values out of the range `a` allows (huge, non-finite, beyond a bound).
fn bad_values(a: &Allowed) -> Vec<String> {
    let num = |l: &Limit| match l {
        Limit::Num(x) => Some(*x),
        _ => None,
    };
    match a {
        Allowed::Real { lo, hi } => {
            let mut v: Vec<String> = ["1e308", "-1e308", "nan", "inf"].map(String::from).into();
            if let Some(x) = lo
                .as_ref()
                .and_then(|e| num(&e.at).map(|x| (x, e.inclusive)))
            {
                v.push(format!("{:?}", if x.1 { x.0 - 1.0 } else { x.0 }));
            }
            if let Some(x) = hi
                .as_ref()
                .and_then(|e| num(&e.at).map(|x| (x, e.inclusive)))
            {
                v.push(format!("{:?}", if x.1 { x.0 + 1.0 } else { x.0 }));
            }
            v
        }
        Allowed::RealOrWord { .. } => vec!["1e308".into(), "nan".into()],
        Allowed::Int { hi, .. } => {
            let mut v = vec!["1000000000000".to_string(), "-1".into()];
            if let Some(x) = num(hi) {
                v.push(format!("{}", x as u64 + 1));
            }
            v
        }
        Allowed::List { .. } => vec!["[1e308]".into(), "[nan]".into()],
        _ => Vec::new(),
    }
}

#[test]
fn every_numeric_key_out_of_range_exits_2_naming_key_file_and_range() {
    let dir = fresh_dir("bad_keys");
    std::fs::create_dir_all(&dir).unwrap();
    let mut checked = 0;
    for k in KEYS {
        // Keys of arrays of tables (`[[faults.events]]`, `[[multistage.scenarios]]`) have their
        // own tests (reliability.rs, scenarios.rs).
        if k.path.contains("events") || k.path.contains("multistage.scenarios") {
            continue;
        }
        let Some((table, key)) = k.path.rsplit_once('.') else {
            continue;
        };
        for v in bad_values(&k.allowed) {
            let text = format!("[{table}]\n{key} = {v}\n");
            // In-process through the loader the CLI uses, every case ...
            let e = exompc_cli::io::parse_scenario(&text)
                .expect_err(&format!("{} = {v} must be rejected", k.path));
            assert!(e.contains(k.path), "{} = {v}: {e}", k.path);
            assert!(
                ["allowed", "expected", "must be"]
                    .iter()
                    .any(|w| e.contains(w)),
                "{} = {v}: {e}",
                k.path
            );
            checked += 1;
        }
    }
    assert!(checked > 200, "{checked} cases");
    // ... and through the binary for the huge value of the issue: exit 2 naming file and key.
    let file = dir.join("kp.toml");
    std::fs::write(&file, "[human]\nkp = 1e308\n").unwrap();
    let r = exompc(&["config", "--check", file.to_str().unwrap()]);
    let err = stderr(&r);
    assert_eq!(r.status.code(), Some(2), "{err}");
    for part in ["kp.toml", "human.kp", "1e308", "> 0", "±1e9"] {
        assert!(err.contains(part), "must name `{part}`: {err}");
    }
}

#[test]
fn model_input_out_of_range_exits_2_naming_field_and_range() {
    for (input, names) in [
        (
            r#"{"link":"robot","payload_kg":1e308,"q":[0.2,-0.5],"qd":[0.5,-1.0],"tau":[3.0,1.0],"dt":0.01}"#,
            ["`payload_kg`", "[0, 20] kg"],
        ),
        (
            r#"{"link":"robot","payload_kg":1,"q":[0.2,-0.5],"qd":[0.5,-1.0],"tau":[1e308,1.0],"dt":1e9}"#,
            ["not finite", "`tau`"],
        ),
    ] {
        let r = common::exompc_stdin(&["model"], input);
        let err = stderr(&r);
        assert_eq!(r.status.code(), Some(2), "{input}: {err}");
        for n in names {
            assert!(err.contains(n), "{input} must name `{n}`: {err}");
        }
    }
}
