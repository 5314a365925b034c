//! `exompc plot DIR`: figures (PNG and SVG) of the traces in a `simulate` or `sweep` folder.
//!
//! A `simulate` folder (`trace.csv`) gives the single-run figures `states` (angles human vs
//! robot, velocities, torques: paper Figs. 3 and 7) and `interaction` (tracking errors, strap
//! forces, scenario probabilities, compute time). A `sweep` folder (`sweep.json`) gives the
//! comparison figures at the largest payload (`states_<ctrl>_<p>kg`, `compare_<p>kg`,
//! `step_time_<p>kg`: Figs. 3-5 / 7-8), at no load (`compare_0kg`: Fig. 6) and the
//! payload-sweep figure `payload_sweep` (RMS strap forces and mean probabilities vs payload).

use exompc::scenario::controller_by_name;
use exompc::sim::Summary;
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::layout::{run_dir_name, SweepFile};
use exompc_cli::trace::{joint_names, read_trace, strap_names, TraceTable};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

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

/// Controller colours, indexed by `ControllerInfo::colour` of the registry (modulo the length).
const CONTROLLER_COLOURS: [RGBColor; 6] = [
    MS,
    NM,
    PD_C,
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn ctrl_color(c: &str) -> RGBColor {
    controller_by_name(c).map_or(PD_C, |i| {
        CONTROLLER_COLOURS[i.colour % CONTROLLER_COLOURS.len()]
    })
}

fn ctrl_label(c: &str) -> &'static str {
    controller_by_name(c).map_or("controller", |i| i.label)
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

/// Label of a tick value with no needless decimals (`40`, `2.5`, `0.25`, `-1e-5`).
fn tick_label(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e6).contains(&a) {
        return format!("{v:.1e}");
    }
    let t = format!("{v:.4}");
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t == "-0" {
        "0".into()
    } else {
        t.to_string()
    }
}

/// The axis ranges of a panel: x over the data, y over the data (or the panel's fixed range)
/// with a small margin; no head room is reserved for the legend, which is drawn beside the plot.
fn panel_ranges(p: &Panel) -> ((f64, f64), (f64, f64)) {
    let (x0, x1) =
        finite_range(p.lines.iter().flat_map(|l| l.x.iter().copied())).unwrap_or((0.0, 1.0));
    let x = if x1 > x0 {
        // Markers at the first and last x get room to be drawn whole.
        let pad = if p.lines.iter().any(|l| l.markers) {
            0.05 * (x1 - x0)
        } else {
            0.0
        };
        (x0 - pad, x1 + pad)
    } else {
        (x0 - 0.5, x1 + 0.5)
    };
    let y = match p.y_range {
        Some(r) => r,
        None => {
            let (a, b) = finite_range(p.lines.iter().flat_map(|l| l.y.iter().copied()))
                .unwrap_or((0.0, 1.0));
            let span = if b > a { b - a } else { a.abs().max(1.0) };
            (a - 0.05 * span, b + 0.05 * span)
        }
    };
    (x, y)
}

