//! File input/output for the CLI: scenario loading, atomic writes and output folders.

use crate::config_help::{describe_error, KeyOrigins};
use crate::error::CliError;
use exompc::config::{Channel, Experiment, FaultEvent, FaultKind};
use serde::Deserialize;
use serde_json::Value;
use std::fs::{self, File};
use std::io::Read as _;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Comment header printed above the default scenario by `exompc config`.
pub const CONFIG_HEADER: &str = "\
# exompc scenario: the embedded default, as stated in docs/MODEL.md.
# Units are SI (m, kg, s, rad, N, N·m). Every key is optional: a file that names only a
# few keys overrides just those and keeps the defaults for the rest.
# Above each key: [unit] meaning, allowed values, and where it comes from (docs/MODEL.md §n).
# One key in full: exompc config --explain KEY (e.g. trajectory.hip_amplitude, robot.thigh).
# Optional keys are shown commented out (# max_time_us, # [[faults.events]]).
# Load with: exompc simulate --config FILE
";

/// The default scenario as TOML with [`CONFIG_HEADER`] on top (the output of `exompc config`).
/// Every key carries a comment with its unit, meaning, allowed values and source.
pub fn default_config_toml() -> Result<String, CliError> {
    let body = toml::to_string_pretty(&Experiment::default())
        .map_err(|e| CliError::Runtime(format!("cannot serialise the default scenario: {e}")))?;
    let body = crate::config_help::comment_scenario_toml(&body);
    Ok(format!("{CONFIG_HEADER}\n{body}"))
}

/// Loads a scenario: the validated default when `path` is `None`, otherwise the TOML file at
/// `path` applied on top of the default (partial override), then validated.
///
/// Unknown keys are rejected with their table path and the closest valid name; `nan`/`inf`
/// parse as floats so that validation rejects them by field name.
pub fn load_scenario(path: Option<&Path>) -> Result<Experiment, CliError> {
    load_scenario_with_origins(path).map(|(s, _)| s)
}

/// [`load_scenario`], also returning which keys the file set (for messages that say which
/// value of a conflicting pair the user wrote).
pub fn load_scenario_with_origins(
    path: Option<&Path>,
) -> Result<(Experiment, KeyOrigins), CliError> {
    let Some(path) = path else {
        let s = Experiment::default();
        exompc::scenario::validate(&s)
            .map_err(|e| CliError::Config(format!("default scenario: {e}")))?;
        return Ok((s, KeyOrigins::of_file(&toml::Table::new())));
    };
    let shown = path.display();
    let text = fs::read_to_string(path)
        .map_err(|e| CliError::Config(format!("cannot read config file {shown}: {e}")))?;
    let base = path.parent().unwrap_or(Path::new(""));
    parse_scenario_with_origins_in(&text, base)
        .map_err(|m| CliError::Config(format!("config file {shown}: {m}")))
}

/// Parses and validates a scenario from TOML text; the error is a one-line message. A recorded
/// gait (`[trajectory] file`) is read relative to the working directory.
pub fn parse_scenario(text: &str) -> Result<Experiment, String> {
    parse_scenario_with_origins(text).map(|(s, _)| s)
}

/// [`parse_scenario`], also returning which keys the text set. A cross-field error names the
/// key the file set and the one it conflicts with (see [`describe_error`]).
pub fn parse_scenario_with_origins(text: &str) -> Result<(Experiment, KeyOrigins), String> {
    parse_scenario_with_origins_in(text, Path::new(""))
}

