//! `exompc config --explain KEY`: one key's or table's unit, meaning, default, allowed range
//! and source, from the library's key table (`exompc::config::KEYS`). It reads the default
//! scenario through [`crate::io`] (key paths, values), which itself uses [`crate::config_help`]
//! for error wording; keeping this text here avoids an import circle between those two.

/// The text of `exompc config --explain KEY`: unit, meaning, default, allowed range and
/// source of a key, or of a table and each of its keys. `Err` for an unknown key, with the
/// whole-schema suggestion of a config file's unknown key.
pub fn explain_text(key: &str) -> Result<String, String> {
    use exompc::config::{Experiment, KEYS};
    let key = key.trim();
    crate::io::check_key_path(key)?;
    let doc = exompc::config::explain(key)
        .ok_or_else(|| format!("`{key}` is a key of the scenario but has no explanation"))?;
    let defaults = Experiment::default();
    let default_of = |path: &str| -> String {
        if path.starts_with("faults.events.") {
            // Per event: `magnitude` is optional, the others are required in each table.
            return if path.ends_with(".magnitude") {
                "0".into()
            } else {
                "none (required in each event)".into()
            };
        }
        if let Some(key) = path.strip_prefix("multistage.scenarios.") {
            // Per scenario: `name` is required, `payload_kg` defaults to 0, an override key to
            // the base table's value.
            return match key {
                "name" => "none (required in each scenario)".into(),
                "payload_kg" => "0".into(),
                _ => match crate::io::get_key(&defaults, key) {
                    Ok(Some(v)) => format!("the base {key} ({v})"),
                    _ => "the base table's value".into(),
                },
            };
        }
        match crate::io::get_key(&defaults, path) {
            Ok(Some(v)) => v.to_string(),
            Ok(None) => "absent".into(),
            Err(_) => "-".into(),
        }
    };
    let mut s = String::new();
    if doc.is_table() {
        let header = if matches!(doc.allowed, exompc::config::Allowed::Tables) {
            format!("[[{}]]", doc.path)
        } else {
            format!("[{}]", doc.path)
        };
        s += &format!(
            "{header}\n  meaning  {}\n  source   {}\n  keys\n",
            doc.meaning, doc.source
        );
        let prefix = format!("{}.", doc.path);
        let children: Vec<_> = KEYS
            .iter()
            .filter(|k| {
                k.path
                    .strip_prefix(&prefix)
                    .is_some_and(|rest| !rest.contains('.'))
            })
            .collect();
        let width = children
            .iter()
            .map(|k| k.path.len() - prefix.len())
            .max()
            .unwrap_or(0);
        for c in children {
            let name = &c.path[prefix.len()..];
            if c.is_table() {
                s += &format!("    {name:<width$}  table: {}\n", c.meaning);
            } else {
                let unit = if c.unit.is_empty() {
                    String::new()
                } else {
                    format!(" [{}]", c.unit)
                };
                s += &format!(
                    "    {name:<width$}  = {}{unit}  {}\n",
                    default_of(c.path),
                    c.meaning
                );
            }
        }
        s += &format!("  (exompc config --explain {}.KEY for one key)\n", doc.path);
        return Ok(s);
    }
    let unit = if doc.unit.is_empty() { "-" } else { doc.unit };
    let mut allowed = doc.allowed.describe();
    if doc.allowed == exompc::config::Allowed::Controller {
        let names: Vec<String> = exompc::scenario::controllers()
            .iter()
            .map(|c| format!("\"{}\" ({})", c.kind, c.description))
            .collect();
        allowed += &format!(": {}", names.join(", "));
    }
    let deps = doc.allowed.depends_on();
    if !deps.is_empty() {
        let vals: Vec<String> = deps
            .iter()
            .map(|d| format!("{d} = {}", default_of(d)))
            .collect();
        allowed += &format!(" (by default {})", vals.join(", "));
    }
    let table = match doc.path.rsplit_once('.').map_or("", |(t, _)| t) {
        "faults.events" => "[[faults.events]]".to_string(),
        t => format!("[{t}]"),
    };
    s += &format!(
        "{}  (in {table})\n  meaning  {}\n  unit     {unit}\n  default  {}\n  allowed  {allowed}\n  source   {}\n",
        doc.path,
        doc.meaning,
        default_of(doc.path),
        doc.source
    );
    Ok(s)
}
