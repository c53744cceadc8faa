//! Line plots for studies and benchmarks: takes named series of (x, y) points, gives the same
//! chart as PNG and SVG (plotters), sized to stay readable in a paper column (text of 20-28 px on
//! a 1000 x 600 image: about 7 pt at 3.5 in wide). Logarithmic axes are real log scales with
//! ticks at decades labelled as numbers are written (`0.1`, `1`, `10`; `1e-6` outside 1e-3 to
//! 1e4); series take the Okabe-Ito colour-blind-safe palette (its yellow left out: too faint on
//! white; dashed once it repeats) with alternating marker shapes, or, when they are ordered
//! values of one parameter, a sequential map (plasma) with one colour each. Reference curves
//! are drawn first as a wide grey band, so that series that follow them stay visible on top.
//! The legend sits beside the plot, never over the data, and draws each entry as the plot does.

use std::path::Path;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::model::{CableId, Model};
use crate::solve::modes::Mode;
use crate::state::{retract, State};

/// One named series.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Points (x, y) in data units.
    pub points: Vec<(f64, f64)>,
    /// Draw markers as well as the line.
    pub markers: bool,
    /// A reference to compare the others with (e.g. the quasi-static path): black, dashed,
    /// drawn on top.
    pub reference: bool,
}

impl Series {
    /// A plain series.
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>, markers: bool) -> Self {
        Self { name: name.into(), points, markers, reference: false }
    }
}

/// A chart description.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Title.
    pub title: String,
    /// X axis label (units included).
    pub x_label: String,
    /// Y axis label (units included).
    pub y_label: String,
    /// Logarithmic x axis (points with x <= 0 are left out).
    pub log_x: bool,
    /// Logarithmic y axis (points with y <= 0 are left out).
    pub log_y: bool,
    /// Data.
    pub series: Vec<Series>,
    /// Optional horizontal reference line (y in data units) with its label (drawn dashed).
    pub reference: Option<(f64, String)>,
    /// The series are ordered values of one parameter (e.g. actuation times, in order): each
    /// gets its own colour from a sequential map instead of the categorical palette.
    pub ordered: bool,
}

/// Okabe & Ito (2008) colours without the yellow: blue, vermillion, bluish green, reddish
/// purple, orange, sky blue.
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
];

/// Plasma (van der Walt and Smith, matplotlib) at nine evenly spaced points, for ordered
/// series: its hue turns from blue through purple and red to orange, so neighbouring series stay
/// apart (viridis spent its last third on greens that looked alike).
const PLASMA: [(f64, f64, f64); 9] = [
    (13.0, 8.0, 135.0),
    (76.0, 2.0, 161.0),
    (126.0, 3.0, 168.0),
    (169.0, 35.0, 149.0),
    (204.0, 71.0, 120.0),
    (230.0, 108.0, 92.0),
    (248.0, 149.0, 64.0),
    (253.0, 197.0, 39.0),
    (240.0, 249.0, 33.0),
];

