//! Argument types and flag handling shared by the subcommands (`--config`, `--controller`,
//! `--formulation`, `--payloads`, the scenario overrides). Command modules import this module
//! and the `exompc_cli` library, never each other.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::Args;
use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::scenario::{controller_info, controllers};
use exompc_cli::config_help::{describe_error, KeyOrigins};
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::layout::tidy;
use std::path::PathBuf;

/// `--config FILE`, shared by the subcommands that run a scenario.
#[derive(Debug, Args)]
pub(crate) struct ConfigOpt {
    /// Scenario TOML file applied on top of the default scenario (see `exompc config`).
    #[arg(long, value_name = "FILE")]
    pub(crate) config: Option<PathBuf>,
    /// Replay a recorded gait: CSV of time and joint angles (t_s,hip_rad,knee_rad or _deg
    /// columns) as the human's desired motion; sets [trajectory] kind = "recorded", file = FILE.
    #[arg(long, value_name = "FILE.csv")]
    pub(crate) gait: Option<PathBuf>,
}

impl ConfigOpt {
    /// Loads and validates the scenario named by `--config` (the default when absent), with
    /// the recorded gait of `--gait`.
    pub(crate) fn load(&self) -> Result<Experiment, CliError> {
        self.load_with_origins().map(|(s, _)| s)
    }

    /// [`ConfigOpt::load`], also returning which keys the file set.
    pub(crate) fn load_with_origins(&self) -> Result<(Experiment, KeyOrigins), CliError> {
        let (mut s, origins) = io::load_scenario_with_origins(self.config.as_deref())?;
        if let Some(g) = &self.gait {
            exompc_cli::gait::use_gait(&mut s, g)?;
        }
        Ok((s, origins))
    }
}

/// Parser of `--controller` / `--controllers` values: the names of the library's controller
/// registry ([`controllers`]), each with its description in `--help`.
pub(crate) fn controller_parser() -> impl TypedValueParser<Value = ControllerKind> {
    PossibleValuesParser::new(
        controllers()
            .into_iter()
            .map(|c| PossibleValue::new(c.name()).help(c.description)),
    )
    .try_map(|name| ControllerKind::new(&name).map_err(|e| e.to_string()))
}

/// Whether controller `c` blends the multi-stage scenarios (takes `--formulation`).
pub(crate) fn is_multistage(c: ControllerKind) -> bool {
    controller_info(c).is_ok_and(|i| i.multistage)
}

