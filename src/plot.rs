//! Line plots for studies and benchmarks: takes named series of (x, y) points, gives the same
//! chart as PNG and SVG (plotters). Log axes are drawn as log10 of the value, labelled so.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

/// One named series.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Points (x, y) in data units.
    pub points: Vec<(f64, f64)>,
    /// Draw markers as well as the line.
    pub markers: bool,
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
    /// Plot log10(x).
    pub log_x: bool,
    /// Plot log10(y).
    pub log_y: bool,
    /// Data.
    pub series: Vec<Series>,
    /// Optional horizontal reference line (y in data units) with its label.
    pub reference: Option<(f64, String)>,
}

fn tr(v: f64, log: bool) -> f64 {
    if log {
        v.max(1e-300).log10()
    } else {
        v
    }
}

fn render<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let pts: Vec<(f64, f64)> = chart
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|&(x, y)| (tr(x, chart.log_x), tr(y, chart.log_y))))
        .chain(chart.reference.iter().map(|(y, _)| (f64::NAN, tr(*y, chart.log_y))))
        .collect();
    let finite = |v: f64| v.is_finite();
    let (mut x0, mut x1) = pts
        .iter()
        .map(|p| p.0)
        .filter(|v| finite(*v))
        .fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
    let (mut y0, mut y1) = pts
        .iter()
        .map(|p| p.1)
        .filter(|v| finite(*v))
        .fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    if y0 > y1 {
        (y0, y1) = (0.0, 1.0);
    }
    let pad = |a: f64, b: f64| if b - a > 0.0 { 0.05 * (b - a) } else { 0.5 * a.abs().max(1.0) };
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    let label = |s: &str, log: bool| if log { format!("log10 {s}") } else { s.to_string() };
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d((x0 - px)..(x1 + px), (y0 - py)..(y1 + py))
        .map_err(err)?;
    c.configure_mesh()
        .x_desc(label(&chart.x_label, chart.log_x))
        .y_desc(label(&chart.y_label, chart.log_y))
        .draw()
        .map_err(err)?;
    if let Some((y, name)) = &chart.reference {
        let y = tr(*y, chart.log_y);
        c.draw_series(LineSeries::new([(x0 - px, y), (x1 + px, y)], BLACK.stroke_width(1)))
            .map_err(err)?
            .label(name.clone())
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
    }
    for (i, s) in chart.series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let data: Vec<(f64, f64)> =
            s.points.iter().map(|&(x, y)| (tr(x, chart.log_x), tr(y, chart.log_y))).collect();
        c.draw_series(LineSeries::new(data.clone(), color.stroke_width(2)))
            .map_err(err)?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        if s.markers {
            c.draw_series(data.iter().map(|&p| Circle::new(p, 4, color.filled()))).map_err(err)?;
        }
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