/// Colour `i` of `n` ordered series: plasma from dark blue to orange, its pale yellow end left
/// out (too faint on white).
fn sequential_colour(i: usize, n: usize) -> RGBColor {
    let t = if n <= 1 { 0.0 } else { 0.8 * i as f64 / (n - 1) as f64 };
    let x = t * (PLASMA.len() - 1) as f64;
    let k = (x.floor() as usize).min(PLASMA.len() - 2);
    let f = x - k as f64;
    let (a, b) = (PLASMA[k], PLASMA[k + 1]);
    let mix = |p: f64, q: f64| (p + f * (q - p)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Text sizes, px: title, axis names, tick labels, legend.
const TITLE_FONT: u32 = 28;
const AXIS_FONT: u32 = 24;
const TICK_FONT: u32 = 22;
const LEGEND_FONT: u32 = 21;
/// Size of a line chart, px (the legend takes its right part).
const CHART_SIZE: (u32, u32) = (1000, 600);
/// Grey of reference bands and of the reference configuration in structure drawings.
const REFERENCE_GREY: RGBColor = RGBColor(175, 175, 175);

/// A tick label: on log axes the decade as a number is written (`0.001` to `1000` plainly,
/// `1e-6`, `2.5e4` outside: `crate::error::readable_number`); up to 6 significant digits on
/// linear ones.
fn tick_label(v: f64, log: bool) -> String {
    if log {
        if !(v > 0.0 && v.is_finite()) {
            return format!("{v}");
        }
        // 9.999999999999999e-5 is 1e-4: round the mantissa, then carry
        let mut e = (v.log10() + 1e-9).floor();
        let mut m = ((v / 10f64.powf(e)) * 1e3).round() / 1e3;
        if m >= 10.0 {
            m /= 10.0;
            e += 1.0;
        }
        if (-3.0..4.0).contains(&e) {
            // the value as written, without the rounding noise of m 10^e
            let digits = (3.0 - e).max(0.0) as usize;
            let text = format!("{:.*}", digits, m * 10f64.powf(e));
            let text =
                if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.') } else { &text };
            text.to_string()
        } else if m == 1.0 {
            format!("1e{e}")
        } else {
            format!("{m}e{e}")
        }
    } else {
        let r = if v == 0.0 { 0.0 } else { format!("{v:.6e}").parse().unwrap_or(v) };
        format!("{}", r + 0.0)
    }
}

/// Data bounds of the drawable points, padded: 5 % on linear axes, a fifth of a decade on
/// log ones.
fn bounds(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && (!log || *v > 0.0))
        .fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
    if lo > hi {
        return if log { (0.1, 10.0) } else { (0.0, 1.0) };
    }
    if log {
        let (a, b) = if hi > lo { (lo, hi) } else { (lo / 10.0, hi * 10.0) };
        (a / 10f64.powf(0.2), b * 10f64.powf(0.2))
    } else {
        let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 * lo.abs().max(1.0) };
        (lo - pad, hi + pad)
    }
}

/// How a legend entry is drawn: as its series is in the plot.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Glyph {
    /// A solid line of this colour (with a marker: circle when the flag is set, else triangle).
    Line(RGBColor, Option<bool>),
    /// A dashed line of this colour (same markers).
    Dashed(RGBColor, Option<bool>),
    /// A reference series: a wide grey band.
    Band,
    /// The horizontal reference line: thin, black, dashed.
    ReferenceLine,
}

/// The colour of non-reference series `i` of `n`, whether it is dashed (the categorical palette
/// repeating), and whether its markers are circles (else triangles, alternating): one rule for
/// the plot and its legend.
fn series_style(chart: &Chart, i: usize, n: usize) -> (RGBColor, bool, bool) {
    let round = i % 2 == 0;
    if chart.ordered {
        (sequential_colour(i, n), false, round)
    } else {
        (PALETTE[i % PALETTE.len()], (i / PALETTE.len()) % 2 == 1, round)
    }
}

/// The legend, in drawing order: references, series, the horizontal reference line.
fn legend_entries(chart: &Chart) -> Vec<(String, Glyph)> {
    let mut out: Vec<(String, Glyph)> =
        chart.series.iter().filter(|s| s.reference).map(|s| (s.name.clone(), Glyph::Band)).collect();
    let n = chart.series.iter().filter(|s| !s.reference).count();
    for (i, s) in chart.series.iter().filter(|s| !s.reference).enumerate() {
        let (color, dashed, round) = series_style(chart, i, n);
        let marker = s.markers.then_some(round);
        out.push((
            s.name.clone(),
            if dashed { Glyph::Dashed(color, marker) } else { Glyph::Line(color, marker) },
        ));
    }
    if let Some((_, name)) = &chart.reference {
        out.push((name.clone(), Glyph::ReferenceLine));
    }
    out
}

