//! `exompc plot DIR`: figures (PNG and SVG) of the traces in a `simulate` or `sweep` folder.
//!
//! A `simulate` folder (`trace.csv`) gives the single-run figures `states` (angles human vs
//! robot, velocities, torques: paper Figs. 3 and 7) and `interaction` (tracking errors, strap
//! forces, scenario probabilities, compute time). A `sweep` folder (`sweep.json`) gives the
//! comparison figures at the largest payload (`states_<ctrl>_<p>kg`, `compare_<p>kg`,
//! `step_time_<p>kg`: Figs. 3-5 / 7-8), at no load (`compare_0kg`: Fig. 6) and the
//! payload-sweep figure `payload_sweep` (RMS strap forces and mean probabilities vs payload).

use crate::sweep::{run_dir_name, SweepFile};
use clap::Args;
use exompc::sim::Summary;
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::trace::{joint_names, read_trace, strap_names, TraceTable};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

#[derive(Debug, Args)]
pub(crate) struct PlotArgs {
    /// Folder written by `simulate` (trace.csv) or `sweep` (sweep.json).
    #[arg(value_name = "DIR", default_value = "out")]
    input: PathBuf,
}

pub(crate) fn run(a: PlotArgs) -> Result<(), CliError> {
    let files = draw_dir(&a.input)?;
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

/// Figure size in pixels.
const SIZE: (u32, u32) = (1000, 700);
const FONT: &str = "sans-serif";

const MS: RGBColor = RGBColor(31, 119, 180);
const NM: RGBColor = RGBColor(214, 39, 40);
const PD_C: RGBColor = RGBColor(44, 160, 44);
const HUMAN: RGBColor = RGBColor(40, 40, 40);
const MEASURED: RGBColor = RGBColor(160, 160, 160);
const SCEN: [RGBColor; 6] = [
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn ctrl_color(c: &str) -> RGBColor {
    match c {
        "msnmpc" => MS,
        "nmpc" => NM,
        _ => PD_C,
    }
}

fn ctrl_label(c: &str) -> &'static str {
    match c {
        "msnmpc" => "MS-NMPC",
        "nmpc" => "NMPC",
        "pd" => "PD",
        _ => "controller",
    }
}

/// Registers the embedded DejaVu Sans font once (no system font library needed).
pub(crate) fn ensure_font() -> Result<(), CliError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && register_font(FONT, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(CliError::Runtime("cannot load the embedded font".into()))
    }
}

/// One curve of a panel.
struct Line {
    label: String,
    x: Vec<f64>,
    y: Vec<f64>,
    color: RGBColor,
    dashed: bool,
    markers: bool,
    width: u32,
}

impl Line {
    fn new(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>, color: RGBColor) -> Self {
        Line {
            label: label.into(),
            x,
            y,
            color,
            dashed: false,
            markers: false,
            width: 2,
        }
    }
    fn dashed(mut self) -> Self {
        self.dashed = true;
        self
    }
    fn thin(mut self) -> Self {
        self.width = 1;
        self
    }
    fn wide(mut self) -> Self {
        self.width = 4;
        self
    }
    fn markers(mut self) -> Self {
        self.markers = true;
        self
    }
}

/// One chart of a figure.
struct Panel {
    title: String,
    x_label: String,
    y_label: String,
    lines: Vec<Line>,
    y_range: Option<(f64, f64)>,
}

impl Panel {
    fn time(title: impl Into<String>, y_label: impl Into<String>, lines: Vec<Line>) -> Self {
        Panel {
            title: title.into(),
            x_label: "time (s)".into(),
            y_label: y_label.into(),
            lines,
            y_range: None,
        }
    }
    fn range(mut self, lo: f64, hi: f64) -> Self {
        self.y_range = Some((lo, hi));
        self
    }
}

/// A figure: a title and rows of panels (each row split evenly).
struct Figure {
    title: String,
    rows: Vec<Vec<Panel>>,
}

fn err(e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("drawing figure: {e}"))
}

fn finite_range(vals: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let mut r: Option<(f64, f64)> = None;
    for v in vals.filter(|v| v.is_finite()) {
        r = Some(match r {
            None => (v, v),
            Some((a, b)) => (a.min(v), b.max(v)),
        });
    }
    r
}

fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &Panel) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    let (x0, x1) =
        finite_range(p.lines.iter().flat_map(|l| l.x.iter().copied())).unwrap_or((0.0, 1.0));
    let (x0, x1) = if x1 > x0 {
        (x0, x1)
    } else {
        (x0 - 0.5, x1 + 0.5)
    };
    let with_legend = p.lines.iter().any(|l| !l.label.is_empty());
    let (y0, y1) = match p.y_range {
        Some(r) => r,
        None => {
            let (a, b) = finite_range(p.lines.iter().flat_map(|l| l.y.iter().copied()))
                .unwrap_or((0.0, 1.0));
            let span = if b > a { b - a } else { a.abs().max(1.0) };
            // Head room for the legend above the data.
            let top = if with_legend { 0.35 } else { 0.05 };
            (a - 0.05 * span, b + top * span)
        }
    };
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, (FONT, 17))
        .margin(6)
        .margin_right(14)
        .x_label_area_size(38)
        .y_label_area_size(62)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .label_style((FONT, 12))
        .axis_desc_style((FONT, 13))
        .light_line_style(BLACK.mix(0.04))
        .bold_line_style(BLACK.mix(0.12))
        .x_labels(8)
        .y_labels(6)
        .draw()
        .map_err(err)?;
    for l in &p.lines {
        let style = ShapeStyle {
            color: l.color.to_rgba(),
            filled: false,
            stroke_width: l.width,
        };
        let pts: Vec<(f64, f64)> =
            l.x.iter()
                .zip(&l.y)
                .map(|(&x, &y)| (x, y))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
        let anno = if l.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts.clone(), 7, 4, style))
                .map_err(err)?
        } else {
            chart
                .draw_series(LineSeries::new(pts.clone(), style))
                .map_err(err)?
        };
        if !l.label.is_empty() {
            let legend_style = ShapeStyle {
                stroke_width: 3,
                ..style
            };
            anno.label(l.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], legend_style));
        }
        if l.markers {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, style.filled())))
                .map_err(err)?;
        }
    }
    if with_legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font((FONT, 12))
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

