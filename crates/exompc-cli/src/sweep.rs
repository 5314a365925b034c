//! `exompc sweep`: every payload × controller run of a scenario, in parallel across cores,
//! each streamed into `DIR/<controller>_<payload>kg/{trace.csv,summary.json}`; then the paper's
//! Table 2 as `DIR/table2.md` and all summaries as `DIR/sweep.json`.

use crate::args::ConfigOpt;
use crate::args::{
    apply_overrides_with, formulation_name, is_multistage, multistage_names, parse_payloads,
    FormulationArg,
};
use clap::Args;
use exompc::config::{ControllerKind, Experiment};
use exompc::sim::Summary;
use exompc_cli::error::CliError;
use exompc_cli::interrupt;
use exompc_cli::io;
use exompc_cli::layout::{run_dir_name, SweepFile};
use exompc_cli::run::run_to_dir;
use exompc_cli::verdict::Verdict;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;
use std::io::IsTerminal as _;
use std::path::{Path, PathBuf};

#[derive(Debug, Args)]
pub(crate) struct SweepArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Payloads (kg): a range `start:step:end` (inclusive) or a comma list `0,1,2`.
    #[arg(
        long,
        value_name = "LIST",
        default_value = "0:0.25:2",
        allow_hyphen_values = true
    )]
    payloads: String,
    /// Controllers to compare, comma-separated.
    #[arg(long, value_parser = crate::args::controller_parser(), value_delimiter = ',', default_value = "nmpc,msnmpc")]
    controllers: Vec<ControllerKind>,
    /// Experiment: 1 (knee only, hip locked) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Override `multistage.formulation` (msnmpc only).
    #[arg(long, value_enum)]
    formulation: Option<FormulationArg>,
    /// Override the run length (s) of the chosen experiment.
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    duration: Option<f64>,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "out/sweep")]
    out: PathBuf,
    /// Replace the results of an earlier sweep in the output folder (without it, such a
    /// folder is refused so that old and new results never mix).
    #[arg(long)]
    force: bool,
    /// Print `sweep.json` on stdout instead of the Markdown table.
    #[arg(long)]
    json: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Also draw the figures into the output folder.
    #[arg(long)]
    plot: bool,
    /// Exit 3 when the verdict is `degraded` (some run had monitor trips, held torques or
    /// solver fallbacks), not only 1 when a run `failed`.
    #[arg(long)]
    strict: bool,
}

fn progress_bar(len: usize, quiet: bool) -> ProgressBar {
    let target = if quiet || !std::io::stderr().is_terminal() {
        ProgressDrawTarget::hidden()
    } else {
        ProgressDrawTarget::stderr()
    };
    let pb = ProgressBar::with_draw_target(Some(len as u64), target);
    if let Ok(style) = ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs {msg}",
    ) {
        pb.set_style(style);
    }
    pb
}

/// The runs of a grid: the summaries of the completed runs, payload-major, and the message of
/// an interruption (SIGINT/SIGTERM) if the grid did not complete.
struct GridResult {
    rows: Vec<Summary>,
    interrupted: Option<String>,
}

/// Runs the whole grid into `out`, returning the summaries payload-major.
fn run_grid(
    base: &Experiment,
    dof: u8,
    payloads: &[f64],
    controllers: &[ControllerKind],
    out: &Path,
    quiet: bool,
) -> Result<GridResult, CliError> {
    let mut jobs = Vec::with_capacity(payloads.len() * controllers.len());
    for &p in payloads {
        for &c in controllers {
            let mut s = base.clone();
            s.controller.kind = c;
            s.uncertainty.payload_kg = p;
            s.validate()
                .map_err(|e| CliError::Usage(format!("--payloads: {p} kg: {e}")))?;
            let dir = out.join(run_dir_name(c.as_str(), p));
            jobs.push((s, dir));
        }
    }
    let pb = progress_bar(jobs.len(), quiet);
    let results: Vec<Result<Summary, CliError>> = jobs
        .par_iter()
        .map(|(s, dir)| {
            let r = run_job(s, dof, dir);
            pb.inc(1);
            r
        })
        .collect();
    pb.finish_and_clear();
    if interrupt::requested() {
        let mut done = Vec::new();
        let mut rows = Vec::new();
        for ((_, d), r) in jobs.iter().zip(results) {
            if let Ok(summary) = r {
                done.push(
                    d.file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .into_owned(),
                );
                rows.push(summary);
            }
        }
        let message = format!(
            "interrupted by {}: {} of {} runs completed in {} ({}); table2.md and sweep.json \
             hold those runs, marked partial",
            interrupt::signal_name(),
            done.len(),
            jobs.len(),
            out.display(),
            if done.is_empty() {
                "none".to_string()
            } else {
                done.join(", ")
            }
        );
        return Ok(GridResult {
            rows,
            interrupted: Some(message),
        });
    }
    Ok(GridResult {
        rows: results.into_iter().collect::<Result<_, _>>()?,
        interrupted: None,
    })
}