/// Cuts polyline `pts` to the box `x × y`: the pieces inside it, with the crossing points
/// interpolated on the border (non-finite points break the line). Every returned point lies in
/// the box, so nothing is drawn outside its panel.
fn clip_polyline(pts: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let inside = |p: (f64, f64)| p.0 >= x.0 && p.0 <= x.1 && p.1 >= y.0 && p.1 <= y.1;
    let finite = |p: (f64, f64)| p.0.is_finite() && p.1.is_finite();
    // Liang-Barsky clipping of segment a-b to the box.
    let clip = |a: (f64, f64), b: (f64, f64)| -> Option<((f64, f64), (f64, f64))> {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
        for (pk, qk) in [
            (-dx, a.0 - x.0),
            (dx, x.1 - a.0),
            (-dy, a.1 - y.0),
            (dy, y.1 - a.1),
        ] {
            if pk == 0.0 {
                if qk < 0.0 {
                    return None;
                }
            } else {
                let r = qk / pk;
                if pk < 0.0 {
                    t0 = t0.max(r);
                } else {
                    t1 = t1.min(r);
                }
            }
        }
        if t0 > t1 {
            return None;
        }
        let at = |t: f64| {
            (
                (a.0 + t * dx).clamp(x.0, x.1),
                (a.1 + t * dy).clamp(y.0, y.1),
            )
        };
        Some((at(t0), at(t1)))
    };
    let mut pieces: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    let flush = |cur: &mut Vec<(f64, f64)>, pieces: &mut Vec<Vec<(f64, f64)>>| {
        if !cur.is_empty() {
            pieces.push(std::mem::take(cur));
        }
    };
    for (i, &b) in pts.iter().enumerate() {
        if !finite(b) {
            flush(&mut cur, &mut pieces);
            continue;
        }
        let a = if i > 0 {
            pts[i - 1]
        } else {
            (f64::NAN, f64::NAN)
        };
        if !finite(a) {
            if inside(b) {
                cur.push(b);
            }
            continue;
        }
        match clip(a, b) {
            Some((pa, pb)) => {
                if cur.last() != Some(&pa) {
                    flush(&mut cur, &mut pieces);
                    cur.push(pa);
                }
                cur.push(pb);
                if pb != b {
                    flush(&mut cur, &mut pieces);
                }
            }
            None => flush(&mut cur, &mut pieces),
        }
    }
    flush(&mut cur, &mut pieces);
    pieces
}

/// What a panel draws, in data coordinates: the axis ranges and, per line, its clipped pieces.
/// Drawing goes through this only, so a test can check that every drawn point is inside.
struct PanelGeometry {
    x: (f64, f64),
    y: (f64, f64),
    pieces: Vec<Vec<Vec<(f64, f64)>>>,
}

fn panel_geometry(p: &Panel) -> PanelGeometry {
    let (x, y) = panel_ranges(p);
    let pieces = p
        .lines
        .iter()
        .map(|l| {
            let pts: Vec<(f64, f64)> = l.x.iter().copied().zip(l.y.iter().copied()).collect();
            clip_polyline(&pts, x, y)
        })
        .collect();
    PanelGeometry { x, y, pieces }
}

/// Width (px) of the legend column beside a panel's plot.
fn legend_width(p: &Panel) -> u32 {
    let chars = p
        .lines
        .iter()
        .map(|l| l.label.chars().count())
        .max()
        .unwrap_or(0) as u32;
    if chars == 0 {
        0
    } else {
        40 + 8 * chars
    }
}

/// Pixel rectangle `(x0, y0, x1, y1)` (inclusive) of a drawing area.
type Rect = (i32, i32, i32, i32);

fn rect_of<DB: DrawingBackend, CT: plotters::coord::CoordTranslate>(
    a: &DrawingArea<DB, CT>,
) -> Rect {
    let (x, y) = a.get_pixel_range();
    (x.start, y.start, x.end - 1, y.end - 1)
}