fn render<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, fig: &Figure) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let body = root
        .titled(&fig.title, (FONT, 20).into_font().style(FontStyle::Bold))
        .map_err(err)?;
    let rows = body.split_evenly((fig.rows.len().max(1), 1));
    for (area, row) in rows.iter().zip(&fig.rows) {
        let cells = area.split_evenly((1, row.len().max(1)));
        for (cell, panel) in cells.iter().zip(row) {
            draw_panel(cell, panel)?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Writes `dir/stem.svg` and `dir/stem.png` (each through a temporary file renamed at the end).
fn save(fig: &Figure, dir: &Path, stem: &str) -> Result<Vec<PathBuf>, CliError> {
    let mut svg = String::new();
    render(
        SVGBackend::with_string(&mut svg, SIZE).into_drawing_area(),
        fig,
    )?;
    let svg_path = dir.join(format!("{stem}.svg"));
    io::write_atomic(&svg_path, svg.as_bytes())?;
    let png_path = dir.join(format!("{stem}.png"));
    let tmp = dir.join(format!(".{stem}.tmp.{}.png", std::process::id()));
    let drawn = render(BitMapBackend::new(&tmp, SIZE).into_drawing_area(), fig);
    if let Err(e) = drawn {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, &png_path)
        .map_err(|e| CliError::io(format!("writing {}", png_path.display()), e))?;
    Ok(vec![png_path, svg_path])
}

/// A loaded run: its trace and (when present) its summary.
struct Run {
    trace: TraceTable,
    summary: Option<Summary>,
    controller: String,
}

impl Run {
    fn load(dir: &Path) -> Result<Self, CliError> {
        let trace = read_trace(&dir.join("trace.csv"))?;
        let summary: Option<Summary> = std::fs::read_to_string(dir.join("summary.json"))
            .ok()
            .and_then(|s| serde_json::from_str(&s).ok());
        let controller = summary
            .as_ref()
            .map(|s| s.controller.clone())
            .unwrap_or_else(|| {
                if trace.scenarios() > 0 {
                    "msnmpc".into()
                } else {
                    "controller".into()
                }
            });
        Ok(Run {
            trace,
            summary,
            controller,
        })
    }

    fn col(&self, name: &str) -> Vec<f64> {
        self.trace.column(name).unwrap_or_default()
    }

    fn t(&self) -> Vec<f64> {
        self.col("t")
    }

    fn deg(&self, name: &str) -> Vec<f64> {
        self.col(name).into_iter().map(f64::to_degrees).collect()
    }

    /// q_human − q_robot of joint `j` (deg).
    fn error_deg(&self, j: &str) -> Vec<f64> {
        let h = self.col(&format!("q_human_{j}"));
        let r = self.col(&format!("q_robot_{j}"));
        h.iter()
            .zip(&r)
            .map(|(a, b)| (a - b).to_degrees())
            .collect()
    }

    fn label(&self) -> &'static str {
        ctrl_label(&self.controller)
    }

    fn describe(&self) -> String {
        let n = self.trace.joints();
        match &self.summary {
            Some(s) => format!("{}, {n}-DOF, payload {} kg", self.label(), s.payload_kg),
            None => format!("{}, {n}-DOF", self.label()),
        }
    }
}

fn probability_panel(run: &Run) -> Option<Panel> {
    let s = run.trace.scenarios();
    if s == 0 {
        return None;
    }
    let t = run.t();
    let lines = (1..=s)
        .map(|i| {
            let y = run
                .col(&format!("mu_{i}"))
                .into_iter()
                .map(|v| 100.0 * v)
                .collect();
            Line::new(format!("μ{i}"), t.clone(), y, SCEN[(i - 1) % SCEN.len()])
        })
        .collect();
    Some(
        Panel::time(
            format!("{}: scenario probabilities", run.label()),
            "probability (%)",
            lines,
        )
        .range(-3.0, 140.0),
    )
}

/// Angles human vs robot, velocities and robot torques per joint (Figs. 3 and 7).
fn states_figure(run: &Run) -> Figure {
    let t = run.t();
    let joints = joint_names(run.trace.joints());
    let c = ctrl_color(&run.controller);
    let row = |kind: &str| -> Vec<Panel> {
        joints
            .iter()
            .map(|j| match kind {
                "q" => Panel::time(
                    format!("{j} angle"),
                    "angle (deg)",
                    vec![
                        Line::new("robot", t.clone(), run.deg(&format!("q_robot_{j}")), c).wide(),
                        Line::new("human", t.clone(), run.deg(&format!("q_human_{j}")), HUMAN)
                            .dashed(),
                    ],
                ),
                "qd" => Panel::time(
                    format!("{j} angular velocity"),
                    "velocity (deg/s)",
                    vec![
                        Line::new("robot", t.clone(), run.deg(&format!("qd_robot_{j}")), c).wide(),
                        Line::new("human", t.clone(), run.deg(&format!("qd_human_{j}")), HUMAN)
                            .dashed(),
                    ],
                ),
                _ => Panel::time(
                    format!("{j} robot torque (control input)"),
                    "torque (N·m)",
                    vec![Line::new(
                        "",
                        t.clone(),
                        run.col(&format!("torque_robot_{j}")),
                        c,
                    )],
                ),
            })
            .collect()
    };
    Figure {
        title: format!("{}: joint angles, velocities and torques", run.describe()),
        rows: vec![row("q"), row("qd"), row("tau")],
    }
}

/// Tracking errors, strap forces (true and measured), probabilities and compute time of one
/// run (the single-run counterpart of Figs. 4, 6 and 8).
fn interaction_figure(run: &Run) -> Figure {
    let t = run.t();
    let n = run.trace.joints();
    let c = ctrl_color(&run.controller);
    let errors = joint_names(n)
        .iter()
        .map(|j| {
            Panel::time(
                format!("{j} tracking error q_H − q_R"),
                "error (deg)",
                vec![Line::new("", t.clone(), run.error_deg(j), c)],
            )
        })
        .collect();
    let forces = strap_names(n)
        .iter()
        .map(|s| {
            Panel::time(
                format!("{s} strap force"),
                "force (N)",
                vec![
                    Line::new(
                        "measured",
                        t.clone(),
                        run.col(&format!("force_measured_{s}")),
                        MEASURED,
                    )
                    .thin(),
                    Line::new("true", t.clone(), run.col(&format!("force_true_{s}")), c),
                ],
            )
        })
        .collect();
    let mut last = Vec::new();
    if let Some(p) = probability_panel(run) {
        last.push(p);
    }
    last.push(Panel::time(
        "controller compute time per step",
        "time (µs)",
        vec![Line::new("", t.clone(), run.col("step_us"), c).thin()],
    ));
    Figure {
        title: format!("{}: tracking errors and interaction forces", run.describe()),
        rows: vec![errors, forces, last],
    }
}

fn draw_run_dir(dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    let run = Run::load(dir)?;
    let mut files = save(&states_figure(&run), dir, "states")?;
    files.extend(save(&interaction_figure(&run), dir, "interaction")?);
    Ok(files)
}

/// NMPC vs MS-NMPC at one payload: tracking errors, strap forces, probabilities (Figs. 4, 6, 8).
fn compare_figure(runs: &[Run], payload: f64) -> Figure {
    let n = runs[0].trace.joints();
    let errors = joint_names(n)
        .iter()
        .map(|j| {
            let lines = runs
                .iter()
                .map(|r| Line::new(r.label(), r.t(), r.error_deg(j), ctrl_color(&r.controller)))
                .collect();
            Panel::time(
                format!("{j} tracking error q_H − q_R"),
                "error (deg)",
                lines,
            )
        })
        .collect();
    let forces = strap_names(n)
        .iter()
        .map(|s| {
            let lines = runs
                .iter()
                .map(|r| {
                    Line::new(
                        r.label(),
                        r.t(),
                        r.col(&format!("force_true_{s}")),
                        ctrl_color(&r.controller),
                    )
                })
                .collect();
            Panel::time(format!("{s} strap force"), "force (N)", lines)
        })
        .collect();
    let mut rows = vec![errors, forces];
    if let Some(p) = runs.iter().find_map(probability_panel) {
        rows.push(vec![p]);
    }
    let names: Vec<&str> = runs.iter().map(Run::label).collect();
    Figure {
        title: format!(
            "{} at {payload} kg, {n}-DOF: tracking errors, strap forces, probabilities",
            names.join(" vs ")
        ),
        rows,
    }
}

/// Compute time per control step of each controller (Fig. 5).
fn step_time_figure(runs: &[Run], payload: f64) -> Figure {
    let panels = runs
        .iter()
        .map(|r| {
            let label = match &r.summary {
                Some(s) => format!(
                    "p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
                    s.step_time_us.p50, s.step_time_us.p99, s.step_time_us.max
                ),
                None => String::new(),
            };
            let panel = Panel::time(
                format!("{} compute time per step", r.label()),
                "time (µs)",
                vec![Line::new(label, r.t(), r.col("step_us"), ctrl_color(&r.controller)).thin()],
            );
            // Isolated pre-emption spikes (ms) would flatten the typical values: the axis stops
            // at 4 × p99; the legend gives the maximum.
            vec![match &r.summary {
                Some(s)
                    if s.step_time_us.p99 > 0.0
                        && s.step_time_us.max > 4.0 * s.step_time_us.p99 =>
                {
                    panel.range(0.0, 4.0 * s.step_time_us.p99)
                }
                _ => panel,
            }]
        })
        .collect();
    Figure {
        title: format!(
            "Controller compute time per step at {payload} kg, {}-DOF",
            runs[0].trace.joints()
        ),
        rows: panels,
    }
}

/// One number of a summary.
type Metric = fn(&Summary) -> Option<f64>;

/// RMS strap forces and mean scenario probabilities against the payload.
fn payload_figure(rows: &[Summary]) -> Figure {
    let dof = rows.first().map_or(2, |r| r.dof);
    let mut ctrls: Vec<&str> = Vec::new();
    for c in ["msnmpc", "nmpc", "pd"] {
        if rows.iter().any(|r| r.controller == c) {
            ctrls.push(c);
        }
    }
    let series = |c: &str, f: &dyn Fn(&Summary) -> Option<f64>| -> (Vec<f64>, Vec<f64>) {
        let mut pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.controller == c)
            .filter_map(|r| f(r).map(|v| (r.payload_kg, v)))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        pts.into_iter().unzip()
    };
    let straps: Vec<(&str, Metric)> = if dof == 1 {
        vec![("shank", |r| r.rms_force_n.shank)]
    } else {
        vec![
            ("thigh", |r| r.rms_force_n.thigh),
            ("shank", |r| r.rms_force_n.shank),
        ]
    };
    let force_row = straps
        .iter()
        .map(|(name, f)| {
            let lines = ctrls
                .iter()
                .map(|c| {
                    let (x, y) = series(c, f);
                    Line::new(ctrl_label(c), x, y, ctrl_color(c)).markers()
                })
                .collect();
            let mut p = Panel::time(format!("{name} strap: RMS force"), "RMS force (N)", lines);
            p.x_label = "payload (kg)".into();
            p
        })
        .collect::<Vec<_>>();
    let mut fig_rows = vec![force_row];
    let s = rows
        .iter()
        .filter_map(|r| r.mean_probability.as_ref().map(Vec::len))
        .max()
        .unwrap_or(0);
    if s > 0 {
        let lines = (0..s)
            .map(|i| {
                let (x, y) = series("msnmpc", &|r: &Summary| {
                    r.mean_probability
                        .as_ref()
                        .and_then(|m| m.get(i))
                        .map(|v| 100.0 * v)
                });
                Line::new(format!("μ̄{}", i + 1), x, y, SCEN[i % SCEN.len()]).markers()
            })
            .collect();
        let mut p = Panel::time(
            "MS-NMPC: mean scenario probabilities",
            "mean probability (%)",
            lines,
        )
        .range(-3.0, 140.0);
        p.x_label = "payload (kg)".into();
        fig_rows.push(vec![p]);
    }
    Figure {
        title: format!("Payload sweep, {dof}-DOF: RMS strap forces and scenario probabilities"),
        rows: fig_rows,
    }
}