/// Width of the legend column, px: room for the longest entry.
fn legend_width(entries: &[(String, Glyph)]) -> u32 {
    let chars = entries.iter().map(|(n, _)| n.chars().count()).max().unwrap_or(0) as f64;
    (chars * 0.47 * LEGEND_FONT as f64 + 75.0).clamp(150.0, 400.0) as u32
}

fn render<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(&chart.title, ("sans-serif", TITLE_FONT)).map_err(err)?;
    let entries = legend_entries(chart);
    let (width, _) = root.dim_in_pixel();
    let (plot_area, legend_area) = root.split_horizontally(width.saturating_sub(legend_width(&entries)));
    let xs = chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let ys = chart
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .chain(chart.reference.iter().map(|r| r.0));
    let (x0, x1) = bounds(xs, chart.log_x);
    let (y0, y1) = bounds(ys, chart.log_y);
    match (chart.log_x, chart.log_y) {
        (false, false) => draw(&plot_area, chart, x0..x1, y0..y1)?,
        (true, false) => draw(&plot_area, chart, (x0..x1).log_scale(), y0..y1)?,
        (false, true) => draw(&plot_area, chart, x0..x1, (y0..y1).log_scale())?,
        (true, true) => draw(&plot_area, chart, (x0..x1).log_scale(), (y0..y1).log_scale())?,
    }
    draw_legend(&legend_area, &entries).map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// The legend column: one row per entry, its glyph then its name.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, Glyph)],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let row = LEGEND_FONT as i32 + 14;
    for (k, (name, glyph)) in entries.iter().enumerate() {
        let y = 60 + k as i32 * row;
        let (x0, x1) = (8, 52);
        match *glyph {
            Glyph::Line(color, marker) | Glyph::Dashed(color, marker) => {
                let style = color.stroke_width(3);
                if matches!(glyph, Glyph::Line(..)) {
                    area.draw(&PathElement::new(vec![(x0, y), (x1, y)], style))?;
                } else {
                    area.draw(&PathElement::new(vec![(x0, y), (x0 + 16, y)], style))?;
                    area.draw(&PathElement::new(vec![(x0 + 26, y), (x1, y)], style))?;
                }
                match marker {
                    Some(true) => area.draw(&Circle::new((30, y), 5, color.filled()))?,
                    Some(false) => area.draw(&TriangleMarker::new((30, y), 6, color.filled()))?,
                    None => {}
                }
            }
            Glyph::Band => {
                area.draw(&PathElement::new(vec![(x0, y), (x1, y)], REFERENCE_GREY.stroke_width(8)))?
            }
            Glyph::ReferenceLine => {
                for x in (x0..x1).step_by(12) {
                    area.draw(&PathElement::new(vec![(x, y), ((x + 7).min(x1), y)], BLACK.stroke_width(2)))?;
                }
            }
        }
        let style =
            ("sans-serif", LEGEND_FONT).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
        area.draw(&Text::new(name.clone(), (x1 + 10, y), style))?;
    }
    Ok(())
}

