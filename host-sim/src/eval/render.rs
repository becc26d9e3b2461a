//! Images for the demo and the reports: PNG maps (probability, truth, thresholded, TP/FP/FN
//! comparison, side-by-side strips) and SVG plots (precision–recall and F1-vs-threshold curves).
//!
//! Grids are row-major with row 0 at the **bottom** (see [`ogm_field::world`]); images store the top
//! row first, so every writer here flips vertically. The SVG plots use plotters' SVG backend,
//! which emits `<text>` elements and needs no system fonts.

use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use image::{GrayImage, Luma, Rgb, RgbImage};
use ogm_field::world::{Truth, World};
use plotters::prelude::*;

use crate::eval::metrics::PrPoint;

/// Gray level of `Truth::Unknown` cells in [`truth_image`] and [`comparison_image`].
pub const UNKNOWN_GRAY: u8 = 205;
/// Gray level for unknown cells (NaN probabilities) in [`probability_image`] and
/// [`threshold_image`]: the same as [`UNKNOWN_GRAY`], ROS map_server's unknown.
pub const NAN_GRAY: u8 = UNKNOWN_GRAY;

/// `probs` with every cell that no measurement reached (`observed` false) set to NaN, so that
/// the images and map files show it unknown (grey, ROS −1) whatever a method estimated there —
/// never free by default. Metrics use the probabilities as they are.
pub fn unknown_where_unobserved(probs: &[f64], observed: &[bool]) -> Vec<f64> {
    probs
        .iter()
        .zip(observed.iter().chain(std::iter::repeat(&false)))
        .map(|(&p, &o)| if o { p } else { f64::NAN })
        .collect()
}
/// Gap between the maps of [`side_by_side_png`], in pixels.
pub const SIDE_BY_SIDE_GAP_PX: u32 = 4;
/// Gray level of the gap between the maps of [`side_by_side_png`].
pub const SIDE_BY_SIDE_GAP_GRAY: u8 = 128;
/// [`comparison_image`] colour of true positives (predicted occupied, truth occupied).
pub const TP_COLOR: [u8; 3] = [0, 0, 0];
/// [`comparison_image`] colour of false positives (predicted occupied, truth free).
pub const FP_COLOR: [u8; 3] = [220, 30, 30];
/// [`comparison_image`] colour of false negatives (predicted free, truth occupied).
pub const FN_COLOR: [u8; 3] = [30, 60, 220];
/// [`comparison_image`] colour of true negatives (predicted free, truth free).
pub const TN_COLOR: [u8; 3] = [255, 255, 255];
/// Size of the SVG plots, in pixels.
pub const PLOT_SIZE: (u32, u32) = (800, 600);

fn check_len(what: &str, len: usize, width: usize, height: usize) -> Result<()> {
    ensure!(
        width.checked_mul(height) == Some(len),
        "{what} has {len} cells, expected {width}x{height}"
    );
    ensure!(
        u32::try_from(width).is_ok() && u32::try_from(height).is_ok(),
        "{width}x{height} is too large for an image"
    );
    Ok(())
}

/// Grid index of image pixel (x, image row r): image row 0 is the top grid row.
fn grid_index(x: u32, r: u32, width: usize, height: usize) -> usize {
    (height - 1 - r as usize) * width + x as usize
}

/// Whether `p` is predicted occupied at threshold `t`, scoring NaN as 0.5 like
/// [`crate::eval::metrics::PrAccumulator`].
fn predicted_occupied(p: f64, t: f64) -> bool {
    let p = if p.is_nan() { 0.5 } else { p };
    p >= t
}

/// Occupancy probabilities as a gray image: p = 0 white, p = 1 black, linear in between (values
/// outside [0, 1] are clamped, NaN is [`NAN_GRAY`]). The top image row is the top grid row.
pub fn probability_image(probs: &[f64], width: usize, height: usize) -> Result<GrayImage> {
    check_len("probs", probs.len(), width, height)?;
    Ok(GrayImage::from_fn(width as u32, height as u32, |x, r| {
        let p = probs[grid_index(x, r, width, height)];
        let v = if p.is_nan() {
            NAN_GRAY
        } else {
            (255.0 * (1.0 - p.clamp(0.0, 1.0))).round() as u8
        };
        Luma([v])
    }))
}

/// The ground truth as a gray image: free white, occupied black, unknown [`UNKNOWN_GRAY`].
pub fn truth_image(world: &World) -> Result<GrayImage> {
    check_len("world.cells", world.cells.len(), world.width, world.height)?;
    Ok(GrayImage::from_fn(
        world.width as u32,
        world.height as u32,
        |x, r| {
            Luma([
                match world.cells[grid_index(x, r, world.width, world.height)] {
                    Truth::Free => 255,
                    Truth::Occupied => 0,
                    Truth::Unknown => UNKNOWN_GRAY,
                },
            ])
        },
    ))
}