/// [`parse_scenario_with_origins`], reading a recorded gait relative to the folder `base`.
pub fn parse_scenario_with_origins_in(
    text: &str,
    base: &Path,
) -> Result<(Experiment, KeyOrigins), String> {
    // The hardware tables of `[robot]` (bus, joints, force sensors) are `run --config`'s;
    // checked here so that every command rejects a bad one, then left out of the scenario.
    let (text, hw) = exompc_can::config::split_hardware(text).map_err(|e| e.to_string())?;
    if let Some(hw) = hw {
        exompc_can::config::HardwareConfig::from_table(hw).map_err(|e| e.to_string())?;
    }
    let text = text.as_str();
    let table: toml::Table =
        toml::from_str(text).map_err(|e| describe_toml_error(text, &e, "TOML syntax error"))?;
    check_keys(&table, &schema(), "")?;
    check_magnitudes(&table, "")?;
    let mut scenario: Experiment =
        toml::from_str(text).map_err(|e| describe_toml_error(text, &e, "invalid scenario"))?;
    crate::gait::attach_recording(&mut scenario, base).map_err(|e| e.to_string())?;
    let origins = KeyOrigins::of_file(&table);
    exompc::scenario::validate(&scenario).map_err(|e| describe_error(&e, &origins))?;
    Ok((scenario, origins))
}

/// Parses a value written on the command line (or passed from Python) as TOML: `0.43`, `5`,
/// `true`, `[1.0, 2.0]`, `"coupled"`. A bare word that is not valid TOML counts as a string
/// (`coupled`).
pub fn parse_value(value: &str) -> toml::Value {
    match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(value.to_string())),
        Err(_) => toml::Value::String(value.trim().to_string()),
    }
}

/// The scenario `s` with one key, named by its dotted path (`robot.payload_position_m`), set to
/// `value`, validated. The key is checked against the schema exactly as a config file's keys
/// (unknown key → closest valid name; wrong type → what was expected), then the whole scenario
/// is validated, so the message names the field and its allowed range.
pub fn set_key(s: &Experiment, key: &str, value: toml::Value) -> Result<Experiment, String> {
    set_keys(s, &[(key.to_string(), value)], Path::new(""))
}

