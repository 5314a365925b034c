//! Config help for people: where each key's value came from (a cross-field error names the
//! key the user set and the one it conflicts with), the commented default scenario of
//! `exompc config`, and `exompc config --explain KEY`.

use exompc::config::ConfigError;
use std::collections::BTreeSet;

/// Where the keys of a scenario got their values: the config file and command-line flags.
#[derive(Debug, Clone, Default)]
pub struct KeyOrigins {
    /// Dotted keys the config file sets (`robot.thigh.length_m`, `faults.events`).
    pub file: BTreeSet<String>,
    /// Keys set by a command-line flag, with the flag (`timing.duration_2dof_s`, `--duration`).
    pub flags: Vec<(String, String)>,
    /// Label of a key set by neither (`default`, or `current value` for an edited scenario).
    pub unset: &'static str,
}

impl KeyOrigins {
    /// Origins of a config file's keys (`table` is the parsed file); the rest are defaults.
    pub fn of_file(table: &toml::Table) -> Self {
        let mut file = BTreeSet::new();
        collect_keys(table, "", &mut file);
        KeyOrigins {
            file,
            flags: Vec::new(),
            unset: "default",
        }
    }

    /// Records that `flag` set `key` (a later flag on the same key wins).
    pub fn set_by_flag(&mut self, key: &str, flag: &str) {
        self.flags.retain(|(k, _)| k != key);
        self.flags.push((key.to_string(), flag.to_string()));
    }

    /// How to label the value of `key`: `your setting`, `set by --duration`, `default`.
    pub fn label(&self, key: &str) -> String {
        if let Some((_, flag)) = self.flags.iter().find(|(k, _)| k == key) {
            return format!("set by {flag}");
        }
        // `faults.events[0].start_s` is set when the file has `faults.events`; an indexed
        // key `multistage.payloads_kg[1]` when it has `multistage.payloads_kg`.
        let mut k = key.to_string();
        loop {
            if self.file.contains(&k) {
                return "your setting".into();
            }
            match k.rfind(['.', '[']) {
                Some(i) => k.truncate(i),
                None => return self.unset.into(),
            }
        }
    }

    /// True when the user set `key` (in the file or by a flag).
    pub fn is_set(&self, key: &str) -> bool {
        self.label(key) != self.unset
    }
}

/// Dotted paths of the leaf keys of `t` (arrays, including arrays of tables, count as leaves).
fn collect_keys(t: &toml::Table, prefix: &str, out: &mut BTreeSet<String>) {
    for (k, v) in t {
        let path = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(sub) => collect_keys(sub, &path, out),
            _ => {
                out.insert(path);
            }
        }
    }
}

/// A validation error as one line that says where each value came from. For a cross-field
/// rule it leads with the key the user set and names the one it conflicts with:
/// `conflicting values: robot.thigh.length_m = 0.2 (your setting) and straps.ls1_m = 0.28
/// (default): straps.ls1_m must be <= robot.thigh.length_m (the thigh strap sits on the
/// robot's thigh link); set straps.ls1_m <= 0.2 or lengthen robot.thigh.length_m`.
pub fn describe_error(e: &ConfigError, origins: &KeyOrigins) -> String {
    // Huge numbers as a user writes them (`1e308`), not as 309 digits.
    let mut e = e.clone();
    e.value = compact_text(&e.value);
    if let Some(d) = e.depends_on.as_mut() {
        d.value = compact_text(&d.value);
    }
    let e = &e;
    let Some(d) = &e.depends_on else {
        return e.to_string();
    };
    let mine = (&e.field, &e.value, origins.label(&e.field));
    let other = (&d.key, &d.value, origins.label(&d.key));
    // Lead with what the user set; the field first when both or neither are set.
    let (first, second) = if origins.is_set(&d.key) && !origins.is_set(&e.field) {
        (other, mine)
    } else {
        (mine, other)
    };
    format!(
        "conflicting values: {} = {} ({}) and {} = {} ({}): {} must be {} {} ({}); {}",
        first.0,
        first.1,
        first.2,
        second.0,
        second.1,
        second.2,
        e.field,
        d.relation,
        d.key,
        d.reason,
        d.fix
    )
}