/// A thresholded map: black where `p ≥ t` (predicted occupied), else white; NaN (unknown)
/// [`NAN_GRAY`].
pub fn threshold_image(probs: &[f64], width: usize, height: usize, t: f64) -> Result<GrayImage> {
    check_len("probs", probs.len(), width, height)?;
    Ok(GrayImage::from_fn(width as u32, height as u32, |x, r| {
        let p = probs[grid_index(x, r, width, height)];
        if p.is_nan() {
            return Luma([NAN_GRAY]);
        }
        Luma([if predicted_occupied(p, t) { 0 } else { 255 }])
    }))
}

/// Thresholded map against the truth: TP [`TP_COLOR`] (black), FP [`FP_COLOR`] (red), FN
/// [`FN_COLOR`] (blue), TN [`TN_COLOR`] (white), truth unknown [`UNKNOWN_GRAY`].
pub fn comparison_image(probs: &[f64], world: &World, t: f64) -> Result<RgbImage> {
    let (w, h) = (world.width, world.height);
    check_len("world.cells", world.cells.len(), w, h)?;
    check_len("probs", probs.len(), w, h)?;
    Ok(RgbImage::from_fn(w as u32, h as u32, |x, r| {
        let i = grid_index(x, r, w, h);
        let occ = predicted_occupied(probs[i], t);
        Rgb(match (world.cells[i], occ) {
            (Truth::Unknown, _) => [UNKNOWN_GRAY; 3],
            (Truth::Occupied, true) => TP_COLOR,
            (Truth::Free, true) => FP_COLOR,
            (Truth::Occupied, false) => FN_COLOR,
            (Truth::Free, false) => TN_COLOR,
        })
    }))
}

/// Same-size gray maps concatenated left to right with [`SIDE_BY_SIDE_GAP_PX`] columns of
/// [`SIDE_BY_SIDE_GAP_GRAY`] between them. Labels only name the maps in error messages.
pub fn side_by_side_image<S: AsRef<str>>(images: &[(S, GrayImage)]) -> Result<GrayImage> {
    let Some((first_label, first)) = images.first() else {
        bail!("side_by_side: no images");
    };
    let (w, h) = first.dimensions();
    for (label, img) in images {
        ensure!(
            img.dimensions() == (w, h),
            "side_by_side: image {:?} is {}x{}, but {:?} is {w}x{h}",
            label.as_ref(),
            img.width(),
            img.height(),
            first_label.as_ref()
        );
    }
    let n = images.len() as u32;
    let total_w = n
        .checked_mul(w)
        .and_then(|v| v.checked_add((n - 1) * SIDE_BY_SIDE_GAP_PX))
        .context("side_by_side: combined image too wide")?;
    let mut out = GrayImage::from_pixel(total_w, h, Luma([SIDE_BY_SIDE_GAP_GRAY]));
    for (i, (_, img)) in images.iter().enumerate() {
        let x0 = i as u32 * (w + SIDE_BY_SIDE_GAP_PX);
        image::imageops::replace(&mut out, img, x0 as i64, 0);
    }
    Ok(out)
}

fn save_png<I: Into<image::DynamicImage>>(path: &Path, img: I) -> Result<()> {
    img.into()
        .save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("writing PNG {}", path.display()))
}

/// Writes [`probability_image`] to `path` as PNG.
pub fn probability_png(
    path: impl AsRef<Path>,
    probs: &[f64],
    width: usize,
    height: usize,
) -> Result<()> {
    let path = path.as_ref();
    let img = probability_image(probs, width, height)
        .with_context(|| format!("rendering {}", path.display()))?;
    save_png(path, img)
}

/// Writes [`truth_image`] to `path` as PNG.
pub fn truth_png(path: impl AsRef<Path>, world: &World) -> Result<()> {
    let path = path.as_ref();
    let img = truth_image(world).with_context(|| format!("rendering {}", path.display()))?;
    save_png(path, img)
}

/// Writes [`threshold_image`] to `path` as PNG.
pub fn threshold_png(
    path: impl AsRef<Path>,
    probs: &[f64],
    width: usize,
    height: usize,
    t: f64,
) -> Result<()> {
    let path = path.as_ref();
    let img = threshold_image(probs, width, height, t)
        .with_context(|| format!("rendering {}", path.display()))?;
    save_png(path, img)
}

