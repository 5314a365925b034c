//! `exompc soak`: a long MS-NMPC run (default 1 h simulated, 2 kg payload) with a fault
//! schedule (the config's `[faults] events`, or one fault of each kind every minute), checking
//! that the output stays within the limits; prints the counters and writes `soak.json`.
use crate::args::ConfigOpt;
use clap::Args;
use exompc::scenario::{run_soak, soak_scenario, RunError, SoakReport, EPISODE_AFTER_S};
use exompc::sim::{Recorder, StepRecord};
use exompc_cli::error::CliError;
use exompc_cli::interrupt::{self, stop_on_interrupt};
use exompc_cli::io;
use exompc_cli::trace::CsvTrace;
use exompc_cli::verdict::Verdict;
use std::path::PathBuf;

/// Longest soak (h): the summary keeps 8 bytes of step time per step (2.9 MB per hour).
const MAX_HOURS: f64 = 100.0;

#[derive(Debug, Args)]
pub(crate) struct SoakArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Simulated duration (hours), in (0, 100].
    #[arg(
        long,
        value_name = "H",
        default_value_t = 1.0,
        allow_hyphen_values = true
    )]
    hours: f64,
    /// True payload (kg).
    #[arg(
        long,
        value_name = "KG",
        default_value_t = 2.0,
        allow_hyphen_values = true
    )]
    payload: f64,
    /// Output folder for `soak.json` (and `soak_trace.csv`).
    #[arg(long, value_name = "DIR", default_value = "out/soak")]
    out: PathBuf,
    /// Also write every N-th step to `soak_trace.csv` (0: no trace), in [0, 1000000000].
    #[arg(long, value_name = "N", allow_negative_numbers = true, default_value_t = 0,
          value_parser = clap::value_parser!(i64).range(0..=1_000_000_000))]
    trace_every: i64,
    /// Replace the results of an earlier soak in the output folder (soak.json,
    /// soak_trace.csv; nothing else). Without it such a folder is refused.
    #[arg(long)]
    force: bool,
    /// Exit 3 when the verdict is `degraded` (monitor trips, solver fallbacks), not only 1
    /// when it is `failed`.
    #[arg(long)]
    strict: bool,
}

/// Forwards every `every`-th step to the trace.
struct Decimated {
    trace: CsvTrace,
    every: usize,
}

impl Recorder<2> for Decimated {
    fn record(&mut self, r: &StepRecord<'_, 2>) -> std::io::Result<()> {
        if r.k.is_multiple_of(self.every) {
            self.trace.record(r)?;
        }
        Ok(())
    }
}