/// [`set_key`] for several keys at once, validated together (so that keys which depend on
/// each other, like `trajectory.kind = "recorded"` and `trajectory.file`, can change in one
/// go); a newly named gait file is read relative to the folder `base`.
pub fn set_keys(
    s: &Experiment,
    changes: &[(String, toml::Value)],
    base: &Path,
) -> Result<Experiment, String> {
    let mut tree = match toml::Value::try_from(s) {
        Ok(toml::Value::Table(t)) => t,
        _ => return Err("cannot serialise the scenario".into()),
    };
    for (key, value) in changes {
        let parts: Vec<&str> = key.split('.').map(str::trim).collect();
        if key.trim().is_empty() || parts.iter().any(|p| p.is_empty()) {
            return Err(format!(
                "invalid key `{key}` (expected a dotted path such as robot.payload_position_m)"
            ));
        }
        // The user's change as a one-key TOML tree, checked like a config file.
        let mut user = value.clone();
        for p in parts.iter().rev() {
            let mut t = toml::Table::new();
            t.insert((*p).to_string(), user);
            user = toml::Value::Table(t);
        }
        if let toml::Value::Table(t) = &user {
            check_keys(t, &schema(), "")?;
            check_magnitudes(t, "")?;
        }
        let (last, tables) = parts.split_last().expect("at least one part");
        let mut node = &mut tree;
        for p in tables {
            let entry = node
                .entry((*p).to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            node = match entry {
                toml::Value::Table(t) => t,
                _ => return Err(format!("`{p}` in `{key}` is not a table")),
            };
        }
        node.insert((*last).to_string(), value.clone());
    }
    let named: Vec<&str> = changes.iter().map(|(k, _)| k.trim()).collect();
    let mut scenario: Experiment =
        toml::Value::Table(tree)
            .try_into()
            .map_err(|e: toml::de::Error| {
                format!(
                    "invalid value for {}: {}",
                    named.join(", "),
                    e.message().trim()
                )
            })?;
    // The loaded recording is not part of the TOML: keep it, or load a newly named file
    // (relative to `base`).
    if scenario.trajectory.file == s.trajectory.file {
        scenario.trajectory.recording = s.trajectory.recording.clone();
    } else {
        crate::gait::attach_recording(&mut scenario, base).map_err(|e| e.to_string())?;
    }
    let origins = KeyOrigins {
        file: named.iter().map(|k| k.to_string()).collect(),
        flags: Vec::new(),
        unset: "current value",
    };
    exompc::scenario::validate(&scenario).map_err(|e| describe_error(&e, &origins))?;
    Ok(scenario)
}

/// The value of one key of `s` by its dotted path, as TOML (`None` for an unset optional key).
pub fn get_key(s: &Experiment, key: &str) -> Result<Option<toml::Value>, String> {
    let schema = toml::Value::Table(schema());
    let tree =
        toml::Value::try_from(s).map_err(|e| format!("cannot serialise the scenario: {e}"))?;
    let (mut node, mut known) = (Some(&tree), &schema);
    let mut prefix = String::new();
    for p in key.split('.') {
        let names: Vec<&str> = known
            .as_table()
            .map(|t| t.keys().map(String::as_str).collect())
            .unwrap_or_default();
        let Some(next) = known.get(p) else {
            let hint = closest(p, &names)
                .map(|c| format!("; did you mean `{c}`?"))
                .unwrap_or_default();
            let place = if prefix.is_empty() {
                "at the top level".to_string()
            } else {
                format!("in table [{prefix}]")
            };
            return Err(format!(
                "unknown key `{p}` {place}{hint} (valid keys: {})",
                names.join(", ")
            ));
        };
        known = next;
        node = node.and_then(|n| n.get(p));
        prefix = join(&prefix, p);
    }
    Ok(node.cloned())
}

/// A TOML tree holding every key a scenario file may contain (optional keys and one fault
/// event filled in), used to check user files key by key.
fn schema() -> toml::Table {
    let mut s = Experiment::default();
    s.controller.sqp.max_time_us = Some(1);
    s.trajectory.file = Some(PathBuf::from("gait.csv"));
    s.faults.events.push(FaultEvent {
        kind: FaultKind::Spike,
        channel: Channel::F1,
        start_s: 0.0,
        duration_s: 0.0,
        magnitude: 0.0,
    });
    s.multistage
        .scenarios
        .push(exompc::scenario::multistage::ScenarioSpec::every_key());
    match toml::Value::try_from(&s) {
        Ok(toml::Value::Table(t)) => t,
        _ => unreachable!("a Scenario always serialises to a TOML table"),
    }
}

fn kind_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a datetime",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// Checks that a dotted key or table path (`trajectory.hip_amplitude`, `robot.thigh`,
/// `faults.events[0].kind`) exists in the scenario schema; an unknown part gets the message of
/// a config file's unknown key (closest name, and the tables where the key exists).
pub fn check_key_path(key: &str) -> Result<(), String> {
    let root = schema_root();
    let mut table = &root;
    let mut prefix = String::new();
    let parts: Vec<&str> = key.split('.').collect();
    if key.is_empty() || parts.iter().any(|p| p.is_empty()) {
        return Err(format!(
            "invalid key `{key}` (expected a dotted path such as trajectory.hip_amplitude)"
        ));
    }
    for (i, part) in parts.iter().enumerate() {
        let name = part.split('[').next().unwrap_or(part);
        let Some(node) = table.get(name) else {
            return Err(unknown_key(name, table, &prefix));
        };
        prefix = join(&prefix, name);
        let node = match node {
            toml::Value::Array(a) => a.first().unwrap_or(node),
            other => other,
        };
        match node {
            toml::Value::Table(t) => table = t,
            _ if i + 1 < parts.len() => {
                return Err(format!(
                    "`{prefix}` is a value, not a table: it has no key `{}`",
                    parts[i + 1]
                ));
            }
            _ => {}
        }
    }
    Ok(())
}

/// The message for a key `key` missing from table `schema` at `prefix`.
fn unknown_key(key: &str, schema: &toml::Table, prefix: &str) -> String {
    let names: Vec<&str> = schema.keys().map(String::as_str).collect();
    let place = if prefix.is_empty() {
        "at the top level".to_string()
    } else if prefix.ends_with(']') {
        format!("in {prefix}")
    } else {
        format!("in table [{prefix}]")
    };
    let homes = tables_holding(&schema_root(), key, "");
    // A near miss here (a typo) first, then where the key exists elsewhere.
    let near = closest(key, &names).filter(|c| homes.is_empty() || levenshtein(key, c) <= 2);
    let mut hint = near
        .map(|c| format!("; did you mean `{c}`?"))
        .unwrap_or_default();
    if !homes.is_empty() {
        let list: Vec<String> = homes.iter().map(|t| format!("[{t}]")).collect();
        hint += &format!("; `{key}` belongs in {}", list.join(" or "));
    }
    format!(
        "unknown key `{key}` {place}{hint} (valid keys: {})",
        names.join(", ")
    )
}

/// Recursively checks that every key of `user` exists in `schema` with a compatible type.
fn check_keys(user: &toml::Table, schema: &toml::Table, prefix: &str) -> Result<(), String> {
    for (key, value) in user {
        let path = join(prefix, key);
        let Some(expected) = schema.get(key) else {
            return Err(exompc::config::removed_key(&path)
                .unwrap_or_else(|| unknown_key(key, schema, prefix)));
        };
        check_value(value, expected, &path)?;
    }
    Ok(())
}

/// The whole schema (see [`schema`]), built once.
fn schema_root() -> toml::Table {
    static ROOT: std::sync::OnceLock<toml::Table> = std::sync::OnceLock::new();
    ROOT.get_or_init(schema).clone()
}

/// Dotted paths of the tables of `t` (searched recursively) that have a key `key`.
fn tables_holding(t: &toml::Table, key: &str, prefix: &str) -> Vec<String> {
    let mut out = Vec::new();
    if !prefix.is_empty() && t.contains_key(key) {
        out.push(prefix.to_string());
    }
    for (k, v) in t {
        if let toml::Value::Table(sub) = v {
            out.extend(tables_holding(sub, key, &join(prefix, k)));
        }
    }
    out
}

fn check_value(value: &toml::Value, expected: &toml::Value, path: &str) -> Result<(), String> {
    use toml::Value as V;
    let mismatch = |what: &str| {
        format!(
            "invalid type for {path}: expected {what}, found {} `{value}`",
            kind_name(value)
        )
    };
    // A number or a word (`controller.k1 = "auto"`): serde and validation judge the value.
    let number_or_word = || {
        matches!(
            exompc::config::explain(path).map(|d| d.allowed),
            Some(exompc::config::Allowed::RealOrWord { .. })
        )
    };
    match (expected, value) {
        (V::Table(s), V::Table(u)) => check_keys(u, s, path),
        (V::Float(_) | V::String(_), V::Float(_) | V::Integer(_) | V::String(_))
            if number_or_word() =>
        {
            Ok(())
        }
        (V::Float(_), V::Float(_) | V::Integer(_)) => Ok(()),
        (V::Float(_), _) => Err(mismatch("a number")),
        (V::Integer(_), V::Integer(i)) if *i < 0 => Err(format!(
            "invalid value for {path}: {i} (allowed: a non-negative integer)"
        )),
        (V::Integer(_), V::Integer(_)) => Ok(()),
        (V::Integer(_), _) => Err(mismatch("an integer")),
        (V::Array(s), V::Array(u)) => match s.first() {
            Some(elem) => u
                .iter()
                .enumerate()
                .try_for_each(|(i, v)| check_value(v, elem, &format!("{path}[{i}]"))),
            None => Ok(()),
        },
        (a, b) if std::mem::discriminant(a) == std::mem::discriminant(b) => Ok(()),
        (a, _) => Err(mismatch(kind_name(a))),
    }
}

/// Largest magnitude of any number in a scenario file: far above every key's sensible range
/// (the largest stated bound is 1e6), so that a huge value (`kp = 1e308`) is rejected as bad
/// input naming its key instead of overflowing a run into a diverged plant.
pub const MAX_MAGNITUDE: f64 = 1e9;

/// Checks that every number of `user` (a config file's or a `--set` tree) is within
/// ±[`MAX_MAGNITUDE`], naming the key, the value and the allowed range.
fn check_magnitudes(user: &toml::Table, prefix: &str) -> Result<(), String> {
    fn check(v: &toml::Value, path: &str) -> Result<(), String> {
        let x = match v {
            toml::Value::Float(x) => *x,
            toml::Value::Integer(i) => *i as f64,
            toml::Value::Array(a) => {
                return a
                    .iter()
                    .enumerate()
                    .try_for_each(|(i, v)| check(v, &format!("{path}[{i}]")))
            }
            toml::Value::Table(t) => return check_magnitudes(t, path),
            _ => return Ok(()),
        };
        if x.is_finite() && x.abs() > MAX_MAGNITUDE {
            let own = exompc::config::explain(path)
                .map(|d| format!("{}, and ", d.allowed.describe()))
                .unwrap_or_default();
            return Err(format!(
                "invalid value for {path}: {} (allowed: {own}within ±{} like every number of a \
                 scenario)",
                crate::config_help::compact_number(x),
                crate::config_help::compact_number(MAX_MAGNITUDE)
            ));
        }
        Ok(())
    }
    for (key, value) in user {
        check(value, &join(prefix, key))?;
    }
    Ok(())
}

/// Levenshtein edit distance between two strings (by characters).
pub fn levenshtein(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// The candidate closest to `name` by Levenshtein distance (first one on ties).
pub fn closest<'a>(name: &str, candidates: &[&'a str]) -> Option<&'a str> {
    candidates
        .iter()
        .copied()
        .min_by_key(|c| levenshtein(name, c))
}

