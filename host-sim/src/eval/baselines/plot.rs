//! SVG plots of the baselines (plotters' SVG backend, like [`crate::eval::render`]; `<text>` elements,
//! no system fonts): energy against time (dhiman-modern-map-inference-ogm Fig. 3), per-cell
//! marginals of the 1-D example (merali-barfoot-mcmc-gibbs-ogm Fig. 2) and summed KL against
//! iterations (its Fig. 3).

use std::path::Path;

use anyhow::{Context, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
pub use plotters::prelude::SeriesLabelPosition;
use plotters::prelude::*;

use crate::eval::render::{write_svg, PALETTE};

/// Size of the plots, in pixels.
pub const PLOT_SIZE: (u32, u32) = (900, 600);

/// One line of a plot.
pub struct Series<'a> {
    /// Legend entry.
    pub name: &'a str,
    /// Points.
    pub points: Vec<(f64, f64)>,
    /// Mark each point with a circle.
    pub markers: bool,
    /// Dashed (drawn as short segments) instead of solid.
    pub dashed: bool,
}

/// Draws `series` into an SVG string over the given axes.
#[allow(clippy::too_many_arguments)]
fn draw<X, Y>(
    title: &str,
    x_desc: &str,
    y_desc: &str,
    x: X,
    y: Y,
    series: &[Series],
    clamp: (f64, f64, f64, f64),
    legend_at: SeriesLabelPosition,
) -> Result<String>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let (x0, x1, y0, y1) = clamp;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 24))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(90)
            .build_cartesian_2d(x, y)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 18))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .filter(|(px, py)| px.is_finite() && py.is_finite() && *px >= x0 && *px <= x1)
                .map(|&(px, py)| (px, py.clamp(y0, y1)))
                .collect();
            let style = color.stroke_width(2);
            let anno = if s.dashed {
                // Three dashes per segment between consecutive points.
                let at = |a: (f64, f64), b: (f64, f64), t: f64| {
                    (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
                };
                let segs: Vec<_> = pts
                    .windows(2)
                    .flat_map(|w| {
                        let (a, b) = (w[0], w[1]);
                        [(0.0, 0.2), (0.4, 0.6), (0.8, 1.0)].map(|(t0, t1)| {
                            PathElement::new(vec![at(a, b, t0), at(a, b, t1)], style)
                        })
                    })
                    .collect();
                chart.draw_series(segs)?
            } else {
                chart.draw_series(LineSeries::new(pts.iter().copied(), style))?
            };
            anno.label(s.name).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
            if s.markers {
                chart.draw_series(
                    pts.iter()
                        .map(|&p| Circle::new(p, 4, color.filled()))
                        .collect::<Vec<_>>(),
                )?;
            }
        }
        if !series.is_empty() {
            chart
                .configure_series_labels()
                .position(legend_at)
                .label_font(("sans-serif", 15))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()?;
        }
        root.present()?;
    }
    Ok(svg)
}

/// Energy against wall-clock time (log time axis), one line per traced method and one marker per
/// `points` entry (methods without a trace, e.g. the samplers: their run time and final energy).
/// The energy axis spans the lowest energy to the highest final energy plus a margin; higher
/// trace values are drawn at the top edge.
pub fn energy_vs_time_svg(
    path: impl AsRef<Path>,
    title: &str,
    traces: &[(String, Vec<(f64, f64)>)],
    points: &[(String, f64, f64)],
) -> Result<()> {
    let path = path.as_ref();
    let all_t = traces
        .iter()
        .flat_map(|(_, t)| t.iter().map(|p| p.0))
        .chain(points.iter().map(|p| p.1));
    let t_max = all_t.fold(1e-3f64, f64::max) * 1.5;
    let t_min = 1e-3f64;
    let lo = traces
        .iter()
        .flat_map(|(_, t)| t.iter().map(|p| p.1))
        .chain(points.iter().map(|p| p.2))
        .filter(|e| e.is_finite())
        .fold(f64::INFINITY, f64::min);
    let finals = traces
        .iter()
        .filter_map(|(_, t)| t.last().map(|p| p.1))
        .chain(points.iter().map(|p| p.2))
        .filter(|e| e.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    let (lo, hi) = if lo.is_finite() && finals.is_finite() {
        let span = (finals - lo).max(1.0);
        (lo - 0.05 * span, finals + 0.6 * span)
    } else {
        (0.0, 1.0)
    };
    let mut series: Vec<Series> = traces
        .iter()
        .map(|(name, t)| Series {
            name,
            points: t.iter().map(|&(s, e)| (s.max(t_min), e)).collect(),
            markers: false,
            dashed: false,
        })
        .collect();
    for (name, s, e) in points {
        series.push(Series {
            name,
            points: vec![(s.max(t_min), *e)],
            markers: true,
            dashed: false,
        });
    }
    let svg = draw(
        title,
        "seconds (log scale)",
        "energy (nats)",
        (t_min..t_max).log_scale(),
        lo..hi,
        &series,
        (t_min, t_max, lo, hi),
        SeriesLabelPosition::UpperRight,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}

/// Per-cell occupancy probabilities against the cell index.
pub fn marginals_svg(
    path: impl AsRef<Path>,
    title: &str,
    x_range: (f64, f64),
    series: &[Series],
    legend_at: SeriesLabelPosition,
) -> Result<()> {
    let path = path.as_ref();
    let svg = draw(
        title,
        "cell k",
        "p(m_k = 1)",
        x_range.0..x_range.1,
        -0.02f64..1.02f64,
        series,
        (x_range.0, x_range.1, -0.02, 1.02),
        legend_at,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}

/// Summed KL divergence against sweeps, both axes logarithmic.
pub fn kl_vs_sweeps_svg(path: impl AsRef<Path>, title: &str, series: &[Series]) -> Result<()> {
    let path = path.as_ref();
    let pts = series.iter().flat_map(|s| s.points.iter());
    let (mut x1, mut y0, mut y1) = (10.0f64, f64::INFINITY, 0.0f64);
    for &(x, y) in pts {
        if x > 0.0 && y > 0.0 && y.is_finite() {
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    let (y0, y1) = if y0.is_finite() {
        (y0 / 2.0, y1 * 2.0)
    } else {
        (1e-4, 1.0)
    };
    let svg = draw(
        title,
        "sweeps i (log scale)",
        "summed KL to exact (nats, log scale)",
        (1.0..x1 * 1.5).log_scale(),
        (y0..y1).log_scale(),
        series,
        (1.0, x1 * 1.5, y0, y1),
        SeriesLabelPosition::UpperRight,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}
