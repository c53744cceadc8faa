//! Line plots for studies and benchmarks: takes named series of (x, y) points, gives the same
//! chart as PNG and SVG (plotters). Logarithmic axes are real log scales with ticks at decades
//! labelled in data units (`1e-3`); series take the Okabe-Ito colour-blind-safe palette (its
//! yellow left out: too faint on white; dashed once it repeats) with alternating marker shapes, and
//! reference curves are drawn last, black and dashed, so that nothing hides them.

use std::path::Path;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

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
    /// Optional horizontal reference line (y in data units) with its label.
    pub reference: Option<(f64, String)>,
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

/// A tick label: `1e-3`, `2.5e4` on log axes; up to 6 significant digits on linear ones.
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
        if m == 1.0 {
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

fn render<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let xs = chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let ys = chart
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .chain(chart.reference.iter().map(|r| r.0));
    let (x0, x1) = bounds(xs, chart.log_x);
    let (y0, y1) = bounds(ys, chart.log_y);
    match (chart.log_x, chart.log_y) {
        (false, false) => draw(root, chart, x0..x1, y0..y1),
        (true, false) => draw(root, chart, (x0..x1).log_scale(), y0..y1),
        (false, true) => draw(root, chart, x0..x1, (y0..y1).log_scale()),
        (true, true) => draw(root, chart, (x0..x1).log_scale(), (y0..y1).log_scale()),
    }
}

fn draw<DB, X, Y>(root: DrawingArea<DB, Shift>, chart: &Chart, x: X, y: Y) -> Result<(), String>
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
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d(x, y)
        .map_err(err)?;
    let x_range = c.x_range();
    c.configure_mesh()
        .x_desc(chart.x_label.as_str())
        .y_desc(chart.y_label.as_str())
        .x_label_formatter(&|v| tick_label(*v, log_x))
        .y_label_formatter(&|v| tick_label(*v, log_y))
        .draw()
        .map_err(err)?;
    for (i, s) in chart.series.iter().filter(|s| !s.reference).enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let data: Vec<(f64, f64)> = s.points.iter().copied().filter(drawable).collect();
        // past the palette's length the colours repeat with dashed lines
        if (i / PALETTE.len()) % 2 == 0 {
            c.draw_series(LineSeries::new(data.clone(), color.stroke_width(2)))
                .map_err(err)?
                .label(s.name.clone())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        } else {
            c.draw_series(DashedLineSeries::new(data.clone(), 6, 4, color.stroke_width(2)))
                .map_err(err)?
                .label(s.name.clone())
                .legend(move |(x, y)| {
                    EmptyElement::at((x, y))
                        + PathElement::new([(0, 0), (7, 0)], color.stroke_width(2))
                        + PathElement::new([(12, 0), (20, 0)], color.stroke_width(2))
                });
        }
        if s.markers {
            if i % 2 == 0 {
                c.draw_series(data.iter().map(|&p| Circle::new(p, 4, color.filled()))).map_err(err)?;
            } else {
                c.draw_series(data.iter().map(|&p| TriangleMarker::new(p, 5, color.filled())))
                    .map_err(err)?;
            }
        }
    }
    // references on top
    for s in chart.series.iter().filter(|s| s.reference) {
        let data: Vec<(f64, f64)> = s.points.iter().copied().filter(drawable).collect();
        c.draw_series(DashedLineSeries::new(data.clone(), 8, 5, BLACK.stroke_width(3)))
            .map_err(err)?
            .label(s.name.clone())
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(3)));
        if s.markers {
            c.draw_series(data.iter().map(|&p| Circle::new(p, 4, BLACK.filled()))).map_err(err)?;
        }
    }
    if let Some((y, name)) = &chart.reference {
        let line = [(x_range.start, *y), (x_range.end, *y)];
        c.draw_series(DashedLineSeries::new(line, 6, 6, BLACK.stroke_width(1)))
            .map_err(err)?
            .label(name.clone())
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
    }
    c.configure_series_labels().background_style(WHITE.mix(0.85)).border_style(BLACK).draw().map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Writes `chart` to `base.png` and `base.svg` (900 x 600 px).
pub fn write(chart: &Chart, base: &Path) -> Result<(), String> {
    let png = base.with_extension("png");
    let svg = base.with_extension("svg");
    render(BitMapBackend::new(&png, (900, 600)).into_drawing_area(), chart)
        .map_err(|e| format!("{}: {e}", png.display()))?;
    render(SVGBackend::new(&svg, (900, 600)).into_drawing_area(), chart)
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

/// One panel of a structure drawing: a reference configuration drawn grey and a displaced one
/// drawn in colour on top.
#[derive(Debug, Clone, PartialEq)]
pub struct StructurePanel {
    /// Panel title.
    pub title: String,
    /// The reference configuration (e.g. the equilibrium).
    pub reference: Vec<Segment>,
    /// The displaced configuration (e.g. a mode shape at a visible amplitude).
    pub displaced: Vec<Segment>,
}

/// Writes `panels` side by side (at most 3 per row, equal scales on both axes and in every
/// panel) to `base.png` and `base.svg`, with `title` above them.
pub fn write_structure_panels(title: &str, panels: &[StructurePanel], base: &Path) -> Result<(), String> {
    let cols = panels.len().clamp(1, 3);
    let rows = panels.len().div_ceil(cols).max(1);
    let size = ((400 * cols) as u32, (400 * rows + 40) as u32);
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
    let root = root.titled(title, ("sans-serif", 22)).map_err(err)?;
    // one square window for all panels, so that shapes compare
    let all = panels.iter().flat_map(|p| p.reference.iter().chain(&p.displaced)).flat_map(|s| [s.from, s.to]);
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
            .caption(&panel.title, ("sans-serif", 16))
            .margin(8)
            .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)
            .map_err(err)?;
        let grey = RGBColor(170, 170, 170);
        for (segments, color) in [(&panel.reference, grey), (&panel.displaced, PALETTE[0])] {
            c.draw_series(segments.iter().map(|s| {
                PathElement::new(vec![s.from, s.to], color.stroke_width(if s.strut { 4 } else { 1 }))
            }))
            .map_err(err)?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Drawing panels of the first `count` vibrating (non-zero) modes of `modes` at `state`: the
/// equilibrium in grey and the structure displaced along the mode in colour, at the amplitude
/// that moves its farthest point by `MODE_DRAWING_AMPLITUDE` of the structure's size. Bars are
/// drawn between their ends, rigid bodies from their centre to each point, cables along their
/// routes; a planar scene is drawn in its xy plane, a spatial one in isometric projection
/// (`x' = (x - y) cos 30deg`, `y' = z + (x + y) sin 30deg`).
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
    let reference = segments(&state.poses);
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
            }
        })
        .collect()
}

/// The largest point displacement of a drawn mode shape, as a fraction of the structure's size.
pub const MODE_DRAWING_AMPLITUDE: f64 = 0.1;

#[cfg(test)]
mod tests {
    use super::tick_label;

    #[test]
    fn tick_labels_read_as_numbers() {
        assert_eq!(tick_label(1e-3, true), "1e-3");
        assert_eq!(tick_label(1.0000000000000002e-3, true), "1e-3");
        assert_eq!(tick_label(2.5e4, true), "2.5e4");
        assert_eq!(tick_label(9.999999999999999e-5, true), "1e-4");
        assert_eq!(tick_label(1e-6, true), "1e-6");
        assert_eq!(tick_label(0.30000000000000004, false), "0.3");
        assert_eq!(tick_label(-0.0, false), "0");
        assert_eq!(tick_label(1500.0, false), "1500");
    }
}