fn draw_sweep_dir(dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    let text = std::fs::read_to_string(dir.join("sweep.json"))
        .map_err(|e| CliError::io(format!("reading {}/sweep.json", dir.display()), e))?;
    let sweep: SweepFile = serde_json::from_str(&text)
        .map_err(|e| CliError::Runtime(format!("bad {}/sweep.json: {e}", dir.display())))?;
    let rows = sweep.rows;
    if rows.is_empty() {
        return Err(CliError::Runtime(format!(
            "{}/sweep.json has no rows",
            dir.display()
        )));
    }
    let mut files = save(&payload_figure(&rows), dir, "payload_sweep")?;
    let load_at = |p: f64| -> Result<Vec<Run>, CliError> {
        let mut runs = Vec::new();
        for c in ["nmpc", "msnmpc", "pd"] {
            if rows.iter().any(|r| r.controller == c && r.payload_kg == p) {
                let d = dir.join(run_dir_name(c, p));
                if d.join("trace.csv").is_file() {
                    runs.push(Run::load(&d)?);
                }
            }
        }
        Ok(runs)
    };
    let pmax = rows
        .iter()
        .map(|r| r.payload_kg)
        .fold(f64::NEG_INFINITY, f64::max);
    let runs = load_at(pmax)?;
    if !runs.is_empty() {
        let tag = run_dir_name("", pmax);
        let tag = tag.trim_start_matches('_');
        let main = runs
            .iter()
            .find(|r| r.controller == "msnmpc")
            .unwrap_or(&runs[0]);
        files.extend(save(
            &states_figure(main),
            dir,
            &format!("states_{}_{tag}", main.controller),
        )?);
        files.extend(save(
            &compare_figure(&runs, pmax),
            dir,
            &format!("compare_{tag}"),
        )?);
        files.extend(save(
            &step_time_figure(&runs, pmax),
            dir,
            &format!("step_time_{tag}"),
        )?);
    }
    if pmax != 0.0 && rows.iter().any(|r| r.payload_kg == 0.0) {
        let runs = load_at(0.0)?;
        if !runs.is_empty() {
            files.extend(save(&compare_figure(&runs, 0.0), dir, "compare_0kg")?);
        }
    }
    Ok(files)
}

/// Draw the figures of the traces in `dir`: the single-run figures for a `simulate` folder
/// (`trace.csv`), the comparison and payload-sweep figures for a `sweep` folder (`sweep.json`).
/// Returns the files written.
pub(crate) fn draw_dir(dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    ensure_font()?;
    let mut files = Vec::new();
    let single = dir.join("trace.csv").is_file();
    let sweep = dir.join("sweep.json").is_file();
    if !single && !sweep {
        return Err(CliError::Usage(format!(
            "{}: no trace.csv (simulate) or sweep.json (sweep) to plot",
            dir.display()
        )));
    }
    if single {
        files.extend(draw_run_dir(dir)?);
    }
    if sweep {
        files.extend(draw_sweep_dir(dir)?);
    }
    Ok(files)
}