/// Turns a toml error into one line: `<what> at line L, column C (<dotted key>): <message>`.
fn describe_toml_error(text: &str, err: &toml::de::Error, what: &str) -> String {
    let msg = err.message().trim().replace('\n', " ");
    match err.span() {
        Some(span) => {
            let start = span.start.min(text.len());
            let before = &text[..start];
            let line = before.matches('\n').count() + 1;
            let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            let at = key_path_at(text, start)
                .map(|p| format!(" ({p})"))
                .unwrap_or_default();
            format!("{what} at line {line}, column {col}{at}: {msg}")
        }
        None => format!("{what}: {msg}"),
    }
}

/// Best-effort dotted path of the key on the line containing byte `offset` (the enclosing
/// `[table]` header plus the key before `=`), for error messages.
fn key_path_at(text: &str, offset: usize) -> Option<String> {
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next().unwrap_or("");
    let header = |l: &str| {
        let l = l.trim();
        l.starts_with('[')
            .then(|| l.trim_matches(|c| c == '[' || c == ']').trim().to_string())
    };
    if let Some(h) = header(line) {
        return Some(h);
    }
    let table = text[..line_start]
        .lines()
        .rev()
        .find_map(header)
        .unwrap_or_default();
    let key = line.split_once('=')?.0.trim().trim_matches('"');
    (!key.is_empty()).then(|| join(&table, key))
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// A unique temporary path next to `dest` (same folder, so that `rename` is atomic).
fn temp_path_for(dest: &Path) -> PathBuf {
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    dest.with_file_name(format!(".{name}.tmp.{}.{n}", std::process::id()))
}

/// Best-effort fsync of the folder holding `path`, so that a rename survives a crash.
fn sync_parent(path: &Path) {
    #[cfg(unix)]
    if let Some(dir) = path.parent() {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
    }
    #[cfg(not(unix))]
    let _ = path;
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder is written,
/// fsynced and renamed over `path`. Readers see either the old or the complete new file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CliError> {
    let mut w = AtomicWriter::create(path)?;
    w.write_all(bytes)
        .map_err(|e| CliError::io(format!("writing {}", path.display()), e))?;
    w.finish()
}

/// A buffered writer on a temporary file that becomes `dest` only on [`AtomicWriter::finish`]
/// (flush, fsync, rename). Dropped without `finish`, it removes the temporary file.
pub struct AtomicWriter {
    inner: Option<BufWriter<File>>,
    temp: PathBuf,
    dest: PathBuf,
}

impl AtomicWriter {
    /// Creates the temporary file next to `dest`.
    pub fn create(dest: &Path) -> Result<Self, CliError> {
        let temp = temp_path_for(dest);
        let file = File::create(&temp)
            .map_err(|e| CliError::io(format!("cannot create {}", temp.display()), e))?;
        Ok(Self {
            inner: Some(BufWriter::new(file)),
            temp,
            dest: dest.to_path_buf(),
        })
    }

    /// The final destination path.
    pub fn dest(&self) -> &Path {
        &self.dest
    }

    /// Flushes, fsyncs and renames the temporary file to the destination.
    pub fn finish(mut self) -> Result<(), CliError> {
        let what = || format!("writing {}", self.dest.display());
        let buf = self.inner.take().expect("AtomicWriter used after finish");
        let file = buf
            .into_inner()
            .map_err(|e| CliError::io(what(), e.into_error()))?;
        file.sync_all().map_err(|e| CliError::io(what(), e))?;
        drop(file);
        fs::rename(&self.temp, &self.dest).map_err(|e| CliError::io(what(), e))?;
        sync_parent(&self.dest);
        Ok(())
    }

    fn writer(&mut self) -> io::Result<&mut BufWriter<File>> {
        self.inner
            .as_mut()
            .ok_or_else(|| io::Error::other("AtomicWriter already finished"))
    }
}

impl Write for AtomicWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.writer()?.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.writer()?.flush()
    }
}