/// Writes [`comparison_image`] to `path` as PNG.
pub fn comparison_png(path: impl AsRef<Path>, probs: &[f64], world: &World, t: f64) -> Result<()> {
    let path = path.as_ref();
    let img = comparison_image(probs, world, t)
        .with_context(|| format!("rendering {}", path.display()))?;
    save_png(path, img)
}

/// Writes [`side_by_side_image`] to `path` as PNG.
pub fn side_by_side_png<S: AsRef<str>>(
    path: impl AsRef<Path>,
    images: &[(S, GrayImage)],
) -> Result<()> {
    let path = path.as_ref();
    let img =
        side_by_side_image(images).with_context(|| format!("rendering {}", path.display()))?;
    save_png(path, img)
}

/// Series colours, cycled (also the baseline plots'); ten, so eval-sim's nine methods get
/// distinct colours.
pub(crate) const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
];

/// Draws unit-square line plots (one series per curve, with a legend) into an SVG string.
fn line_plot_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[(&str, Vec<(f64, f64)>)],
    legend_at: SeriesLabelPosition,
) -> Result<String> {
    line_plot_svg_in(
        title,
        x_label,
        y_label,
        (0.0, 1.0),
        (0.0, 1.0),
        series,
        legend_at,
    )
}

/// [`line_plot_svg`] over the given axis ranges.
fn line_plot_svg_in(
    title: &str,
    x_label: &str,
    y_label: &str,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    series: &[(&str, Vec<(f64, f64)>)],
    legend_at: SeriesLabelPosition,
) -> Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 28))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_labels(11)
            .y_labels(11)
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 20))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        for (i, (name, pts)) in series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))?
                .label(*name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        if !series.is_empty() {
            chart
                .configure_series_labels()
                .position(legend_at)
                .label_font(("sans-serif", 18))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()?;
        }
        root.present()?;
    }
    Ok(svg)
}

/// Writes an SVG string to `path` (errors name the file).
pub(crate) fn write_svg(path: &Path, svg: &str) -> Result<()> {
    std::fs::write(path, svg).with_context(|| format!("writing SVG {}", path.display()))
}