fn draw<DB, X, Y>(root: &DrawingArea<DB, Shift>, chart: &Chart, x: X, y: Y) -> Result<(), String>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let (log_x, log_y) = (chart.log_x, chart.log_y);
    let drawable =
        |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite() && (!log_x || p.0 > 0.0) && (!log_y || p.1 > 0.0);
    let mut c = ChartBuilder::on(root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(75)
        .y_label_area_size(105)
        .build_cartesian_2d(x, y)
        .map_err(err)?;
    let x_range = c.x_range();
    c.configure_mesh()
        .x_desc(chart.x_label.as_str())
        .y_desc(chart.y_label.as_str())
        .axis_desc_style(("sans-serif", AXIS_FONT))
        .label_style(("sans-serif", TICK_FONT))
        .x_label_formatter(&|v| tick_label(*v, log_x))
        .y_label_formatter(&|v| tick_label(*v, log_y))
        .draw()
        .map_err(err)?;
    // references first, as a wide grey band under the series that follow them
    for s in chart.series.iter().filter(|s| s.reference) {
        let data: Vec<(f64, f64)> = s.points.iter().copied().filter(drawable).collect();
        c.draw_series(LineSeries::new(data.clone(), REFERENCE_GREY.stroke_width(8))).map_err(err)?;
        if s.markers {
            c.draw_series(data.iter().map(|&p| Circle::new(p, 6, REFERENCE_GREY.filled()))).map_err(err)?;
        }
    }
    let n = chart.series.iter().filter(|s| !s.reference).count();
    for (i, s) in chart.series.iter().filter(|s| !s.reference).enumerate() {
        let (color, dashed, round) = series_style(chart, i, n);
        let data: Vec<(f64, f64)> = s.points.iter().copied().filter(drawable).collect();
        if dashed {
            c.draw_series(DashedLineSeries::new(data.clone(), 8, 6, color.stroke_width(3))).map_err(err)?;
        } else {
            c.draw_series(LineSeries::new(data.clone(), color.stroke_width(3))).map_err(err)?;
        }
        if s.markers {
            if round {
                c.draw_series(data.iter().map(|&p| Circle::new(p, 5, color.filled()))).map_err(err)?;
            } else {
                c.draw_series(data.iter().map(|&p| TriangleMarker::new(p, 6, color.filled())))
                    .map_err(err)?;
            }
        }
    }
    if let Some((y, _)) = &chart.reference {
        let line = [(x_range.start, *y), (x_range.end, *y)];
        c.draw_series(DashedLineSeries::new(line, 7, 5, BLACK.stroke_width(2))).map_err(err)?;
    }
    Ok(())
}

/// Writes `chart` to `base.png` and `base.svg` (1000 x 600 px, the legend at the right).
pub fn write(chart: &Chart, base: &Path) -> Result<(), String> {
    let png = base.with_extension("png");
    let svg = base.with_extension("svg");
    render(BitMapBackend::new(&png, CHART_SIZE).into_drawing_area(), chart)
        .map_err(|e| format!("{}: {e}", png.display()))?;
    render(SVGBackend::new(&svg, CHART_SIZE).into_drawing_area(), chart)
        .map_err(|e| format!("{}: {e}", svg.display()))?;
    Ok(())
}

/// A straight segment of a structure drawing, in plot coordinates (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Start point.
    pub from: (f64, f64),
    /// End point.
    pub to: (f64, f64),
    /// A strut (drawn thick) rather than a cable (thin).
    pub strut: bool,
}

/// A point drawn on a structure: a point mass (filled dot) or a pulley (open circle), in plot
/// coordinates (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mark {
    /// A point-mass body.
    Mass((f64, f64)),
    /// A pulley: an interior point of a cable's route.
    Pulley((f64, f64)),
}

/// One panel of a structure drawing: a reference configuration drawn grey and a displaced one
/// drawn in colour on top, with axes in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct StructurePanel {
    /// Panel title.
    pub title: String,
    /// The reference configuration (e.g. the equilibrium).
    pub reference: Vec<Segment>,
    /// The displaced configuration (e.g. a mode shape at a visible amplitude).
    pub displaced: Vec<Segment>,
    /// Point masses and pulleys of the reference configuration.
    pub reference_marks: Vec<Mark>,
    /// The same of the displaced configuration.
    pub displaced_marks: Vec<Mark>,
    /// Names of the horizontal and vertical axes (units included).
    pub axes: (String, String),
    /// The largest displacement of a point drawn, m (the drawing's exaggeration).
    pub largest_displacement: f64,
}

/// Side of one panel of a structure drawing, px.
const PANEL_SIZE: usize = 520;