pub(crate) fn run(a: SoakArgs) -> Result<(), CliError> {
    let base = a.config.load()?;
    if !(a.hours.is_finite() && a.hours > 0.0 && a.hours <= MAX_HOURS) {
        return Err(CliError::Usage(format!(
            "--hours {}: out of range (allowed: finite, in (0, {MAX_HOURS}] h)",
            crate::args::show_number(a.hours)
        )));
    }
    let mut check = base.clone();
    check.uncertainty.payload_kg = a.payload;
    check.validate().map_err(|e| {
        crate::args::flag_error(
            "--payload",
            a.payload,
            "uncertainty.payload_kg",
            &e,
            &exompc_cli::config_help::KeyOrigins::default(),
        )
    })?;
    soak_scenario(&base, a.hours * 3600.0, a.payload)
        .validate()
        .map_err(|e| CliError::Usage(format!("--hours: {e}")))?;
    let out = a.out;
    exompc_cli::earlier::refuse_or_clear(&out, exompc_cli::earlier::SOAK_FILES, a.force, "soak")?;
    let _out_dir = io::prepare_out_dir(&out)?;
    let mut trace = match a.trace_every as usize {
        0 => None,
        every => Some(Decimated {
            trace: CsvTrace::create_with(
                &out.join("soak_trace.csv"),
                2,
                &exompc_cli::run::multistage_keys(&base),
            )?,
            every,
        }),
    };
    let mut stop = stop_on_interrupt();
    let mut recs: Vec<&mut dyn Recorder<2>> = Vec::new();
    if let Some(t) = trace.as_mut() {
        recs.push(t);
    }
    // Last, so that the trace holds the step the summary ends on.
    recs.push(&mut stop);
    let seconds = a.hours * 3600.0;
    let mut stop_reference = stop_on_interrupt();
    let report = run_soak(
        &base,
        seconds,
        a.payload,
        &mut recs,
        &mut [&mut stop_reference],
    )
    .map_err(|e| match e {
        RunError::Config(c) => CliError::Config(c.to_string()),
        other => CliError::Runtime(other.to_string()),
    })?;
    let s = &report.stats;
    // Stopped by SIGINT/SIGTERM: the counters cover the simulated time run so far.
    let partial = interrupt::requested() && report.simulated_s < seconds;
    if partial {
        println!(
            "partial: interrupted by {} after {:.0} of {:.0} s simulated",
            interrupt::signal_name(),
            report.simulated_s,
            seconds
        );
    }
    println!(
        "soak {} | payload {:.2} kg | {:.0} s simulated, {} steps, {} fault events | wall {:.1} s",
        report.controller,
        report.payload_kg,
        report.simulated_s,
        s.steps,
        report.fault_events,
        report.wall_time_s
    );
    println!(
        "  NaN {}   limit violations {}   max |F| {:.2} N   RMS F {:.2} N",
        s.nan_count, s.limit_violations, s.max_abs_force_n, s.rms_force_n
    );
    println!(
        "  solver failures {}   bad measurements {}   monitor trips {} ({} steps)",
        s.solver_failures, s.bad_measurement_steps, report.monitor_trips, s.monitor_steps
    );
    println!(
        "  sensor faults {} (estimated steps {})   handovers {}   fallback stops {}   \
         escalations {}   revocations {}",
        report.sensor_faults,
        report.estimated_steps,
        report.handovers,
        report.fallback_stops,
        report.escalations,
        report.revocations
    );
    match report.latched_at_s {
        Some(t) => println!(
            "  LATCHED at {t:.1} s by {} after {} handovers: the fallback kept the torque for \
             {:.1} s ({:.1}% of the run)",
            report.latched_by.as_deref().unwrap_or("a monitor"),
            report.handovers,
            report.latched_for_s,
            100.0 * report.latched_for_s / report.simulated_s.max(1e-9)
        ),
        None => println!("  not latched"),
    }
    print_fault_classes(&report);
    drop(recs);
    if let Some(t) = trace {
        t.trace.finish()?;
        println!("  wrote {}", out.join("soak_trace.csv").display());
    }
    let mut json = serde_json::to_value(&report)
        .map_err(|e| CliError::Runtime(format!("serialising soak report: {e}")))?;
    if partial {
        if let Some(obj) = json.as_object_mut() {
            obj.insert("partial".into(), true.into());
            obj.insert("planned_s".into(), seconds.into());
        }
    }
    let json = serde_json::to_string_pretty(&json)
        .map_err(|e| CliError::Runtime(format!("serialising soak report: {e}")))?;
    let path = out.join("soak.json");
    io::write_atomic(&path, json.as_bytes())?;
    println!("  wrote {}", path.display());
    if partial {
        return Err(CliError::Interrupted(format!(
            "interrupted by {}: {:.0} of {seconds:.0} s simulated; partial results kept in {} \
             (soak.json marked \"partial\": true)",
            interrupt::signal_name(),
            report.simulated_s,
            out.display()
        )));
    }
    let verdict = Verdict::of_soak(&report);
    println!("{verdict}");
    verdict.outcome("soak", a.strict)
}

/// The per-fault verdicts: one line per class of injected fault.
fn print_fault_classes(r: &SoakReport) {
    if r.fault_classes.is_empty() {
        return;
    }
    println!(
        "  fault episodes within issue 28's goals: {} of {} (each against the same run without \
         faults, up to {EPISODE_AFTER_S:.0} s after it)",
        r.fault_episodes_passing, r.fault_episodes
    );
    println!(
        "    {:<24} {:<10} {:>6} {:>6} {:>9} {:>16} {:>16}",
        "fault", "group", "dur s", "goal N", "pass", "worst peak N @s", "worst RMS x @s"
    );
    for c in &r.fault_classes {
        println!(
            "    {:<24} {:<10} {:>6.2} {:>6.0} {:>9} {:>7.2} @{:<8.1} {:>7.2} @{:<8.1}",
            c.fault,
            c.group.name(),
            c.duration_s,
            c.peak_goal_n,
            format!("{}/{}", c.passing, c.episodes),
            c.worst_peak_force_n,
            c.worst_peak_at_s,
            c.worst_rms_ratio,
            c.worst_rms_at_s
        );
    }
}