/// The registered multi-stage controllers' names (`msnmpc`), for messages.
pub(crate) fn multistage_names() -> String {
    controllers()
        .iter()
        .filter(|c| c.multistage)
        .map(|c| c.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Formulation choice on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum FormulationArg {
    Decoupled,
    Coupled,
}

impl From<FormulationArg> for Formulation {
    fn from(f: FormulationArg) -> Self {
        match f {
            FormulationArg::Decoupled => Formulation::Decoupled,
            FormulationArg::Coupled => Formulation::Coupled,
        }
    }
}

/// Command-line spelling of a formulation.
pub(crate) fn formulation_name(f: FormulationArg) -> &'static str {
    match f {
        FormulationArg::Decoupled => "decoupled",
        FormulationArg::Coupled => "coupled",
    }
}

/// Apply the command-line overrides to the scenario and validate the result; a bad flag value
/// is reported naming the flag.
pub(crate) fn apply_overrides(
    s: &mut Experiment,
    dof: u8,
    controller: Option<ControllerKind>,
    formulation: Option<FormulationArg>,
    payload: Option<f64>,
    duration: Option<f64>,
) -> Result<(), CliError> {
    let origins = KeyOrigins {
        unset: "default or --config",
        ..KeyOrigins::default()
    };
    apply_overrides_with(s, &origins, dof, controller, formulation, payload, duration)
}

/// [`apply_overrides`] knowing which keys the config file set (`origins`), so that a flag
/// value conflicting with another key names both and says which one the user set where.
pub(crate) fn apply_overrides_with(
    s: &mut Experiment,
    origins: &KeyOrigins,
    dof: u8,
    controller: Option<ControllerKind>,
    formulation: Option<FormulationArg>,
    payload: Option<f64>,
    duration: Option<f64>,
) -> Result<(), CliError> {
    let mut origins = origins.clone();
    if let Some(k) = controller {
        s.controller.kind = k;
    }
    if let (Some(f), Some(k)) = (formulation, controller) {
        if !is_multistage(k) {
            return Err(CliError::Usage(format!(
                "--formulation {} applies to --controller {} only, not --controller {k}",
                formulation_name(f),
                multistage_names()
            )));
        }
    }
    if let Some(f) = formulation {
        s.multistage.formulation = f.into();
    }
    if let Some(p) = payload {
        s.uncertainty.payload_kg = p;
        origins.set_by_flag("uncertainty.payload_kg", "--payload");
        s.validate()
            .map_err(|e| flag_error("--payload", p, "uncertainty.payload_kg", &e, &origins))?;
    }
    if let Some(d) = duration {
        let key = if dof == 1 {
            s.timing.duration_1dof_s = d;
            "timing.duration_1dof_s"
        } else {
            s.timing.duration_2dof_s = d;
            "timing.duration_2dof_s"
        };
        origins.set_by_flag(key, "--duration");
        s.validate()
            .map_err(|e| flag_error("--duration", d, key, &e, &origins))?;
    }
    Ok(())
}

/// A number as a user would write it: `1e308` rather than 309 digits.
pub(crate) fn show_number(v: f64) -> String {
    exompc_cli::config_help::compact_number(v)
}

/// The error for flag `flag` given `value`, which sets scenario key `key`, when validation
/// rejected the scenario with `e`: it leads with the flag and the value typed, then the
/// allowed range (`--duration 1e308: out of range (allowed: finite, in [0.01, 1000000] s; it
/// sets timing.duration_2dof_s)`), or the rule it breaks with another key.
pub(crate) fn flag_error(
    flag: &str,
    value: f64,
    key: &str,
    e: &exompc::config::ConfigError,
    origins: &KeyOrigins,
) -> CliError {
    let typed = show_number(value);
    if e.field == key && e.depends_on.is_none() {
        let unit = exompc::config::explain(key)
            .map(|d| d.unit)
            .filter(|u| !u.is_empty() && *u != "-")
            .map(|u| format!(" {u}"))
            .unwrap_or_default();
        return CliError::Usage(format!(
            "{flag} {typed}: out of range (allowed: {}{unit}; it sets {key})",
            e.allowed
        ));
    }
    CliError::Usage(format!("{flag} {typed}: {}", describe_error(e, origins)))
}

/// Largest number of payloads a sweep accepts.
const MAX_PAYLOADS: usize = 1000;

fn usage(msg: impl std::fmt::Display) -> CliError {
    CliError::Usage(format!("--payloads: {msg}"))
}

/// Largest payload (kg) `--payloads` accepts in a list or range (each is then validated
/// against `uncertainty.payload_kg`'s own range).
const MAX_PAYLOAD_KG: f64 = 1e3;

fn parse_number(s: &str) -> Result<f64, CliError> {
    let t = s.trim();
    let v: f64 = t
        .parse()
        .map_err(|_| usage(format!("`{t}` is not a number")))?;
    if !v.is_finite() {
        return Err(usage(format!("`{t}` is not a finite number")));
    }
    if v.abs() > MAX_PAYLOAD_KG {
        return Err(usage(format!(
            "`{t}` is out of range (allowed: within ±{MAX_PAYLOAD_KG} kg)"
        )));
    }
    Ok(v)
}

/// Parses `--payloads`: `start:step:end` (inclusive of `end` within 1e-9) or a comma list.
pub(crate) fn parse_payloads(spec: &str) -> Result<Vec<f64>, CliError> {
    let spec = spec.trim();
    if spec.is_empty() {
        return Err(usage(
            "empty list (expected start:step:end or a comma list)",
        ));
    }
    let values = if spec.contains(':') {
        let parts: Vec<&str> = spec.split(':').collect();
        let [a, step, b] = parts[..] else {
            return Err(usage(format!(
                "`{spec}`: a range has three parts, start:step:end"
            )));
        };
        let (a, step, b) = (parse_number(a)?, parse_number(step)?, parse_number(b)?);
        if step <= 0.0 {
            return Err(usage(format!("step {step} must be > 0")));
        }
        if b < a {
            return Err(usage(format!("end {b} is below start {a}")));
        }
        let n = ((b - a) / step + 1e-9).floor();
        if n + 1.0 > MAX_PAYLOADS as f64 {
            return Err(usage(format!(
                "more than {MAX_PAYLOADS} payloads in `{spec}`"
            )));
        }
        (0..=n as usize)
            .map(|i| tidy(a + i as f64 * step))
            .collect()
    } else {
        let v: Vec<f64> = spec
            .split(',')
            .map(|p| parse_number(p).map(tidy))
            .collect::<Result<_, _>>()?;
        if v.len() > MAX_PAYLOADS {
            return Err(usage(format!("more than {MAX_PAYLOADS} payloads")));
        }
        v
    };
    for (i, p) in values.iter().enumerate() {
        if values[..i].contains(p) {
            return Err(usage(format!("payload {p} kg is listed twice")));
        }
    }
    Ok(values)
}