/// Draws panel `p` into `area`; returns the pixel rectangles where series colours may appear
/// (the plot area and the legend column).
fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    p: &Panel,
) -> Result<Vec<Rect>, CliError>
where
    DB::ErrorType: 'static,
{
    let g = panel_geometry(p);
    // The legend gets its own column right of the plot: it never covers data. A line with
    // nothing visible gets no entry.
    let lw = legend_width(p);
    let (plot_area, legend_area) = if lw > 0 {
        let w = area.dim_in_pixel().0;
        let (a, b) = area.split_horizontally(w.saturating_sub(lw));
        (a, Some(b))
    } else {
        (area.clone(), None)
    };
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(&p.title, (FONT, 18))
        .margin(6)
        .margin_right(if lw > 0 { 4 } else { 14 })
        .x_label_area_size(38)
        .y_label_area_size(62)
        .build_cartesian_2d(g.x.0..g.x.1, g.y.0..g.y.1)
        .map_err(err)?;
    let fmt = |v: &f64| tick_label(*v);
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .label_style((FONT, 12))
        .axis_desc_style((FONT, 14))
        .light_line_style(BLACK.mix(0.04))
        .bold_line_style(BLACK.mix(0.12))
        .x_labels(8)
        .y_labels(6)
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .draw()
        .map_err(err)?;
    // Legend entries: label, the line's style, dashed, markers (drawn as plotted).
    let mut entries: Vec<(String, ShapeStyle, bool, bool)> = Vec::new();
    for (l, pieces) in p.lines.iter().zip(&g.pieces) {
        let style = ShapeStyle {
            color: l.color.to_rgba(),
            filled: false,
            stroke_width: l.width,
        };
        // Wide polylines are drawn with mitred joins: a sharp reversal (a chattering
        // probability, a noisy peak) would shoot a long spike out of the panel. Split the
        // pieces at every turn sharper than 90° in pixel space, so there are no such joins.
        let to_px = |q: &(f64, f64)| chart.backend_coord(q);
        let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
        for piece in pieces {
            let mut cur: Vec<(f64, f64)> = Vec::with_capacity(piece.len());
            for &q in piece {
                let n = cur.len();
                // A point on the previous point's pixel makes a zero-length segment, whose
                // join has no direction: skip it.
                if n >= 1 && to_px(&q) == to_px(&cur[n - 1]) {
                    continue;
                }
                if n >= 2 {
                    let (a, b, c) = (to_px(&cur[n - 2]), to_px(&cur[n - 1]), to_px(&q));
                    let dot = (b.0 - a.0) * (c.0 - b.0) + (b.1 - a.1) * (c.1 - b.1);
                    if dot <= 0 {
                        let last = cur[n - 1];
                        runs.push(std::mem::take(&mut cur));
                        cur.push(last);
                    }
                }
                cur.push(q);
            }
            if !cur.is_empty() {
                runs.push(cur);
            }
        }
        for piece in &runs {
            if l.dashed {
                chart
                    .draw_series(DashedLineSeries::new(piece.clone(), 7, 4, style))
                    .map_err(err)?;
            } else {
                chart
                    .draw_series(LineSeries::new(piece.clone(), style))
                    .map_err(err)?;
            }
        }
        if l.markers {
            let marks =
                l.x.iter()
                    .zip(&l.y)
                    .map(|(&x, &y)| (x, y))
                    .filter(|&(x, y)| x >= g.x.0 && x <= g.x.1 && y >= g.y.0 && y <= g.y.1);
            chart
                .draw_series(marks.map(|q| Circle::new(q, 4, style.filled())))
                .map_err(err)?;
        }
        if !l.label.is_empty() && pieces.iter().any(|q| !q.is_empty()) {
            entries.push((l.label.clone(), style, l.dashed, l.markers));
        }
    }
    let mut rects = vec![rect_of(chart.plotting_area())];
    if let Some(la) = legend_area {
        rects.push(rect_of(&la));
        for (i, (label, style, dashed, markers)) in entries.iter().enumerate() {
            let y = 40 + 20 * i as i32;
            // The plotted line's own width (at least 2 px so that a thin line's colour shows).
            let s = ShapeStyle {
                stroke_width: style.stroke_width.max(2),
                ..*style
            };
            if *dashed {
                la.draw(&PathElement::new(vec![(4, y), (11, y)], s))
                    .map_err(err)?;
                la.draw(&PathElement::new(vec![(17, y), (24, y)], s))
                    .map_err(err)?;
            } else {
                la.draw(&PathElement::new(vec![(4, y), (24, y)], s))
                    .map_err(err)?;
            }
            if *markers {
                la.draw(&Circle::new((14, y), 4, style.filled()))
                    .map_err(err)?;
            }
            la.draw(&Text::new(
                label.as_str(),
                (30, y - 7),
                (FONT, 12).into_font(),
            ))
            .map_err(err)?;
        }
    }
    Ok(rects)
}

/// Draws `fig` into `root`; returns the pixel rectangles where series colours may appear.
fn render<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<Vec<Rect>, CliError>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let body = root
        .titled(&fig.title, (FONT, 20).into_font().style(FontStyle::Bold))
        .map_err(err)?;
    let rows = body.split_evenly((fig.rows.len().max(1), 1));
    let mut rects = Vec::new();
    for (area, row) in rows.iter().zip(&fig.rows) {
        let cells = area.split_evenly((1, row.len().max(1)));
        for (cell, panel) in cells.iter().zip(row) {
            rects.extend(draw_panel(cell, panel)?);
        }
    }
    root.present().map_err(err)?;
    Ok(rects)
}

