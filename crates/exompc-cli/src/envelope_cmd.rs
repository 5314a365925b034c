//! `exompc envelope`: scan the operating envelope (cells × payloads × controllers) in
//! parallel, classify every run, judge every cell (MS-NMPC against NMPC) and write
//! `envelope.json`, `envelope.md` and the heat map `envelope.{png,svg}`.

use crate::args::parse_payloads;
use crate::args::ConfigOpt;
use crate::plot::{colour_bar, heat_cell, heat_err as err, write_drawing, Drawing};
use clap::builder::TypedValueParser as _;
use clap::Args;
use exompc::sim::StabilityCriteria;
use exompc_cli::envelope::{class_counts, markdown, scan, Envelope, Grid};
use exompc_cli::error::CliError;
use exompc_cli::io;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::io::IsTerminal as _;
use std::path::{Path, PathBuf};

#[derive(Debug, Args)]
pub(crate) struct EnvelopeArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// A grid over scenario keys: `--set robot.payload_position_m=0.1,0.3,0.43` (repeat for a
    /// Cartesian product). Without it, the grid of `--grid` (default: the standard envelope).
    #[arg(long, value_name = "KEY=V1,V2,...")]
    set: Vec<String>,
    /// Grid file (format of envelopes/standard.toml); default the embedded standard envelope.
    #[arg(long, value_name = "FILE", conflicts_with = "set")]
    grid: Option<PathBuf>,
    /// Payloads (kg), `start:step:end` or a comma list (overrides the grid's).
    #[arg(long, value_name = "LIST", allow_hyphen_values = true)]
    payloads: Option<String>,
    /// Controllers, comma-separated (overrides the grid's; default nmpc,msnmpc).
    #[arg(long, value_delimiter = ',', value_parser = crate::args::controller_parser().map(|k| k.to_string()))]
    controllers: Vec<String>,
    /// Experiment of the `--set` cells: 1 (knee) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "out/envelope")]
    out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Replace the results of an earlier scan in the output folder (envelope.json,
    /// envelope.md, envelope.png, envelope.svg; nothing else). Without it such a folder is
    /// refused.
    #[arg(long)]
    force: bool,
    /// Exit with status 1 when a cell fails the acceptance.
    #[arg(long)]
    check: bool,
    /// Scan the bare controller: the safety monitors' thresholds out of reach (plausibility
    /// checks and torque limits stay). Default: the configured monitors, as deployed.
    #[arg(long)]
    no_monitors: bool,
}

pub(crate) fn run(a: EnvelopeArgs) -> Result<(), CliError> {
    let mut base = a.config.load()?;
    if a.no_monitors {
        base = exompc_cli::envelope::without_monitors(&base);
    }
    let mut grid = if !a.set.is_empty() {
        Grid::product(&a.set, a.dof, vec![0.0, 1.0, 2.0, 3.0], vec![])?
    } else if let Some(path) = &a.grid {
        let text = std::fs::read_to_string(path)
            .map_err(|e| CliError::Config(format!("cannot read {}: {e}", path.display())))?;
        let mut g = Grid::parse(&text, &path.display().to_string())?;
        g.base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        g
    } else {
        Grid::standard()
    };
    if let Some(p) = &a.payloads {
        grid.payloads_kg = parse_payloads(p)?;
    }
    if !a.controllers.is_empty() {
        grid.controllers = a.controllers.clone();
    } else if grid.controllers.is_empty() {
        grid.controllers = vec!["nmpc".into(), "msnmpc".into()];
    }
    grid.controllers.dedup();
    // Bad cells are bad input: reported before an output folder is looked at.
    for cell in &grid.cells {
        grid.cell_scenario(&base, cell)?;
    }
    exompc_cli::earlier::refuse_or_clear(
        &a.out,
        exompc_cli::earlier::ENVELOPE_FILES,
        a.force,
        "envelope scan",
    )?;
    let _out_dir = io::prepare_out_dir(&a.out)?;

    let total = grid.cells.len() * grid.payloads_kg.len() * grid.controllers.len();
    let target = if a.quiet || !std::io::stderr().is_terminal() {
        ProgressDrawTarget::hidden()
    } else {
        ProgressDrawTarget::stderr()
    };
    let pb = ProgressBar::with_draw_target(Some(total as u64), target);
    if let Ok(style) = ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs, eta {eta}",
    ) {
        pb.set_style(style);
    }
    let criteria = StabilityCriteria::default();
    let env = scan(&base, &grid, &criteria, &|| pb.inc(1))?;
    pb.finish_and_clear();

    let json = serde_json::to_string_pretty(&env)
        .map_err(|e| CliError::Runtime(format!("serialising the envelope: {e}")))?;
    io::write_atomic(&a.out.join("envelope.json"), json.as_bytes())?;
    let md = markdown(&env);
    io::write_atomic(&a.out.join("envelope.md"), md.as_bytes())?;
    let figures = heat_map(&env, &a.out)?;
    print!("{md}");
    for c in &grid.controllers {
        let counts: Vec<String> = class_counts(&env, c)
            .iter()
            .map(|(k, n)| format!("{n} {}", k.name()))
            .collect();
        println!("{c}: {}", counts.join(", "));
    }
    println!(
        "wrote {0}/envelope.json, {0}/envelope.md{1}",
        a.out.display(),
        figures
            .iter()
            .map(|f| format!(", {}", f.display()))
            .collect::<String>()
    );
    if env.partial {
        let done = env.runs.iter().filter(|r| r.stability.is_some()).count();
        return Err(CliError::Interrupted(format!(
            "interrupted by {}: {done} of {total} runs completed; partial results kept in {} \
             (envelope.json marked \"partial\": true, envelope.md, heat map)",
            exompc_cli::interrupt::signal_name(),
            a.out.display()
        )));
    }
    if a.check && !env.failing().is_empty() {
        return Err(CliError::Runtime(format!(
            "{} of {} cells fail the acceptance",
            env.failing().len(),
            env.verdicts.len()
        )));
    }
    Ok(())
}