/// Writes `panels` side by side (at most 3 per row, equal scales on both axes and in every
/// panel, axes in metres) to `base.png` and `base.svg`, with `title` above them.
pub fn write_structure_panels(title: &str, panels: &[StructurePanel], base: &Path) -> Result<(), String> {
    let cols = panels.len().clamp(1, 3);
    let rows = panels.len().div_ceil(cols).max(1);
    let size = ((PANEL_SIZE * cols) as u32, (PANEL_SIZE * rows + 50) as u32);
    let png = base.with_extension("png");
    let svg = base.with_extension("svg");
    render_panels(BitMapBackend::new(&png, size).into_drawing_area(), title, panels, (rows, cols))
        .map_err(|e| format!("{}: {e}", png.display()))?;
    render_panels(SVGBackend::new(&svg, size).into_drawing_area(), title, panels, (rows, cols))
        .map_err(|e| format!("{}: {e}", svg.display()))?;
    Ok(())
}

fn render_panels<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    panels: &[StructurePanel],
    (rows, cols): (usize, usize),
) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, ("sans-serif", 24)).map_err(err)?;
    // one square window for all panels, so that shapes compare
    let marks = |m: &Mark| match *m {
        Mark::Mass(p) | Mark::Pulley(p) => p,
    };
    let all = panels.iter().flat_map(|p| {
        p.reference
            .iter()
            .chain(&p.displaced)
            .flat_map(|s| [s.from, s.to])
            .chain(p.reference_marks.iter().chain(&p.displaced_marks).map(marks))
    });
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in all.filter(|p| p.0.is_finite() && p.1.is_finite()) {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (-1.0, 1.0, -1.0, 1.0);
    }
    let half = 0.55 * (x1 - x0).max(y1 - y0).max(1e-9);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let areas = root.split_evenly((rows, cols));
    for (area, panel) in areas.iter().zip(panels) {
        let mut c = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(50)
            .y_label_area_size(65)
            .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)
            .map_err(err)?;
        c.configure_mesh()
            .x_desc(panel.axes.0.as_str())
            .y_desc(panel.axes.1.as_str())
            .axis_desc_style(("sans-serif", 16))
            .label_style(("sans-serif", 15))
            .x_labels(5)
            .y_labels(5)
            .x_label_formatter(&|v| tick_label(*v, false))
            .y_label_formatter(&|v| tick_label(*v, false))
            .light_line_style(WHITE)
            .draw()
            .map_err(err)?;
        let configurations = [
            (&panel.reference, &panel.reference_marks, REFERENCE_GREY),
            (&panel.displaced, &panel.displaced_marks, PALETTE[0]),
        ];
        for (segments, points, color) in configurations {
            c.draw_series(segments.iter().map(|s| {
                PathElement::new(vec![s.from, s.to], color.stroke_width(if s.strut { 4 } else { 1 }))
            }))
            .map_err(err)?;
            c.draw_series(points.iter().map(|m| match *m {
                Mark::Mass(p) => Circle::new(p, 6, color.filled()),
                Mark::Pulley(p) => Circle::new(p, 5, color.stroke_width(2)),
            }))
            .map_err(err)?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Drawing panels of the first `count` vibrating (non-zero) modes of `modes` at `state`: the
/// equilibrium in grey and the structure displaced along the mode in colour, at the amplitude
/// that moves its farthest point by `MODE_DRAWING_AMPLITUDE` of the structure's size (recorded
/// in `StructurePanel::largest_displacement`). Bars are drawn between their ends, rigid bodies
/// from their centre to each point, cables along their routes, point masses as dots and pulleys
/// (interior route points) as circles; a planar scene is drawn in its xy plane, a spatial one in
/// isometric projection (`x' = (x - y) cos 30deg`, `y' = z + (x + y) sin 30deg`), axes in metres.
pub fn mode_panels(model: &Model, state: &State, modes: &[Mode], count: usize) -> Vec<StructurePanel> {
    use crate::model::BodyKind;
    let project = |p: nalgebra::Vector3<f64>| {
        if model.planar {
            (p.x, p.y)
        } else {
            let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
            ((p.x - p.y) * c, p.z + (p.x + p.y) * s)
        }
    };
    let positions = |poses: &[crate::model::Pose]| -> Vec<nalgebra::Vector3<f64>> {
        model.points.iter().map(|p| poses[p.body.0].transform_point(&p.local)).collect()
    };
    let segments = |poses: &[crate::model::Pose]| -> Vec<Segment> {
        let at = positions(poses);
        let mut out = Vec::new();
        for (b, body) in model.bodies.iter().enumerate() {
            let own: Vec<usize> = (0..model.points.len()).filter(|&p| model.points[p].body.0 == b).collect();
            match body.kind {
                BodyKind::Bar => {
                    let end =
                        |suffix: &str| own.iter().copied().find(|&p| model.points[p].name.ends_with(suffix));
                    if let (Some(a), Some(e)) = (end(".a"), end(".b")) {
                        out.push(Segment { from: project(at[a]), to: project(at[e]), strut: true });
                    }
                }
                BodyKind::Rigid => {
                    let centre = project(poses[b].position);
                    for &p in &own {
                        out.push(Segment { from: centre, to: project(at[p]), strut: true });
                    }
                }
                BodyKind::Node | BodyKind::Fixed => {}
            }
        }
        for c in 0..model.cables.len() {
            for w in model.route(CableId(c)).windows(2) {
                out.push(Segment { from: project(at[w[0].0]), to: project(at[w[1].0]), strut: false });
            }
        }
        out
    };
    let marks = |poses: &[crate::model::Pose]| -> Vec<Mark> {
        let at = positions(poses);
        let mut out: Vec<Mark> = (0..model.points.len())
            .filter(|&p| model.bodies[model.points[p].body.0].kind == BodyKind::Node)
            .map(|p| Mark::Mass(project(at[p])))
            .collect();
        for c in 0..model.cables.len() {
            let route = model.route(CableId(c));
            for p in &route[1..route.len().saturating_sub(1)] {
                out.push(Mark::Pulley(project(at[p.0])));
            }
        }
        out
    };
    let axes = if model.planar {
        ("x (m)".to_string(), "y (m)".to_string())
    } else {
        ("(x - y) cos 30° (m)".to_string(), "z + (x + y) sin 30° (m)".to_string())
    };
    let reference = segments(&state.poses);
    let reference_marks = marks(&state.poses);
    let rest = positions(&state.poses);
    let size = crate::solve::statics::body_size(model)
        .max(rest.iter().flat_map(|a| rest.iter().map(move |b| (a - b).norm())).fold(0.0, f64::max));
    modes
        .iter()
        .enumerate()
        .filter(|(_, m)| !m.zero)
        .take(count)
        .map(|(i, m)| {
            // unit amplitude moves points by `reach`: scale to the drawing amplitude
            let mut unit = state.poses.clone();
            retract(model, &mut unit, &m.shape, 1e-6);
            let reach =
                positions(&unit).iter().zip(&rest).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max) / 1e-6;
            let mut moved = state.poses.clone();
            retract(model, &mut moved, &m.shape, MODE_DRAWING_AMPLITUDE * size / reach.max(1e-300));
            StructurePanel {
                title: if m.omega_squared < 0.0 {
                    format!("mode {}: unstable (omega^2 = {:.3e} 1/s^2)", i + 1, m.omega_squared)
                } else {
                    format!("mode {}: {:.4} Hz", i + 1, m.frequency_hz)
                },
                reference: reference.clone(),
                displaced: segments(&moved),
                reference_marks: reference_marks.clone(),
                displaced_marks: marks(&moved),
                axes: axes.clone(),
                largest_displacement: MODE_DRAWING_AMPLITUDE * size,
            }
        })
        .collect()
}