/// Something drawn alike on the SVG and the PNG backend ([`write_drawing`]): the figures of
/// this module and the heat maps of `exompc envelope` and `exompc faults`.
pub(crate) trait Drawing {
    /// Draws it on `root`.
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), CliError>
    where
        DB::ErrorType: 'static;
}

impl Drawing for Figure {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), CliError>
    where
        DB::ErrorType: 'static,
    {
        render(root, self).map(drop)
    }
}

/// Writes `dir/stem.svg` and `dir/stem.png` of `drawing`, `size` pixels (each through a
/// temporary file renamed at the end; the temporary PNG is removed when it fails to draw);
/// returns the PNG's path, then the SVG's.
pub(crate) fn write_drawing(
    drawing: &impl Drawing,
    dir: &Path,
    stem: &str,
    size: (u32, u32),
) -> Result<Vec<PathBuf>, CliError> {
    ensure_font()?;
    let mut svg = String::new();
    drawing.draw(SVGBackend::with_string(&mut svg, size).into_drawing_area())?;
    let svg_path = dir.join(format!("{stem}.svg"));
    io::write_atomic(&svg_path, svg.as_bytes())?;
    let png_path = dir.join(format!("{stem}.png"));
    let tmp = dir.join(format!(".{stem}.tmp.{}.png", std::process::id()));
    if let Err(e) = drawing.draw(BitMapBackend::new(&tmp, size).into_drawing_area()) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, &png_path)
        .map_err(|e| CliError::io(format!("writing {}", png_path.display()), e))?;
    Ok(vec![png_path, svg_path])
}