/// The heat map's force scale saturates here (N): an RMS strap force.
const HEAT_MAX_N: f64 = 60.0;

/// The heat map: rows are cells, columns payloads; each cell coloured by the MS-NMPC's
/// largest RMS strap force, labelled with it; a black frame and `✗` where the run is not
/// stable, `▲` where it is worse than the NMPC (the acceptance's ratio).
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    env: &Envelope,
) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    let font = "sans-serif";
    root.fill(&WHITE).map_err(err)?;
    let (w, h) = root.dim_in_pixel();
    let ctrl = if env.grid.controllers.iter().any(|c| c == "msnmpc") {
        "msnmpc"
    } else {
        env.grid.controllers[0].as_str()
    };
    let title = format!(
        "{} RMS strap force (N, max of the straps) across the envelope",
        if ctrl == "msnmpc" { "MS-NMPC" } else { ctrl }
    );
    root.draw(&Text::new(title, (20, 12), (font, 20).into_font()))
        .map_err(err)?;
    let legend = "✗ not stable (limit cycle / growing)   ▲ worse than NMPC   grey: run failed";
    root.draw(&Text::new(legend, (20, 40), (font, 14).into_font()))
        .map_err(err)?;
    let (left, top, bottom) = (260i32, 70i32, 40i32);
    // Right of the cells: the colour bar and its scale.
    let bar_w = 110i32;
    let rows = env.grid.cells.len().max(1) as i32;
    let cols = env.grid.payloads_kg.len().max(1) as i32;
    let cw = ((w as i32 - left - bar_w - 10) / cols).max(10);
    let ch = ((h as i32 - top - bottom) / rows).max(10);
    colour_bar(
        &root,
        (w as i32 - bar_w + 20, top),
        rows * ch,
        font,
        HEAT_MAX_N,
    )?;
    for (j, p) in env.grid.payloads_kg.iter().enumerate() {
        let x = left + j as i32 * cw + cw / 2 - 20;
        root.draw(&Text::new(
            format!("{p} kg"),
            (x, top + rows * ch + 8),
            (font, 14).into_font(),
        ))
        .map_err(err)?;
    }
    for (i, cell) in env.grid.cells.iter().enumerate() {
        let y = top + i as i32 * ch;
        root.draw(&Text::new(
            cell.name.clone(),
            (10, y + ch / 2 - 7),
            (font, 12).into_font(),
        ))
        .map_err(err)?;
        for (j, &p) in env.grid.payloads_kg.iter().enumerate() {
            let x = left + j as i32 * cw;
            let run = env.run(i, p, ctrl);
            let v = run.map_or(f64::NAN, |r| {
                r.rms().iter().copied().fold(f64::NAN, f64::max)
            });
            let verdict = env
                .verdicts
                .iter()
                .find(|d| d.cell == i && d.payload_kg == p)
                .and_then(|d| d.verdict.clone());
            let unstable = verdict.as_ref().map_or_else(
                || {
                    run.and_then(|r| r.stability.as_ref()).is_none_or(|s| {
                        matches!(
                            s.class,
                            exompc::sim::RunClass::LimitCycle | exompc::sim::RunClass::Growing
                        )
                    })
                },
                |d| !d.stable,
            );
            let worse = verdict.as_ref().is_some_and(|d| !d.no_worse_than_nmpc);
            let mut label = if v.is_finite() {
                format!("{v:.1}")
            } else {
                "failed".into()
            };
            if unstable {
                label += " ✗";
            }
            if worse {
                label += " ▲";
            }
            heat_cell(
                &root,
                (x, y, cw, ch),
                v,
                HEAT_MAX_N,
                if unstable { 3 } else { 0 },
                label,
                cw / 2 - 30,
                14,
            )?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// The heat map of an envelope scan (drawn by [`draw`]).
struct EnvelopeMap<'a>(&'a Envelope);

impl Drawing for EnvelopeMap<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), CliError>
    where
        DB::ErrorType: 'static,
    {
        draw(root, self.0)
    }
}

/// Writes `dir/envelope.svg` and `dir/envelope.png`.
fn heat_map(env: &Envelope, dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    let size = (900u32, (110 + 34 * env.grid.cells.len()).max(300) as u32);
    write_drawing(&EnvelopeMap(env), dir, "envelope", size)
}