/// `v` as a user would write it: plain decimals for ordinary magnitudes, scientific notation
/// (`1e308`, `1e-12`) for very large or small ones.
pub fn compact_number(v: f64) -> String {
    let a = v.abs();
    if v.is_finite() && a != 0.0 && !(1e-6..1e9).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// [`compact_number`] of a number written as text (unchanged when `text` is no number).
pub fn compact_text(text: &str) -> String {
    match text.trim().parse::<f64>() {
        Ok(v) if text.len() > 12 => compact_number(v),
        _ => text.to_string(),
    }
}

/// Adds a `# ...` comment line (unit, meaning, allowed values, source) above every table
/// header and every `key = value` line of `toml` (a serialised scenario), and the optional
/// keys that are absent as commented-out examples. The result parses to the same scenario.
pub fn comment_scenario_toml(toml: &str) -> String {
    let mut out = String::with_capacity(toml.len() * 4);
    let mut table = String::new();
    let comment = |out: &mut String, path: &str| {
        if let Some(doc) = exompc::config::explain(path) {
            out.push_str("# ");
            out.push_str(&doc.comment());
            out.push('\n');
        }
    };
    // Commented-out examples of the optional keys, written at the end of their table.
    let optional = |out: &mut String, table: &str| {
        if table == "controller.sqp" && !toml.contains("max_time_us") {
            comment(out, "controller.sqp.max_time_us");
            out.push_str("# max_time_us = 5000\n");
        }
        if table == "multistage" && !toml.contains("[[multistage.scenarios]]") {
            out.push_str(
                "# Named scenarios instead of the payload list (leave payloads_kg out; one \
                 [[multistage.scenarios]] table each, docs/SCENARIOS.md):\n",
            );
            out.push_str("# [[multistage.scenarios]]\n");
            for (key, example) in [
                ("name", "\"soft straps\""),
                ("payload_kg", "1.0"),
                ("straps.stiffness", "600.0"),
                ("robot.shank.mass_kg", "2.0"),
            ] {
                if let Some(doc) = exompc::config::explain(&format!("multistage.scenarios.{key}")) {
                    out.push_str(&format!("# {key} = {example}    # {}\n", doc.comment()));
                }
            }
        }
        if table == "faults" && toml.contains("events = []") {
            out.push_str(
                "# An event (replace `events = []` above by one [[faults.events]] table per event):\n",
            );
            out.push_str("# [[faults.events]]\n");
            for (key, example) in [
                ("kind", "\"spike\""),
                ("channel", "\"f1\""),
                ("start_s", "5.0"),
                ("duration_s", "0.1"),
                ("magnitude", "30.0"),
            ] {
                if let Some(doc) = exompc::config::explain(&format!("faults.events.{key}")) {
                    out.push_str(&format!("# {key} = {example}    # {}\n", doc.comment()));
                }
            }
        }
    };
    for line in toml.lines() {
        let t = line.trim();
        if t.starts_with('[') && !line.starts_with(' ') {
            let name = t.trim_matches(|c| c == '[' || c == ']').trim();
            // The previous table ends here (a blank line was already written before us).
            if out.ends_with("\n\n") {
                out.pop();
                optional(&mut out, &table);
                out.push('\n');
            }
            table = name.to_string();
            comment(&mut out, &table);
        } else if let Some((key, _)) = line.split_once(" = ") {
            let key = key.trim();
            if !line.starts_with(' ') && !key.is_empty() && !key.contains(['#', '"']) {
                let path = if table.is_empty() {
                    key.to_string()
                } else {
                    format!("{table}.{key}")
                };
                comment(&mut out, &path);
            }
        }
        out.push_str(line);
        out.push('\n');
    }
    optional(&mut out, &table);
    out
}