/// Writes `dir/stem.svg` and `dir/stem.png` of a figure ([`write_drawing`], [`SIZE`]).
fn save(fig: &Figure, dir: &Path, stem: &str) -> Result<Vec<PathBuf>, CliError> {
    write_drawing(fig, dir, stem, SIZE)
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

/// Legend label of scenario `i` (0-based) with trace key `key`: its name from the summary
/// (`"0 kg"`, ...), else the name in the column (`mu_<name>`), else `μ<i+1>`.
fn scenario_label(names: Option<&[String]>, i: usize, key: &str) -> String {
    match names.and_then(|n| n.get(i)) {
        Some(name) => name.clone(),
        None if key.parse::<usize>().is_ok() => format!("μ{key}"),
        None => key.to_string(),
    }
}

fn probability_panel(run: &Run) -> Option<Panel> {
    let keys = run.trace.scenario_keys();
    if keys.is_empty() {
        return None;
    }
    let t = run.t();
    let names = run.summary.as_ref().and_then(|s| s.scenarios.as_deref());
    let lines = keys
        .iter()
        .enumerate()
        .map(|(i, key)| {
            let y = run
                .col(&format!("mu_{key}"))
                .into_iter()
                .map(|v| 100.0 * v)
                .collect();
            Line::new(
                scenario_label(names, i, key),
                t.clone(),
                y,
                SCEN[i % SCEN.len()],
            )
        })
        .collect();
    Some(
        Panel::time(
            format!("{}: scenario probabilities", run.label()),
            "probability (%)",
            lines,
        )
        .range(0.0, 100.0),
    )
}

/// Title of a strap-force panel, with the sign convention (docs/MODEL.md §4:
/// `F = ks J (q_H − q_R) + cs J (qd_H − qd_R)`, positive when the human is ahead of the robot).
fn strap_title(s: &str) -> String {
    format!("{s} strap force (F > 0: human ahead of robot)")
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
                strap_title(s),
                "force (N)",
                // The thin measured line on top of the true one, so that both stay visible.
                vec![
                    Line::new("true", t.clone(), run.col(&format!("force_true_{s}")), c),
                    Line::new(
                        "measured",
                        t.clone(),
                        run.col(&format!("force_measured_{s}")),
                        MEASURED,
                    )
                    .thin(),
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
            Panel::time(strap_title(s), "force (N)", lines)
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
            let stats = match &r.summary {
                Some(s) => format!(
                    ": p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
                    s.step_time_us.p50, s.step_time_us.p99, s.step_time_us.max
                ),
                None => String::new(),
            };
            let panel = Panel::time(
                format!("{} compute time per step{stats}", r.label()),
                "time (µs)",
                vec![Line::new("", r.t(), r.col("step_us"), ctrl_color(&r.controller)).thin()],
            );
            // Isolated pre-emption spikes (ms) would flatten the typical values: the axis stops
            // at 4 × p99 (the spikes are cut at the top); the title gives the maximum.
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
    let ctrls = exompc_cli::layout::controller_order(rows);
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
    // The probabilities of the first controller (in table order) that reports them.
    let multistage = ctrls
        .iter()
        .find(|c| {
            rows.iter()
                .any(|r| &r.controller == *c && r.mean_probability.is_some())
        })
        .map_or("", |c| c.as_str());
    if s > 0 {
        let names = rows.iter().find_map(|r| r.scenarios.as_deref());
        let lines = (0..s)
            .map(|i| {
                let (x, y) = series(multistage, &|r: &Summary| {
                    r.mean_probability
                        .as_ref()
                        .and_then(|m| m.get(i))
                        .map(|v| 100.0 * v)
                });
                let label = match names.and_then(|n| n.get(i)) {
                    Some(name) => format!("μ {name}"),
                    None => format!("μ{}", i + 1),
                };
                Line::new(label, x, y, SCEN[i % SCEN.len()]).markers()
            })
            .collect();
        let mut p = Panel::time(
            format!("{}: mean scenario probabilities", ctrl_label(multistage)),
            "mean probability (%)",
            lines,
        )
        .range(0.0, 100.0);
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
        for c in exompc_cli::layout::controller_order(&rows) {
            let c = c.as_str();
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
        // The states figure of the first controller with scenarios (MS-NMPC), else the first.
        let main = runs
            .iter()
            .find(|r| r.trace.scenarios() > 0)
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

/// Colour of a force `v` (N) on the white → yellow → red → dark-red scale of the heat maps,
/// saturating at `max` N; grey when not finite.
pub(crate) fn heat_scaled(v: f64, max: f64) -> RGBColor {
    if !v.is_finite() {
        return RGBColor(150, 150, 150);
    }
    let x = (v / max).clamp(0.0, 1.0);
    let lerp = |a: u8, b: u8, t: f64| (a as f64 + (b as f64 - a as f64) * t).round() as u8;
    let stops = [
        (0.0, (255, 255, 255)),
        (1.0 / 6.0, (255, 237, 160)),
        (1.0 / 3.0, (253, 141, 60)),
        (2.0 / 3.0, (215, 48, 31)),
        (1.0, (127, 0, 0)),
    ];
    for w in stops.windows(2) {
        let ((x0, c0), (x1, c1)) = (w[0], w[1]);
        if x <= x1 {
            let t = (x - x0) / (x1 - x0);
            return RGBColor(
                lerp(c0.0, c1.0, t),
                lerp(c0.1, c1.1, t),
                lerp(c0.2, c1.2, t),
            );
        }
    }
    RGBColor(127, 0, 0)
}

/// The colour bar of [`heat_scaled`] up to `max` at `(x, y)`, `height` pixels tall: 0 N at
/// the bottom, `max` N (and beyond) at the top, six tick intervals, titled with the quantity
/// and its unit.
pub(crate) fn colour_bar<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (x, y): (i32, i32),
    height: i32,
    font: &str,
    max: f64,
) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    let height = height.max(60);
    let width = 16;
    root.draw(&Text::new(
        "force (N)",
        (x - 14, y - 22),
        (font, 14).into_font(),
    ))
    .map_err(heat_err)?;
    for k in 0..height {
        let v = max * f64::from(height - 1 - k) / f64::from(height - 1);
        root.draw(&Rectangle::new(
            [(x, y + k), (x + width, y + k + 1)],
            heat_scaled(v, max).filled(),
        ))
        .map_err(heat_err)?;
    }
    root.draw(&Rectangle::new(
        [(x, y), (x + width, y + height)],
        BLACK.stroke_width(1),
    ))
    .map_err(heat_err)?;
    for n in 0..=6 {
        let ty = y + (f64::from(height - 1) * (1.0 - f64::from(n) / 6.0)).round() as i32;
        root.draw(&PathElement::new(
            vec![(x + width, ty), (x + width + 4, ty)],
            BLACK.stroke_width(1),
        ))
        .map_err(heat_err)?;
        let tick = max * f64::from(n) / 6.0;
        let label = if n == 6 {
            format!("≥ {tick}")
        } else {
            format!("{tick}")
        };
        root.draw(&Text::new(
            label,
            (x + width + 7, ty - 6),
            (font, 12).into_font(),
        ))
        .map_err(heat_err)?;
    }
    Ok(())
}

/// One cell of a heat map: the rectangle `[(x, y), (x + w − 2, y + h − 2)]` filled with the
/// colour of `v` on [`heat_scaled`]'s scale up to `max`; framed in black `frame` pixels wide
/// (0: no frame); `label` written `text_dx` pixels right of the left edge, vertically centred,
/// in `font_size`, white on the upper half of the scale.
#[allow(clippy::too_many_arguments)]
pub(crate) fn heat_cell<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (x, y, w, h): (i32, i32, i32, i32),
    v: f64,
    max: f64,
    frame: u32,
    label: String,
    text_dx: i32,
    font_size: u32,
) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    root.draw(&Rectangle::new(
        [(x, y), (x + w - 2, y + h - 2)],
        heat_scaled(v, max).filled(),
    ))
    .map_err(heat_err)?;
    if frame > 0 {
        root.draw(&Rectangle::new(
            [(x + 1, y + 1), (x + w - 3, y + h - 3)],
            BLACK.stroke_width(frame),
        ))
        .map_err(heat_err)?;
    }
    let color = if v > max / 2.0 { WHITE } else { BLACK };
    root.draw(&Text::new(
        label,
        (x + text_dx, y + h / 2 - 7),
        (FONT, font_size).into_font().color(&color),
    ))
    .map_err(heat_err)?;
    Ok(())
}

/// The error of drawing a heat map.
pub(crate) fn heat_err(e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("drawing the heat map: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use exompc_cli::trace::header;

    /// A 2-DOF, 3-scenario trace whose probabilities chatter between 0 and 1 every step
    /// (with rounding excursions just outside [0, 1]), with force spikes and NaN gaps.
    fn chattering_run() -> Run {
        let columns = header(2, 3);
        // More steps than pixels across a panel: several points share a pixel column.
        let n = 3000;
        let rows = (0..n)
            .map(|k| {
                let t = k as f64 * 0.01;
                columns
                    .iter()
                    .map(|c| {
                        let ph = (t * 6.0).sin();
                        match c.as_str() {
                            "t" => t,
                            "mu_1" => {
                                if (k / 2) % 2 == 0 {
                                    1.0 + 1e-12
                                } else {
                                    -1e-12
                                }
                            }
                            "mu_2" => (k % 3) as f64 / 2.0,
                            "mu_3" => 1.0 - (k % 2) as f64,
                            c if c.starts_with("force") && k % 97 == 0 => 1e4,
                            c if c.starts_with("q_human") && k % 50 == 0 => f64::NAN,
                            "step_us" => {
                                if k % 100 == 7 {
                                    9000.0
                                } else {
                                    5.0
                                }
                            }
                            _ => ph,
                        }
                    })
                    .collect()
            })
            .collect();
        Run {
            trace: TraceTable {
                columns,
                rows,
                status: vec![String::new(); n],
            },
            summary: Some(Summary {
                controller: "msnmpc".into(),
                dof: 2,
                payload_kg: 2.0,
                step_time_us: exompc::sim::StepTimeStats {
                    p50: 5.0,
                    p99: 6.0,
                    max: 9000.0,
                    ..Default::default()
                },
                ..Default::default()
            }),
            controller: "msnmpc".into(),
        }
    }

    fn assert_inside(fig: &Figure) {
        for panel in fig.rows.iter().flatten() {
            let g = panel_geometry(panel);
            let mut drawn = 0;
            for pieces in &g.pieces {
                for piece in pieces {
                    for &(x, y) in piece {
                        drawn += 1;
                        assert!(
                            x >= g.x.0 && x <= g.x.1 && y >= g.y.0 && y <= g.y.1,
                            "{}: ({x}, {y}) outside {:?} × {:?}",
                            panel.title,
                            g.x,
                            g.y
                        );
                    }
                }
            }
            assert!(drawn > 0, "{}: something is drawn", panel.title);
            if panel.y_label.contains("probability") {
                assert_eq!(g.y, (0.0, 100.0), "{}", panel.title);
            }
        }
        // The rendered pixels: every pixel of a series colour lies in a plot area or a legend
        // column (catches spikes of line joins and anything else drawn outside).
        let mut buf = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
        let rects = render(
            BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area(),
            fig,
        )
        .unwrap();
        // (The greys of the human and measured lines also occur in anti-aliased text.)
        let colours: Vec<RGBColor> = [MS, NM, PD_C].into_iter().chain(SCEN).collect();
        // A line on the border may overhang by half its width (4 px lines).
        const PEN: i32 = 2;
        let mut seen = 0;
        for (i, px) in buf.chunks(3).enumerate() {
            if !colours.iter().any(|c| px == [c.0, c.1, c.2]) {
                continue;
            }
            seen += 1;
            let (x, y) = ((i as u32 % SIZE.0) as i32, (i as u32 / SIZE.0) as i32);
            assert!(
                rects
                    .iter()
                    .any(|r| x >= r.0 - PEN && x <= r.2 + PEN && y >= r.1 - PEN && y <= r.3 + PEN),
                "{}: series pixel at ({x}, {y}) outside every panel",
                fig.title
            );
        }
        assert!(seen > 1000, "{}: series drawn", fig.title);
    }

    #[test]
    fn no_series_leaves_its_panel() {
        ensure_font().unwrap();
        let run = chattering_run();
        let runs = [chattering_run(), {
            let mut r = chattering_run();
            r.controller = "nmpc".into();
            r
        }];
        let mut rows = vec![run.summary.clone().unwrap()];
        rows[0].mean_probability = Some(vec![0.5, 1.0 + 1e-12, -1e-12]);
        rows[0].rms_force_n.thigh = Some(3.0);
        rows[0].rms_force_n.shank = Some(f64::NAN);
        let mut r2 = rows[0].clone();
        r2.payload_kg = 0.0;
        r2.rms_force_n.shank = Some(4.0);
        rows.push(r2);
        for fig in [
            states_figure(&run),
            interaction_figure(&run),
            compare_figure(&runs, 2.0),
            step_time_figure(&runs, 2.0),
            payload_figure(&rows),
        ] {
            assert_inside(&fig);
        }
    }

    #[test]
    fn clipping_cuts_at_the_border() {
        let b = ((0.0, 10.0), (0.0, 1.0));
        // Up through the top and back: two pieces meeting the border at y = 1.
        let p = clip_polyline(&[(0.0, 0.5), (2.0, 1.5), (4.0, 0.5)], b.0, b.1);
        assert_eq!(
            p,
            vec![vec![(0.0, 0.5), (1.0, 1.0)], vec![(3.0, 1.0), (4.0, 0.5)]]
        );
        // Entirely outside: nothing drawn (and so no legend entry).
        assert!(clip_polyline(&[(0.0, 5.0), (1.0, 6.0)], b.0, b.1).is_empty());
        // A NaN breaks the line.
        let p = clip_polyline(
            &[(0.0, 0.2), (1.0, f64::NAN), (2.0, 0.3), (3.0, 0.4)],
            b.0,
            b.1,
        );
        assert_eq!(p, vec![vec![(0.0, 0.2)], vec![(2.0, 0.3), (3.0, 0.4)]]);
    }

    #[test]
    fn tick_labels_have_no_needless_decimals() {
        assert_eq!(tick_label(40.0), "40");
        assert_eq!(tick_label(2.5), "2.5");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(-0.0), "0");
        assert_eq!(tick_label(-3.0), "-3");
        assert_eq!(tick_label(1e-5), "1.0e-5");
    }
}