impl Drop for AtomicWriter {
    fn drop(&mut self) {
        if self.inner.take().is_some() {
            let _ = fs::remove_file(&self.temp);
        }
    }
}

/// Creates `dir` (and parents) if needed and checks that it is a writable folder.
///
/// Failures are [`CliError::Usage`] (exit 2): the folder comes from a command-line flag.
pub fn ensure_out_dir(dir: &Path) -> Result<(), CliError> {
    let shown = dir.display();
    if dir.exists() && !dir.is_dir() {
        return Err(CliError::Usage(format!(
            "output path {shown} exists and is not a folder"
        )));
    }
    fs::create_dir_all(dir)
        .map_err(|e| CliError::Usage(format!("cannot create output folder {shown}: {e}")))?;
    let probe = dir.join(format!(".exompc-write-test.{}", std::process::id()));
    File::create(&probe)
        .and_then(|_| fs::remove_file(&probe))
        .map_err(|e| CliError::Usage(format!("output folder {shown} is not writable: {e}")))
}

/// An output folder prepared by [`prepare_out_dir`]: the folders it created (parents
/// included) are removed again when it drops if they are still empty, so a refused or failed
/// start leaves no empty folder behind (a folder holding any file stays).
#[derive(Debug)]
pub struct OutDir {
    created: Vec<PathBuf>,
}

