//! Config help (issue 15): cross-field errors name the key the user set and the key it
//! conflicts with; `exompc config` comments every key; `exompc config --explain KEY`.

mod common;
use common::{exompc, scratch, stderr};

/// Runs `exompc config --check FILE` on `toml` (or `simulate` with `extra` flags).
fn check(name: &str, toml: &str, extra: &[&str]) -> std::process::Output {
    let path = scratch(name);
    std::fs::write(&path, toml).unwrap();
    if extra.is_empty() {
        exompc(&["config", "--check", path.to_str().unwrap()])
    } else {
        let out = common::fresh_dir(&format!("{name}.out"));
        let mut args = vec![
            "simulate",
            "--config",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        exompc(&args)
    }
}

#[test]
fn cross_field_errors_name_the_key_set_and_the_key_it_conflicts_with() {
    let cases: &[(&str, &str, &[&str], &[&str])] = &[
        // The case: the user shortened the link, the default strap no longer fits.
        (
            "thigh.toml",
            "[robot.thigh]\nlength_m = 0.2\n",
            &[],
            &[
                "robot.thigh.length_m = 0.2 (your setting) and straps.ls1_m = 0.28 (default)",
                "straps.ls1_m must be <= robot.thigh.length_m",
                "set straps.ls1_m <= 0.2 or lengthen robot.thigh.length_m",
            ],
        ),
        // The user's value is the one out of range: it leads.
        (
            "strap.toml",
            "[straps]\nls2_m = 0.5\n",
            &[],
            &["straps.ls2_m = 0.5 (your setting) and robot.shank.length_m = 0.43 (default)"],
        ),
        // Both set by the user.
        (
            "both.toml",
            "[robot.thigh]\nlength_m = 0.2\n[straps]\nls1_m = 0.3\n",
            &[],
            &["straps.ls1_m = 0.3 (your setting) and robot.thigh.length_m = 0.2 (your setting)"],
        ),
        (
            "com.toml",
            "[robot.shank]\nlength_m = 0.1\n",
            &[],
            &[
                "robot.shank.length_m = 0.1 (your setting) and robot.shank.com_m = 0.18 (default)",
                "the centre of mass lies on the link",
            ],
        ),
        (
            "payload_pos.toml",
            "[robot.shank]\nlength_m = 0.2\ncom_m = 0.1\n",
            &[],
            &["robot.shank.length_m = 0.2 (your setting) and robot.payload_position_m = 0.215 (default)"],
        ),
        (
            "np.toml",
            "[controller]\nnp = 2\n",
            &[],
            &[
                "controller.np = 2 (your setting) and controller.nc = 3 (default)",
                "set controller.nc <= 2 or raise controller.np",
            ],
        ),
        (
            "nc.toml",
            "[controller]\nnc = 1\n[multistage]\nformulation = \"coupled\"\nrobust_horizon = 2\n",
            &[],
            &["multistage.robust_horizon = 2 (your setting) and controller.nc = 1 (your setting)"],
        ),
        (
            "floor.toml",
            "[multistage]\npayloads_kg = [0.0, 1.0, 2.0, 3.0]\nprobability_floor = 0.3\n",
            &[],
            &["multistage.probability_floor = 0.3 (your setting) and multistage.payloads_kg"],
        ),
        (
            "swing.toml",
            "[trajectory]\nbase_frequency_hz = 0.1\n",
            &[],
            &["trajectory.base_frequency_hz = 0.1 (your setting) and trajectory.frequency_swing_hz = 0.2 (default)"],
        ),
        // A flag against a file value.
        (
            "dt.toml",
            "[timing]\ndt = 0.5\n",
            &["--duration", "0.1"],
            &[
                "--duration 0.1: conflicting values: timing.duration_2dof_s = 0.1 (set by --duration) \
                 and timing.dt = 0.5 (your setting)",
                "shorten timing.dt",
            ],
        ),
    ];
    for (name, toml, extra, needles) in cases {
        let out = check(name, toml, extra);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(err.starts_with("error: "), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: one line: {err}");
        for n in *needles {
            assert!(err.contains(n), "{name}: `{n}` not in: {err}");
        }
    }
}

use exompc::config::{explain, Allowed, Experiment, Limit, KEYS};
use std::collections::BTreeSet;

/// The scenario as a TOML tree with the optional keys filled in (a solve time budget and one
/// fault event), so that every key a file may hold is present.
fn full_tree() -> toml::Table {
    let text = "[controller.sqp]\nmax_time_us = 5000\n[[faults.events]]\nkind = \"spike\"\n\
                channel = \"f1\"\nstart_s = 1.0\nduration_s = 0.1\nmagnitude = 3.0\n";
    let s = exompc_cli::io::parse_scenario(text).unwrap();
    match toml::Value::try_from(&s).unwrap() {
        toml::Value::Table(t) => t,
        _ => unreachable!(),
    }
}

/// [`full_tree`] with one `[[multistage.scenarios]]` table holding every key of a scenario
/// override (set to the base values), so that the scenario keys can be walked and probed.
fn scenario_tree() -> toml::Table {
    let mut t = full_tree();
    let spec = toml::Value::try_from(exompc::config::scenarios::ScenarioSpec::every_key()).unwrap();
    let ms = t.get_mut("multistage").unwrap().as_table_mut().unwrap();
    ms.insert("scenarios".into(), toml::Value::Array(vec![spec]));
    t
}

/// The tree a key is probed in: [`scenario_tree`] for the scenario-override keys.
fn tree_for(path: &str) -> toml::Table {
    if path.starts_with("multistage.scenarios") {
        scenario_tree()
    } else {
        full_tree()
    }
}

/// Dotted paths of every table and key of `t`; the keys of an array of tables are
/// `<array>.<key>`.
fn walk(t: &toml::Table, prefix: &str, out: &mut BTreeSet<String>) {
    for (k, v) in t {
        let path = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        out.insert(path.clone());
        match v {
            toml::Value::Table(sub) => walk(sub, &path, out),
            toml::Value::Array(a) => {
                if let Some(toml::Value::Table(sub)) = a.first() {
                    walk(sub, &path, out);
                }
            }
            _ => {}
        }
    }
}

#[test]
fn every_key_is_explained_and_every_explanation_names_a_key() {
    let mut keys = BTreeSet::new();
    walk(&scenario_tree(), "", &mut keys);
    // `trajectory.file` (a recorded gait's CSV) only parses back with the recording loaded by
    // the CLI, so the serialised tree cannot hold it; it is a key all the same.
    keys.insert("trajectory.file".to_string());
    assert!(keys.len() > 120, "{}", keys.len());
    let missing: Vec<&String> = keys.iter().filter(|k| explain(k).is_none()).collect();
    assert!(
        missing.is_empty(),
        "keys without an explanation: {missing:?}"
    );
    let unknown: Vec<&str> = KEYS
        .iter()
        .map(|d| d.path)
        .filter(|p| !keys.contains(*p))
        .collect();
    assert!(
        unknown.is_empty(),
        "explanations of keys that do not exist: {unknown:?}"
    );
    let mut seen = BTreeSet::new();
    for d in KEYS {
        assert!(seen.insert(d.path), "{} explained twice", d.path);
        assert!(
            d.meaning.len() > 8 && d.meaning.ends_with('.'),
            "{}: {}",
            d.path,
            d.meaning
        );
        assert!(!d.source.is_empty(), "{}: no source", d.path);
        let numeric = matches!(
            d.allowed,
            Allowed::Real { .. }
                | Allowed::Int { .. }
                | Allowed::List { .. }
                | Allowed::RealOrWord { .. }
        );
        assert_eq!(numeric, !d.unit.is_empty(), "{}: unit `{}`", d.path, d.unit);
        for dep in d.allowed.depends_on() {
            assert!(keys.contains(dep), "{} depends on unknown {dep}", d.path);
        }
    }
}

/// Sets `path` (a dotted key; `faults.events.K` is the key of the one fault event) in `tree`.
fn set(tree: &mut toml::Table, path: &str, v: toml::Value) {
    let parts: Vec<&str> = path.split('.').collect();
    let (last, tables) = parts.split_last().unwrap();
    let mut node = tree;
    for p in tables {
        node = match node.get_mut(*p).unwrap() {
            toml::Value::Table(t) => t,
            toml::Value::Array(a) => a[0].as_table_mut().unwrap(),
            _ => panic!("{path}"),
        };
    }
    node.insert((*last).to_string(), v);
}

fn get(tree: &toml::Table, path: &str) -> toml::Value {
    let mut node = toml::Value::Table(tree.clone());
    for p in path.split('.') {
        if let toml::Value::Array(a) = &node {
            node = a[0].clone();
        }
        node = node.get(p).unwrap().clone();
    }
    node
}

/// `Ok(())` when the scenario with `path = v` is valid as far as `path` goes (a rule about
/// another key may still fail); `Err(message)` when `path` itself is rejected.
fn probe(path: &str, v: toml::Value) -> Result<(), String> {
    let mut tree = tree_for(path);
    set(&mut tree, path, v);
    let s: Experiment = toml::Value::Table(tree)
        .try_into()
        .map_err(|e: toml::de::Error| e.message().to_string())?;
    // `faults.events.start_s` is reported as `faults.events[0].start_s`.
    let reported = path
        .replacen("faults.events.", "faults.events[0].", 1)
        .replacen("multistage.scenarios.", "multistage.scenarios[0].", 1);
    match exompc::scenario::validate(&s) {
        Err(e) if e.field == reported || e.field.starts_with(&format!("{reported}[")) => {
            Err(e.to_string())
        }
        _ => Ok(()),
    }
}

fn limit(tree: &toml::Table, l: Limit) -> f64 {
    match l {
        Limit::Num(v) => v,
        Limit::Key(k) => {
            let v = get(tree, k);
            v.as_float().or(v.as_integer().map(|i| i as f64)).unwrap()
        }
        Limit::InverseLen(k) => 1.0 / get(tree, k).as_array().unwrap().len() as f64,
    }
}

/// The documented ranges agree with `Experiment::validate`: each end is accepted or rejected as
/// documented and values just beyond it are rejected; every word of a choice is accepted and
/// the list is serde's own.
#[test]
fn documented_ranges_agree_with_validation() {
    let f = toml::Value::Float;
    let beyond = |v: f64, up: bool| {
        let d = (v.abs() * 1e-6).max(1e-9);
        if up {
            v + d
        } else {
            v - d
        }
    };
    for d in KEYS {
        let p = d.path;
        let tree = tree_for(p);
        match d.allowed {
            Allowed::Real { lo, hi } => {
                assert!(probe(p, f(f64::NAN)).is_err(), "{p}: NaN accepted");
                match lo {
                    Some(e) => {
                        let v = limit(&tree, e.at);
                        assert_eq!(probe(p, f(v)).is_ok(), e.inclusive, "{p} = {v} (lower end)");
                        assert!(probe(p, f(beyond(v, false))).is_err(), "{p} below {v}");
                    }
                    None => assert!(probe(p, f(-1e9)).is_ok(), "{p} = -1e9"),
                }
                match hi {
                    Some(e) => {
                        let v = limit(&tree, e.at);
                        assert_eq!(probe(p, f(v)).is_ok(), e.inclusive, "{p} = {v} (upper end)");
                        assert!(probe(p, f(beyond(v, true))).is_err(), "{p} above {v}");
                    }
                    None => assert!(probe(p, f(1e9)).is_ok(), "{p} = 1e9"),
                }
            }
            Allowed::RealOrWord { lo, word } => {
                let text = |t: &str| toml::Value::String(t.to_string());
                assert!(probe(p, f(f64::NAN)).is_err(), "{p}: NaN accepted");
                assert!(probe(p, f(lo)).is_ok(), "{p} = {lo}");
                assert!(probe(p, f(beyond(lo, false))).is_err(), "{p} below {lo}");
                assert!(probe(p, f(1e9)).is_ok(), "{p} = 1e9");
                assert!(probe(p, text(word)).is_ok(), "{p} = {word}");
                let e = probe(p, text("bogus")).unwrap_err();
                assert!(e.contains(word), "{p}: {e}");
            }
            Allowed::Int { lo, hi } => {
                let i = |v: i64| toml::Value::Integer(v);
                let hi = limit(&tree, hi) as i64;
                assert!(probe(p, i(lo as i64)).is_ok(), "{p} = {lo}");
                assert!(probe(p, i(lo as i64 - 1)).is_err(), "{p} = {lo} - 1");
                assert!(probe(p, i(hi)).is_ok(), "{p} = {hi}");
                assert!(probe(p, i(hi + 1)).is_err(), "{p} = {hi} + 1");
            }
            Allowed::List {
                min_len,
                max_len,
                lo,
                hi,
            } => {
                let list = |n: usize, v: f64| toml::Value::Array(vec![f(v); n]);
                assert!(probe(p, list(min_len, lo)).is_ok(), "{p}: {min_len} × {lo}");
                assert!(probe(p, list(max_len, hi)).is_ok(), "{p}: {max_len} × {hi}");
                if min_len > 0 {
                    assert!(
                        probe(p, list(min_len - 1, lo)).is_err(),
                        "{p}: {min_len} - 1"
                    );
                }
                assert!(
                    probe(p, list(max_len + 1, lo)).is_err(),
                    "{p}: {max_len} + 1"
                );
                assert!(
                    probe(p, list(1, beyond(lo, false))).is_err(),
                    "{p}: below {lo}"
                );
                assert!(
                    probe(p, list(1, beyond(hi, true))).is_err(),
                    "{p}: above {hi}"
                );
            }
            Allowed::Choice(words) => {
                for w in words {
                    assert!(
                        probe(p, toml::Value::String(w.to_string())).is_ok(),
                        "{p} = {w}"
                    );
                }
                let e = probe(p, toml::Value::String("bogus".into())).unwrap_err();
                let listed: BTreeSet<&str> = e
                    .split("expected")
                    .nth(1)
                    .unwrap_or_else(|| panic!("{p}: {e}"))
                    .split('`')
                    .skip(1)
                    .step_by(2)
                    .collect();
                assert_eq!(listed, words.iter().copied().collect(), "{p}: {e}");
            }
            Allowed::Path => {
                let e = probe(p, toml::Value::Integer(3)).unwrap_err();
                assert!(e.contains("string"), "{p}: {e}");
            }
            Allowed::Name(n) => {
                let text = |t: &str| toml::Value::String(t.to_string());
                assert!(probe(p, text("a name")).is_ok(), "{p} = a name");
                assert!(
                    probe(p, text(&"x".repeat(n))).is_ok(),
                    "{p}: {n} characters"
                );
                for bad in ["", " lead", "a,b", "q\"t", &"x".repeat(n + 1)] {
                    assert!(probe(p, text(bad)).is_err(), "{p} = {bad:?} accepted");
                }
            }
            Allowed::Controller => {
                // Every registered controller's name, nothing else; the error lists them.
                let names: Vec<&str> = exompc::scenario::controllers()
                    .iter()
                    .map(|c| c.name())
                    .collect();
                for n in &names {
                    assert!(
                        probe(p, toml::Value::String(n.to_string())).is_ok(),
                        "{p} = {n}"
                    );
                }
                let e = probe(p, toml::Value::String("bogus".into())).unwrap_err();
                for n in &names {
                    assert!(e.contains(&format!("\"{n}\"")), "{p}: {e}");
                }
                assert!(probe(p, toml::Value::String("Not a name".into())).is_err());
            }
            Allowed::Bool => {
                for b in [true, false] {
                    assert!(probe(p, toml::Value::Boolean(b)).is_ok(), "{p} = {b}");
                }
            }
            Allowed::Table | Allowed::Tables => {
                assert!(
                    matches!(get(&tree, p), toml::Value::Table(_) | toml::Value::Array(_)),
                    "{p}"
                );
            }
        }
    }
}

#[test]
fn config_prints_every_key_with_a_comment_and_parses_back() {
    let out = exompc(&["config"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let mut keys = 0;
    for (i, l) in lines.iter().enumerate() {
        let is_key = !l.starts_with([' ', '#']) && l.contains(" = ");
        let is_table = l.starts_with('[');
        if is_key || is_table {
            keys += 1;
            let above = lines[i - 1];
            assert!(above.starts_with("# "), "no comment above `{l}`");
            assert!(above.contains("docs/"), "no source above `{l}`: {above}");
        }
        if is_key
            && !l.contains('"')
            && !l.contains("true")
            && !l.contains("false")
            && !l.contains("[]")
        {
            assert!(
                lines[i - 1].starts_with("# ["),
                "no unit above `{l}`: {}",
                lines[i - 1]
            );
        }
    }
    assert!(keys > 120, "{keys}");
    assert!(text.contains("# [m] Thigh strap distance Ls1 from the hip. Allowed: finite, in (0, robot.thigh.length_m]. (docs/MODEL.md §4)\nls1_m = 0.28"));
    assert_eq!(
        exompc_cli::io::parse_scenario(&text).unwrap(),
        Experiment::default()
    );
    // The commented-out optional keys are valid too.
    let uncommented = text
        .replace("# max_time_us = 5000", "max_time_us = 5000")
        .replace("events = []\n", "")
        .lines()
        .map(|l| {
            l.strip_prefix("# [[")
                .map_or(l.to_string(), |r| format!("[[{r}"))
        })
        .collect::<Vec<_>>()
        .join("\n");
    let uncommented: String = uncommented
        .lines()
        .map(|l| {
            for k in [
                "kind",
                "channel",
                "start_s",
                "duration_s",
                "magnitude",
                "name",
                "payload_kg",
                "straps.stiffness",
                "robot.shank.mass_kg",
            ] {
                if let Some(r) = l.strip_prefix(&format!("# {k} = ")) {
                    return format!("{k} = {r}");
                }
            }
            l.to_string()
        })
        .collect::<Vec<_>>()
        .join("\n");
    let s = exompc_cli::io::parse_scenario(&uncommented).expect("optional keys uncommented");
    assert_eq!(s.controller.sqp.max_time_us, Some(5000));
    assert_eq!(s.faults.events.len(), 1);
    assert_eq!(s.multistage.scenarios.len(), 1);
    assert_eq!(s.multistage.scenarios[0].straps.stiffness, Some(600.0));
}

#[test]
fn explain_prints_unit_meaning_default_range_and_source() {
    let out = exompc(&["config", "--explain", "trajectory.hip_amplitude"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    for want in [
        "trajectory.hip_amplitude",
        "unit     rad",
        "default  0.3",
        "allowed  finite, >= 0",
        "source   docs/MODEL.md §6",
        "hip swing amplitude",
    ] {
        assert!(text.contains(want), "`{want}` not in:\n{text}");
    }
    let out = exompc(&["config", "--explain", "straps.ls1_m"]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("(0, robot.thigh.length_m] (by default robot.thigh.length_m = 0.43)"),
        "{text}"
    );
    // A table: its keys with defaults, units and meanings.
    let out = exompc(&["config", "--explain", "robot.thigh"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    for want in [
        "[robot.thigh]",
        "length_m",
        "= 0.43 [m]",
        "mass_kg",
        "com_m",
        "inertia_kgm2",
        "docs/MODEL.md §3",
    ] {
        assert!(text.contains(want), "`{want}` not in:\n{text}");
    }
    let out = exompc(&["config", "--explain", "faults.events[0].kind"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8(out.stdout)
        .unwrap()
        .contains("\"dropout\""));
    // Unknown keys get the whole-schema suggestion.
    for (key, want) in [
        ("payload_kg", "`payload_kg` belongs in [uncertainty]"),
        (
            "robot.mass_kg",
            "`mass_kg` belongs in [robot.shank] or [robot.thigh]",
        ),
        ("trajectory.hip_amplitud", "did you mean `hip_amplitude`"),
        ("human.height_m.x", "not a table"),
    ] {
        let out = exompc(&["config", "--explain", key]);
        assert_eq!(out.status.code(), Some(2), "{key}");
        let err = stderr(&out);
        assert!(err.contains(want), "{key}: {err}");
    }
    let out = exompc(&[
        "config",
        "--explain",
        "multistage.scenarios[1].straps.stiffness",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("default  the base straps.stiffness (937.5)"),
        "{text}"
    );
}

/// Entries of `dir` (names), sorted.
fn entries(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn simulate_and_soak_refuse_a_folder_with_earlier_results_unless_forced() {
    let dir = common::fresh_dir("earlier_simulate");
    let d = dir.to_str().unwrap();
    let sim = |extra: &[&str]| {
        let mut a = vec!["simulate", "--dof", "1", "--controller", "pd", "--out", d];
        a.extend_from_slice(extra);
        exompc(&a)
    };
    let first = sim(&["--plot", "--duration", "0.2"]);
    assert!(first.status.success(), "{}", stderr(&first));
    assert!(dir.join("states.png").is_file());
    let before = std::fs::read(dir.join("summary.json")).unwrap();
    let again = sim(&["--duration", "0.2"]);
    assert_eq!(again.status.code(), Some(2));
    let err = stderr(&again);
    assert!(
        err.contains("already holds results of an earlier run")
            && err.contains("--force")
            && err.contains("summary.json")
            && err.contains("states.png"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(dir.join("summary.json")).unwrap(),
        before,
        "untouched"
    );
    // --force replaces exompc's files only: the old figures go (no --plot this time), the
    // user's own file and a leftover temporary trace of a killed run are handled.
    std::fs::write(dir.join("notes.txt"), "mine").unwrap();
    std::fs::write(dir.join(".trace.csv.tmp.99999.0"), "half").unwrap();
    let forced = sim(&["--force", "--duration", "0.3"]);
    assert!(forced.status.success(), "{}", stderr(&forced));
    assert_eq!(entries(&dir), ["notes.txt", "summary.json", "trace.csv"]);
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap();
    assert!(
        (s["duration_s"].as_f64().unwrap() - 0.3).abs() < 1e-9,
        "{s}"
    );

    let dir = common::fresh_dir("earlier_soak");
    let d = dir.to_str().unwrap();
    let soak = |force: bool| {
        let mut a = vec!["soak", "--hours", "0.0002", "--out", d];
        if force {
            a.push("--force");
        }
        exompc(&a)
    };
    assert!(soak(false).status.success());
    let again = soak(false);
    assert_eq!(again.status.code(), Some(2), "{}", stderr(&again));
    assert!(
        stderr(&again).contains("earlier soak (soak.json)"),
        "{}",
        stderr(&again)
    );
    let forced = soak(true);
    assert!(forced.status.success(), "{}", stderr(&forced));
    assert_eq!(entries(&dir), ["soak.json"]);
}

#[test]
fn strict_makes_a_degraded_run_exit_3() {
    // 20 kg is far outside the scenarios: with the paper's method (the robust default holds it)
    // the monitors take over (verdict degraded).
    let cfg_dir = common::fresh_dir("strict_config");
    std::fs::create_dir_all(&cfg_dir).unwrap();
    let paper = cfg_dir.join("paper.toml");
    std::fs::write(&paper, "[controller]\nmethod = \"paper\"\n").unwrap();
    let paper = paper.to_str().unwrap().to_string();
    let run = |strict: bool| {
        let dir = common::fresh_dir(&format!("strict_{strict}"));
        let mut a = vec![
            "simulate",
            "--config",
            &paper,
            "--dof",
            "1",
            "--payload",
            "20",
            "--out",
        ];
        let d = dir.to_str().unwrap().to_string();
        a.push(&d);
        if strict {
            a.push("--strict");
        }
        let o = exompc(&a);
        (o, dir)
    };
    let (plain, _) = run(false);
    assert_eq!(plain.status.code(), Some(0), "{}", stderr(&plain));
    let stdout = String::from_utf8_lossy(&plain.stdout).into_owned();
    assert!(stdout.contains("verdict: degraded"), "{stdout}");
    let (strict, dir) = run(true);
    assert_eq!(strict.status.code(), Some(3), "{}", stderr(&strict));
    assert!(
        stderr(&strict).contains("run degraded (--strict): verdict: degraded"),
        "{}",
        stderr(&strict)
    );
    assert!(dir.join("summary.json").is_file(), "results are written");
    // An ok run passes --strict.
    let dir = common::fresh_dir("strict_ok");
    let ok = exompc(&[
        "simulate",
        "--dof",
        "1",
        "--duration",
        "2",
        "--strict",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(ok.status.code(), Some(0), "{}", stderr(&ok));
    // sweep and soak take the flag too.
    let dir = common::fresh_dir("strict_sweep");
    let sweep = exompc(&[
        "sweep",
        "--config",
        &paper,
        "--dof",
        "1",
        "--payloads",
        "20",
        "--controllers",
        "msnmpc",
        "--quiet",
        "--strict",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(sweep.status.code(), Some(3), "{}", stderr(&sweep));
    let dir = common::fresh_dir("strict_soak");
    let soak = exompc(&[
        "soak",
        "--hours",
        "0.0002",
        "--strict",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let code = soak.status.code();
    let out = String::from_utf8_lossy(&soak.stdout).into_owned();
    let want = if out.contains("verdict: ok") { 0 } else { 3 };
    assert_eq!(code, Some(want), "{out}");
}

#[test]
fn run_and_virtual_robot_refuse_a_folder_with_earlier_results() {
    for cmd in ["run", "virtual-robot"] {
        let dir = common::fresh_dir(&format!("earlier_{cmd}"));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("summary.json"), "{}").unwrap();
        let key = dir.with_extension("key");
        let _ = std::fs::remove_file(&key);
        assert!(exompc(&["keygen", key.to_str().unwrap()]).status.success());
        let mut a = vec![
            cmd,
            "--key",
            key.to_str().unwrap(),
            "--quiet",
            "--no-mlock",
            "--rt-priority",
            "0",
            "--connect-timeout",
            "0.2",
        ];
        if cmd == "run" {
            a.extend(["--robot", "127.0.0.1:9"]);
        }
        a.extend(["--out", dir.to_str().unwrap()]);
        let o = exompc(&a);
        assert_eq!(o.status.code(), Some(2), "{cmd}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("earlier run (summary.json)"),
            "{cmd}: {}",
            stderr(&o)
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("summary.json")).unwrap(),
            "{}"
        );
    }
}

/// The `[controller.robust]` keys removed in issue 31 (fixed constants now) are rejected, in a
/// file (exit 2) and by `set`, with an error naming the key; the knobs that stay load.
#[test]
fn removed_robust_keys_are_rejected_naming_the_key() {
    for key in exompc::control::REMOVED_ROBUST_KEYS {
        let out = check(
            &format!("removed_{key}.toml"),
            &format!("[controller.robust]\n{key} = 0.5\n"),
            &[],
        );
        assert_eq!(out.status.code(), Some(2), "{key}");
        let err = stderr(&out);
        assert!(
            err.contains(&format!("controller.robust.{key} is no longer a setting")),
            "{key}: {err}"
        );
        let s = exompc::config::Experiment::default();
        let e = exompc_cli::io::set_key(
            &s,
            &format!("controller.robust.{key}"),
            exompc_cli::io::parse_value("0.5"),
        )
        .unwrap_err();
        assert!(e.contains("is no longer a setting"), "{key}: {e}");
    }
    let kept = "[controller.robust]\nfilter_aware = \"always\"\nrelease_s = 1.0\n\
                human_bandwidth_hz = 4.0\nweight_smoothing_s = 0.2\nobserver_velocity_gain = 20.0\n\
                intent_estimate = \"paper\"\nintent_gains = \"configured\"\nvelocity_tracking = \"joint\"\n";
    let out = check("robust_kept.toml", kept, &[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
}