/// The largest point displacement of a drawn mode shape, as a fraction of the structure's size.
pub const MODE_DRAWING_AMPLITUDE: f64 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordered_series_get_distinct_colours_and_the_legend_draws_each_entry_as_the_plot() {
        let mut series: Vec<Series> = (0..8)
            .map(|k| Series::new(format!("T = {k} s"), vec![(0.0, k as f64), (1.0, 1.0)], false))
            .collect();
        series.insert(
            0,
            Series { reference: true, ..Series::new("quasi-static", vec![(0.0, 0.0), (1.0, 1.0)], false) },
        );
        let chart = Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            log_x: false,
            log_y: false,
            series,
            reference: Some((1.0, "1 %".into())),
            ordered: true,
        };
        let legend = legend_entries(&chart);
        assert_eq!(legend.len(), 10);
        assert_eq!(
            legend[0],
            ("quasi-static".to_string(), Glyph::Band),
            "the reference as the grey band it is drawn as"
        );
        assert_eq!(legend[9], ("1 %".to_string(), Glyph::ReferenceLine), "the 1 % line dashed, as drawn");
        let colours: Vec<RGBColor> = legend[1..9]
            .iter()
            .map(|(_, g)| match g {
                Glyph::Line(c, None) => *c,
                other => panic!("ordered series are solid lines: {other:?}"),
            })
            .collect();
        for (i, a) in colours.iter().enumerate() {
            assert!(colours[i + 1..].iter().all(|b| b != a), "8 ordered series, 8 colours: {colours:?}");
        }
        // the categorical palette repeats dashed past its length
        let chart = Chart { ordered: false, ..chart };
        let legend = legend_entries(&chart);
        assert!(matches!(legend[7].1, Glyph::Dashed(c, None) if c == PALETTE[0]));
    }

    #[test]
    fn charts_are_written_with_text_a_paper_column_can_read() {
        let dir = std::env::temp_dir().join(format!("tensegrity-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let chart = Chart {
            title: "work-precision".into(),
            x_label: "wall time (s)".into(),
            y_label: "max point error (m)".into(),
            log_x: true,
            log_y: true,
            series: vec![Series::new("generalized-alpha", vec![(1e-3, 1e-2), (1e-1, 1e-6)], true)],
            reference: None,
            ordered: false,
        };
        write(&chart, &dir.join("chart")).unwrap();
        let svg = std::fs::read_to_string(dir.join("chart.svg")).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        let sizes: Vec<f64> = svg
            .split("font-size=\"")
            .skip(1)
            .filter_map(|rest| rest.split('"').next()?.parse().ok())
            .collect();
        assert!(!sizes.is_empty());
        // plotters writes px * 0.8 (points); 20 px and more everywhere
        assert!(sizes.iter().all(|&s| s >= 16.0), "font sizes {sizes:?}");
        // decades read as numbers
        let texts: Vec<&str> = svg
            .split("<text")
            .skip(1)
            .filter_map(|t| t.split('>').nth(1)?.split('<').next())
            .map(str::trim)
            .collect();
        assert!(
            texts.contains(&"0.01") && texts.contains(&"0.1") && texts.contains(&"1e-6"),
            "tick labels {texts:?}"
        );
    }

    #[test]
    fn tick_labels_read_as_numbers() {
        assert_eq!(tick_label(1e-3, true), "0.001");
        assert_eq!(tick_label(1.0000000000000002e-3, true), "0.001");
        assert_eq!(tick_label(0.1, true), "0.1");
        assert_eq!(tick_label(1.0, true), "1");
        assert_eq!(tick_label(10.0, true), "10");
        assert_eq!(tick_label(0.25, true), "0.25");
        assert_eq!(tick_label(1000.0, true), "1000");
        assert_eq!(tick_label(2.5e4, true), "2.5e4");
        assert_eq!(tick_label(9.999999999999999e-5, true), "1e-4");
        assert_eq!(tick_label(1e-6, true), "1e-6");
        assert_eq!(tick_label(0.30000000000000004, false), "0.3");
        assert_eq!(tick_label(-0.0, false), "0");
        assert_eq!(tick_label(1500.0, false), "1500");
    }
}