impl Drop for OutDir {
    fn drop(&mut self) {
        // Deepest first; `remove_dir` fails (and we stop) on a folder that is not empty.
        for d in self.created.iter().rev() {
            if fs::remove_dir(d).is_err() {
                break;
            }
        }
    }
}

/// [`ensure_out_dir`], remembering which folders it created so that they vanish again if
/// nothing was written into them (see [`OutDir`]). Keep the guard alive for the whole
/// command.
pub fn prepare_out_dir(dir: &Path) -> Result<OutDir, CliError> {
    let mut missing = Vec::new();
    let mut p = Some(dir);
    while let Some(d) = p {
        if d.as_os_str().is_empty() || d.exists() {
            break;
        }
        missing.push(d.to_path_buf());
        p = d.parent();
    }
    missing.reverse();
    let guard = OutDir { created: missing };
    ensure_out_dir(dir)?;
    Ok(guard)
}

// ---------------------------------------------------------------------------------------------
// JSON requests on stdin (`exompc model`, `exompc solve`)
// ---------------------------------------------------------------------------------------------

/// Reads all of stdin as text.
pub fn read_stdin() -> Result<String, CliError> {
    let mut text = String::new();
    std::io::stdin()
        .read_to_string(&mut text)
        .map_err(|e| CliError::Usage(format!("cannot read the JSON input on stdin: {e}")))?;
    Ok(text)
}