/// One run of the grid, written whole or not at all: into a hidden temporary folder beside
/// `dir`, renamed to `dir` when complete (removed on failure or interruption).
fn run_job(s: &Experiment, dof: u8, dir: &Path) -> Result<Summary, CliError> {
    interrupt::check("not started")?;
    let name = dir.file_name().unwrap_or_default().to_string_lossy();
    let tmp = dir.with_file_name(format!(".{name}.tmp.{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    io::ensure_out_dir(&tmp)?;
    let r = run_to_dir(s, dof, Some(&tmp)).and_then(|summary| {
        std::fs::rename(&tmp, dir)
            .map_err(|e| CliError::io(format!("moving {} into place", dir.display()), e))?;
        Ok(summary)
    });
    if r.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    r.map_err(|e| match e {
        CliError::Runtime(m) => CliError::Runtime(format!("{}: {m}", dir.display())),
        other => other,
    })
}

/// Files a sweep (and `plot`) writes at the top of its folder.
fn is_sweep_output(name: &str) -> bool {
    let figure = [".png", ".svg"].iter().any(|e| name.ends_with(e))
        && ["payload_sweep", "states_", "compare_", "step_time_"]
            .iter()
            .any(|p| name.starts_with(p));
    figure || name == "sweep.json" || name == "table2.md"
}

/// A run folder `<controller>_<payload>kg` holding a run's results.
fn is_run_dir(path: &Path) -> bool {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    ["pd_", "nmpc_", "msnmpc_"]
        .iter()
        .any(|p| name.starts_with(p))
        && name.ends_with("kg")
        && (path.join("summary.json").is_file() || path.join("trace.csv").is_file())
}

/// Refuses an output folder holding earlier sweep results unless `force`; with `force`,
/// removes those results (only what a sweep writes) so old and new never mix.
fn clear_earlier_results(out: &Path, force: bool) -> Result<(), CliError> {
    let Ok(entries) = std::fs::read_dir(out) else {
        return Ok(());
    };
    let earlier: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().unwrap_or_default().to_string_lossy();
            (p.is_file() && is_sweep_output(&name)) || (p.is_dir() && is_run_dir(p))
        })
        .collect();
    if earlier.is_empty() {
        return Ok(());
    }
    if !force {
        return Err(CliError::Usage(format!(
            "{} already holds results of an earlier sweep ({} files and run folders, e.g. {}): \
             choose another --out, or pass --force to replace them",
            out.display(),
            earlier.len(),
            earlier[0].file_name().unwrap_or_default().to_string_lossy()
        )));
    }
    for p in earlier {
        let r = if p.is_dir() {
            std::fs::remove_dir_all(&p)
        } else {
            std::fs::remove_file(&p)
        };
        r.map_err(|e| CliError::io(format!("removing earlier result {}", p.display()), e))?;
    }
    Ok(())
}

fn pct(v: Option<f64>, digits: usize) -> String {
    v.filter(|x| x.is_finite())
        .map_or_else(|| "–".to_string(), |x| format!("{x:.digits$}"))
}

/// The Markdown rendering of the paper's Table 2 for `rows` (any subset of controllers).
pub(crate) fn table2(rows: &[Summary]) -> String {
    let mut payloads: Vec<f64> = Vec::new();
    for r in rows {
        if !payloads.contains(&r.payload_kg) {
            payloads.push(r.payload_kg);
        }
    }
    let label = |c: &str| exompc_cli::layout::controller_label(c);
    let ctrls = exompc_cli::layout::controller_order(rows);
    let find = |p: f64, c: &str| rows.iter().find(|r| r.payload_kg == p && r.controller == c);
    let scenarios = rows
        .iter()
        .filter_map(|r| r.mean_probability.as_ref().map(Vec::len))
        .max()
        .unwrap_or(0);

    let mut head = vec!["payload (kg)".to_string()];
    for c in &ctrls {
        head.push(format!("{} RMS F thigh (N)", label(c)));
        head.push(format!("{} RMS F shank (N)", label(c)));
    }
    for c in &ctrls {
        head.push(format!("{} δmax hip (deg)", label(c)));
        head.push(format!("{} δmax knee (deg)", label(c)));
    }
    for i in 1..=scenarios {
        head.push(format!("μ̄{i} (%)"));
    }
    for c in &ctrls {
        head.push(format!("{} step p50/p99 (µs)", label(c)));
    }
    let mut out = format!("| {} |\n", head.join(" | "));
    out += &format!("|{}\n", "---:|".repeat(head.len()));
    for &p in &payloads {
        let mut cells = vec![format!("{p:.2}")];
        for c in &ctrls {
            let r = find(p, c);
            cells.push(pct(r.and_then(|r| r.rms_force_n.thigh), 2));
            cells.push(pct(r.and_then(|r| r.rms_force_n.shank), 2));
        }
        for c in &ctrls {
            let r = find(p, c);
            cells.push(pct(r.and_then(|r| r.delta_max_deg.hip), 2));
            cells.push(pct(r.and_then(|r| r.delta_max_deg.knee), 2));
        }
        let mu = ctrls
            .iter()
            .find_map(|c| find(p, c).and_then(|r| r.mean_probability.clone()));
        for i in 0..scenarios {
            cells.push(pct(
                mu.as_ref().and_then(|m| m.get(i)).map(|v| 100.0 * v),
                2,
            ));
        }
        for c in &ctrls {
            cells.push(match find(p, c) {
                Some(r) => format!("{:.0} / {:.0}", r.step_time_us.p50, r.step_time_us.p99),
                None => "–".to_string(),
            });
        }
        out += &format!("| {} |\n", cells.join(" | "));
    }
    out
}