/// Precision–recall curves (recall on x, precision on y, both [0, 1]), one line per named
/// method, with a legend. Thresholds at which nothing is predicted occupied (precision
/// undefined) are left out.
pub fn pr_curve_svg<S: AsRef<str>>(
    path: impl AsRef<Path>,
    curves: &[(S, Vec<PrPoint>)],
    title: &str,
) -> Result<()> {
    let path = path.as_ref();
    let series: Vec<(&str, Vec<(f64, f64)>)> = curves
        .iter()
        .map(|(name, pts)| {
            let xy = pts
                .iter()
                .filter(|p| p.any_predicted())
                .map(|p| (p.recall, p.precision))
                .collect();
            (name.as_ref(), xy)
        })
        .collect();
    let svg = line_plot_svg(
        title,
        "Recall",
        "Precision",
        &series,
        SeriesLabelPosition::LowerLeft,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}

/// Max F1 against the number of scans inserted (the anytime curve of an online run), one line
/// per named series; the y axis spans the data (rounded out to tenths).
pub fn anytime_svg<S: AsRef<str>>(
    path: impl AsRef<Path>,
    series: &[(S, Vec<(f64, f64)>)],
    title: &str,
) -> Result<()> {
    let path = path.as_ref();
    let all = series.iter().flat_map(|(_, p)| p.iter());
    let (mut xmax, mut ymin) = (1.0f64, 1.0f64);
    for &(x, y) in all {
        xmax = xmax.max(x);
        ymin = ymin.min(y);
    }
    let ymin = ((ymin * 10.0).floor() / 10.0).clamp(0.0, 0.9);
    let s: Vec<(&str, Vec<(f64, f64)>)> = series
        .iter()
        .map(|(n, p)| (n.as_ref(), p.clone()))
        .collect();
    let svg = line_plot_svg_in(
        title,
        "Scans inserted",
        "Max F1 (all cells)",
        (0.0, xmax),
        (ymin, 1.0),
        &s,
        SeriesLabelPosition::LowerRight,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}

/// F1 score against the cell threshold (threshold on x, F1 on y, both [0, 1]), one line per
/// named method, with a legend.
pub fn f1_vs_threshold_svg<S: AsRef<str>>(
    path: impl AsRef<Path>,
    curves: &[(S, Vec<PrPoint>)],
    title: &str,
) -> Result<()> {
    let path = path.as_ref();
    let series: Vec<(&str, Vec<(f64, f64)>)> = curves
        .iter()
        .map(|(name, pts)| {
            (
                name.as_ref(),
                pts.iter().map(|p| (p.threshold, p.f1)).collect(),
            )
        })
        .collect();
    let svg = line_plot_svg(
        title,
        "Threshold",
        "F1 score",
        &series,
        SeriesLabelPosition::LowerMiddle,
    )
    .with_context(|| format!("plotting {}", path.display()))?;
    write_svg(path, &svg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::metrics::PrAccumulator;

    fn world_3x2() -> World {
        // Bottom row (row 0): Free, Occupied, Unknown; top row (row 1): Occupied, Free, Free.
        World {
            width: 3,
            height: 2,
            resolution_m: 0.05,
            origin_m: (0.0, 0.0),
            cells: vec![
                Truth::Free,
                Truth::Occupied,
                Truth::Unknown,
                Truth::Occupied,
                Truth::Free,
                Truth::Free,
            ],
        }
    }

    fn load_gray(path: &Path) -> GrayImage {
        image::open(path).unwrap().to_luma8()
    }

    #[test]
    fn probability_png_flips_and_scales() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        // Row 0 (bottom): 0, 0.5, 1; row 1 (top): NaN, 0.25, 2.0 (clamped).
        let probs = [0.0, 0.5, 1.0, f64::NAN, 0.25, 2.0];
        probability_png(&path, &probs, 3, 2).unwrap();
        let img = load_gray(&path);
        assert_eq!(img.dimensions(), (3, 2));
        // Image row 0 is the grid's top row.
        assert_eq!(img.get_pixel(0, 0)[0], NAN_GRAY);
        assert_eq!(img.get_pixel(1, 0)[0], 191);
        assert_eq!(img.get_pixel(2, 0)[0], 0);
        assert_eq!(img.get_pixel(0, 1)[0], 255);
        assert_eq!(img.get_pixel(1, 1)[0], 128);
        assert_eq!(img.get_pixel(2, 1)[0], 0);
    }

    #[test]
    fn unobserved_cells_are_drawn_unknown() {
        let probs = [0.1, 0.9, 0.0];
        let shown = unknown_where_unobserved(&probs, &[true, false]);
        assert_eq!(shown[0], 0.1);
        assert!(shown[1].is_nan() && shown[2].is_nan());
        let img = probability_image(&shown, 3, 1).unwrap();
        assert_eq!(img.get_pixel(1, 0)[0], UNKNOWN_GRAY);
        let th = threshold_image(&shown, 3, 1, 0.5).unwrap();
        assert_eq!(
            (th.get_pixel(0, 0)[0], th.get_pixel(1, 0)[0]),
            (255, UNKNOWN_GRAY)
        );
    }

    #[test]
    fn truth_threshold_and_comparison_pngs() {
        let dir = tempfile::tempdir().unwrap();
        let world = world_3x2();
        let truth_path = dir.path().join("truth.png");
        truth_png(&truth_path, &world).unwrap();
        let t = load_gray(&truth_path);
        assert_eq!(t.dimensions(), (3, 2));
        let top: Vec<u8> = (0..3).map(|x| t.get_pixel(x, 0)[0]).collect();
        let bottom: Vec<u8> = (0..3).map(|x| t.get_pixel(x, 1)[0]).collect();
        assert_eq!(top, [0, 255, 255]);
        assert_eq!(bottom, [255, 0, UNKNOWN_GRAY]);

        // Bottom: 0.9 (Free → FP), 0.5 (Occupied, t = 0.5 → TP), 0.7 (Unknown);
        // top: 0.1 (Occupied → FN), 0.2 (Free → TN), NaN (Free, 0.5 ≥ 0.5 → FP; drawn unknown
        // in the thresholded map).
        let probs = [0.9, 0.5, 0.7, 0.1, 0.2, f64::NAN];
        let th_path = dir.path().join("th.png");
        threshold_png(&th_path, &probs, 3, 2, 0.5).unwrap();
        let th = load_gray(&th_path);
        let top: Vec<u8> = (0..3).map(|x| th.get_pixel(x, 0)[0]).collect();
        let bottom: Vec<u8> = (0..3).map(|x| th.get_pixel(x, 1)[0]).collect();
        assert_eq!(top, [255, 255, NAN_GRAY]);
        assert_eq!(bottom, [0, 0, 0]);

        let cmp_path = dir.path().join("cmp.png");
        comparison_png(&cmp_path, &probs, &world, 0.5).unwrap();
        let c = image::open(&cmp_path).unwrap().to_rgb8();
        assert_eq!(c.dimensions(), (3, 2));
        assert_eq!(c.get_pixel(0, 0).0, FN_COLOR);
        assert_eq!(c.get_pixel(1, 0).0, TN_COLOR);
        assert_eq!(c.get_pixel(2, 0).0, FP_COLOR);
        assert_eq!(c.get_pixel(0, 1).0, FP_COLOR);
        assert_eq!(c.get_pixel(1, 1).0, TP_COLOR);
        assert_eq!(c.get_pixel(2, 1).0, [UNKNOWN_GRAY; 3]);
    }

    #[test]
    fn side_by_side_concatenates_with_gap() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sbs.png");
        let a = GrayImage::from_pixel(3, 2, Luma([0]));
        let b = GrayImage::from_pixel(3, 2, Luma([255]));
        let c = GrayImage::from_pixel(3, 2, Luma([10]));
        side_by_side_png(&path, &[("a", a.clone()), ("b", b), ("c", c)]).unwrap();
        let img = load_gray(&path);
        let gap = SIDE_BY_SIDE_GAP_PX;
        assert_eq!(img.dimensions(), (9 + 2 * gap, 2));
        for y in 0..2 {
            assert_eq!(img.get_pixel(0, y)[0], 0);
            assert_eq!(img.get_pixel(2, y)[0], 0);
            assert_eq!(img.get_pixel(3, y)[0], SIDE_BY_SIDE_GAP_GRAY);
            assert_eq!(img.get_pixel(3 + gap, y)[0], 255);
            assert_eq!(img.get_pixel(5 + gap, y)[0], 255);
            assert_eq!(img.get_pixel(6 + 2 * gap, y)[0], 10);
            assert_eq!(img.get_pixel(8 + 2 * gap, y)[0], 10);
        }
        // Mismatched sizes and empty input are errors.
        let small = GrayImage::new(2, 2);
        let err = side_by_side_png(&path, &[("a", a), ("small", small)]).unwrap_err();
        assert!(format!("{err:#}").contains("small"), "{err:#}");
        assert!(side_by_side_png::<&str>(&path, &[]).is_err());
    }

    #[test]
    fn length_mismatch_and_io_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.png");
        let err = probability_png(&path, &[0.5; 5], 3, 2).unwrap_err();
        assert!(format!("{err:#}").contains("bad.png"), "{err:#}");
        let mut world = world_3x2();
        assert!(comparison_png(&path, &[0.5; 5], &world, 0.5).is_err());
        world.cells.pop();
        assert!(truth_png(&path, &world).is_err());
        assert!(!path.exists());

        let missing = dir.path().join("no-such-dir").join("x.png");
        let err = threshold_png(&missing, &[0.5; 6], 3, 2, 0.5).unwrap_err();
        assert!(format!("{err:#}").contains("x.png"), "{err:#}");
        let missing_svg = dir.path().join("no-such-dir").join("x.svg");
        let err = pr_curve_svg::<&str>(&missing_svg, &[], "t").unwrap_err();
        assert!(format!("{err:#}").contains("x.svg"), "{err:#}");
    }

    #[test]
    fn svg_plots_contain_series_names() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = PrAccumulator::new();
        a.add(
            &[0.9, 0.6, 0.3, 0.7, 0.2, 0.5],
            &[
                Truth::Occupied,
                Truth::Occupied,
                Truth::Occupied,
                Truth::Free,
                Truth::Free,
                Truth::Free,
            ],
            None,
        )
        .unwrap();
        let mut b = PrAccumulator::new();
        b.add(&[0.8, 0.1], &[Truth::Occupied, Truth::Free], None)
            .unwrap();
        let curves = vec![
            ("Traditional OGM".to_string(), a.curve()),
            ("MCMC+border, L=9".to_string(), b.curve()),
        ];
        let pr = dir.path().join("pr.svg");
        pr_curve_svg(&pr, &curves, "Precision-recall").unwrap();
        let text = std::fs::read_to_string(&pr).unwrap();
        assert!(text.starts_with("<svg"), "{}", &text[..40.min(text.len())]);
        for needle in [
            "Traditional OGM",
            "MCMC+border, L=9",
            "Precision-recall",
            "Recall",
            "Precision",
        ] {
            assert!(text.contains(needle), "missing {needle}");
        }
        assert!(text.contains("<polyline"));

        let f1 = dir.path().join("f1.svg");
        f1_vs_threshold_svg(&f1, &curves, "F1 & threshold").unwrap();
        let text = std::fs::read_to_string(&f1).unwrap();
        for needle in [
            "Traditional OGM",
            "MCMC+border, L=9",
            "F1 &amp; threshold",
            "Threshold",
            "F1 score",
        ] {
            assert!(text.contains(needle), "missing {needle}");
        }
    }
}