/// Parses `text` as one JSON object of type `T`; every error is a usage error that names the
/// offending field where there is one. `probe` checks a single field's value against its type
/// (it returns `None` for a field name it does not know), so that type errors, which serde
/// reports without the field name, can be attributed.
pub fn parse_input<T: for<'de> Deserialize<'de>>(
    text: &str,
    probe: impl Fn(&str, &Value) -> Option<Result<(), serde_json::Error>>,
) -> Result<T, CliError> {
    let value: Value = serde_json::from_str(text).map_err(|e| {
        let field = key_before(text, e.line(), e.column())
            .map(|k| format!(" (in field `{k}`)"))
            .unwrap_or_default();
        CliError::Usage(format!("malformed JSON input{field}: {e}"))
    })?;
    let Value::Object(obj) = &value else {
        return Err(CliError::Usage(
            "the JSON input must be one object, e.g. {\"q\": [...], ...}".into(),
        ));
    };
    serde_json::from_value::<T>(value.clone()).map_err(|e| {
        let msg = e.to_string();
        if msg.contains("field") {
            // serde names missing and unknown fields itself.
            return CliError::Usage(format!("invalid input: {msg}"));
        }
        for (k, v) in obj {
            if let Some(Err(fe)) = probe(k, v) {
                return CliError::Usage(format!("invalid input: field `{k}`: {fe}"));
            }
        }
        CliError::Usage(format!("invalid input: {msg}"))
    })
}

/// The last object key (`"name":`) before 1-based `line`/`column` of `text`, for locating a
/// syntax error (for example an out-of-range number) in a field.
fn key_before(text: &str, line: usize, column: usize) -> Option<String> {
    let mut offset = 0;
    for (i, l) in text.split_inclusive('\n').enumerate() {
        if i + 1 == line {
            offset += column.min(l.len());
            break;
        }
        offset += l.len();
    }
    let head = text.get(..offset.min(text.len()))?;
    let bytes = head.as_bytes();
    let mut i = head.len();
    while i > 0 {
        i -= 1;
        if bytes[i] != b':' {
            continue;
        }
        let before = head[..i].trim_end();
        let Some(inner) = before.strip_suffix('"') else {
            continue;
        };
        let start = inner.rfind('"')?;
        return Some(inner[start + 1..].to_string());
    }
    None
}

/// Probe helper: does `v` deserialise as `T`?
pub fn probe_as<T: for<'de> Deserialize<'de>>(v: &Value) -> Result<(), serde_json::Error> {
    T::deserialize(v).map(|_| ())
}

/// Checks that `v` has `n` finite entries, naming the field.
pub fn check_vec(name: &str, v: &[f64], n: usize) -> Result<(), CliError> {
    if v.len() != n {
        return Err(CliError::Usage(format!(
            "field `{name}` must have {n} entr{} (like `q`), found {}",
            if n == 1 { "y" } else { "ies" },
            v.len()
        )));
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(CliError::Usage(format!(
            "field `{name}[{i}]` must be a finite number, found {}",
            v[i]
        )));
    }
    Ok(())
}

/// Number of joints given by `q` (1 or 2), naming the field otherwise.
pub fn joint_count(q: &[f64]) -> Result<usize, CliError> {
    match q.len() {
        1 | 2 => Ok(q.len()),
        n => Err(CliError::Usage(format!(
            "field `q` must have 1 (knee only) or 2 (hip, knee) entries, found {n}"
        ))),
    }
}