pub(crate) fn run(a: SweepArgs) -> Result<(), CliError> {
    let (mut s, origins) = a.config.load_with_origins()?;
    let payloads = parse_payloads(&a.payloads)?;
    let mut controllers: Vec<ControllerKind> = Vec::new();
    for c in a.controllers {
        if controllers.contains(&c) {
            return Err(CliError::Usage(format!(
                "--controllers: {c} is listed twice"
            )));
        }
        controllers.push(c);
    }
    if controllers.is_empty() {
        return Err(CliError::Usage("--controllers: empty list".into()));
    }
    if let Some(f) = a.formulation {
        if !controllers.iter().any(|c| is_multistage(*c)) {
            return Err(CliError::Usage(format!(
                "--formulation {} applies to {}, which --controllers does not list",
                formulation_name(f),
                multistage_names()
            )));
        }
    }
    apply_overrides_with(
        &mut s,
        &origins,
        a.dof,
        None,
        a.formulation,
        None,
        a.duration,
    )?;
    clear_earlier_results(&a.out, a.force)?;
    let _out_dir = io::prepare_out_dir(&a.out)?;

    let grid = run_grid(&s, a.dof, &payloads, &controllers, &a.out, a.quiet)?;
    let rows = grid.rows;
    let total = payloads.len() * controllers.len();
    let mut table = table2(&rows);
    if grid.interrupted.is_some() {
        table += &format!(
            "\nPartial: the sweep was interrupted; {} of {total} runs completed.\n",
            rows.len()
        );
    }
    io::write_atomic(&a.out.join("table2.md"), table.as_bytes())?;
    let file = SweepFile {
        rows,
        partial: grid.interrupted.is_some(),
    };
    let json = serde_json::to_string_pretty(&file)
        .map_err(|e| CliError::Runtime(format!("serialising sweep: {e}")))?;
    io::write_atomic(&a.out.join("sweep.json"), json.as_bytes())?;
    if let Some(message) = grid.interrupted {
        return Err(CliError::Interrupted(message));
    }
    if a.plot {
        crate::plot::draw_dir(&a.out)?;
    }
    if a.json {
        println!("{json}");
    } else {
        print!("{table}");
        println!(
            "wrote {0}/table2.md, {0}/sweep.json and {1} run folders",
            a.out.display(),
            file.rows.len()
        );
    }
    let verdict = Verdict::of_sweep(&file.rows);
    if !a.json {
        println!("{verdict}");
    }
    verdict.outcome("sweep", a.strict)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payload_ranges_and_lists() {
        assert_eq!(
            parse_payloads("0:0.25:2").unwrap(),
            vec![0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0]
        );
        assert_eq!(
            parse_payloads("0:0.1:0.3").unwrap(),
            vec![0.0, 0.1, 0.2, 0.3]
        );
        assert_eq!(parse_payloads("0, 2").unwrap(), vec![0.0, 2.0]);
        assert_eq!(parse_payloads("1").unwrap(), vec![1.0]);
        for bad in ["", "a", "0:0:1", "1:0.5:0", "0:1", "0,0", "nan", "0:1:1:2"] {
            let e = parse_payloads(bad).unwrap_err();
            assert!(e.to_string().starts_with("--payloads"), "{bad}: {e}");
            assert_eq!(e.exit_code(), 2);
        }
        assert_eq!(run_dir_name("nmpc", 0.25), "nmpc_0.25kg");
        assert_eq!(run_dir_name("msnmpc", 2.0), "msnmpc_2kg");
    }
}
