//! PNG figures like the paper's: trajectory vs reference (Figs. 4 and 10), horizontal error
//! with its 1-sigma and 3-sigma bands (Figs. 5 and 11), heading error with its bands (Figs. 6
//! and 12), and the stability study's history and histograms (Figs. 7 and 8).
//!
//! Text is drawn by `ab_glyph` from DejaVu Sans embedded in the binary (`assets/`), so the
//! figures render identically on machines without any system font.

use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{anyhow, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::calib::{Evaluation, WindowEstimate};

/// DejaVu Sans 2.37 (Bitstream Vera licence, see `assets/DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

const FAMILY: &str = "sans-serif";

fn register_font() -> Result<()> {
    let mut result = Ok(());
    REGISTER.call_once(|| {
        for family in ["sans-serif", "serif", "monospace"] {
            if plotters::style::register_font(family, FontStyle::Normal, FONT).is_err() {
                result = Err(anyhow!("the embedded font cannot be parsed"));
            }
        }
    });
    result
}

fn pe<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting: {e:?}")
}

fn range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let span = (hi - lo).max(1e-9);
    (lo - pad * span, hi + pad * span)
}

/// A legend entry's sample: a short line in `style`.
fn legend_line(style: impl Into<ShapeStyle>) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    let style = style.into();
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style)
}

/// The chart of every figure: `f64` on both axes.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The series' legend, in a box at `position`, text of `font_size`.
fn legend_box<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    font_size: u32,
    position: SeriesLabelPosition,
) -> Result<()> {
    chart
        .configure_series_labels()
        .label_font((FAMILY, font_size))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(position)
        .draw()
        .map_err(pe)
}

const ODO: RGBColor = RGBColor(200, 30, 30);
const REF: RGBColor = RGBColor(30, 30, 30);
const BAND1: RGBColor = RGBColor(30, 120, 200);
const BAND3: RGBColor = RGBColor(230, 140, 20);

/// The figures of one evaluated run, `<prefix>_trajectory.png`, `<prefix>_horizontal_error.png`
/// and (when the reference has a heading) `<prefix>_heading_error.png`; returns their paths.
pub fn run_figures(dir: &Path, prefix: &str, title: &str, ev: &Evaluation) -> Result<Vec<PathBuf>> {
    register_font()?;
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?;
    let mut out = Vec::new();

    // Trajectory, equal scales on both axes.
    let path = dir.join(format!("{prefix}_trajectory.png"));
    {
        let (w, h) = (900u32, 900u32);
        let root = BitMapBackend::new(&path, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let all_x = ev
            .odo
            .iter()
            .map(|p| p.0)
            .chain(ev.reference.iter().map(|p| p.0));
        let all_y = ev
            .odo
            .iter()
            .map(|p| p.1)
            .chain(ev.reference.iter().map(|p| p.1));
        let (mut x0, mut x1) = range(all_x, 0.05);
        let (mut y0, mut y1) = range(all_y, 0.05);
        let (sx, sy) = (x1 - x0, y1 - y0);
        if sx > sy {
            let c = 0.5 * (y0 + y1);
            (y0, y1) = (c - sx / 2.0, c + sx / 2.0);
        } else {
            let c = 0.5 * (x0 + x1);
            (x0, x1) = (c - sy / 2.0, c + sy / 2.0);
        }
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("{title}: trajectory"), (FAMILY, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(pe)?;
        chart
            .configure_mesh()
            .x_desc("x (east) [m]")
            .y_desc("y (north) [m]")
            .label_style((FAMILY, 15))
            .draw()
            .map_err(pe)?;
        chart
            .draw_series(LineSeries::new(
                ev.reference.iter().copied(),
                REF.stroke_width(2),
            ))
            .map_err(pe)?
            .label("reference (RTK GNSS)")
            .legend(legend_line(REF.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(ev.odo.iter().copied(), ODO.stroke_width(2)))
            .map_err(pe)?
            .label("odometry")
            .legend(legend_line(ODO.stroke_width(2)));
        if let Some(&p) = ev.reference.first() {
            chart
                .draw_series(std::iter::once(Circle::new(p, 6, REF.filled())))
                .map_err(pe)?;
        }
        legend_box(&mut chart, 16, SeriesLabelPosition::UpperRight)?;
        root.present().map_err(pe)?;
    }
    out.push(path);

    // Horizontal error with the 1-sigma and 3-sigma bands.
    let path = dir.join(format!("{prefix}_horizontal_error.png"));
    let three: Vec<f64> = ev.sigma_h.iter().map(|s| 3.0 * s).collect();
    error_figure(
        &path,
        &format!("{title}: horizontal position error"),
        "horizontal error [m]",
        &ev.t,
        &ev.horizontal,
        &ev.sigma_h,
        &three,
        false,
    )?;
    out.push(path);

    // Heading error with its bands (degrees).
    let (ht, he, hs): (Vec<f64>, Vec<f64>, Vec<f64>) = {
        let mut v = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..ev.t.len() {
            if let Some(e) = ev.heading_err[i] {
                v.0.push(ev.t[i]);
                v.1.push(e.to_degrees());
                v.2.push(ev.sigma_heading[i].to_degrees());
            }
        }
        v
    };
    if !ht.is_empty() {
        let path = dir.join(format!("{prefix}_heading_error.png"));
        let three: Vec<f64> = hs.iter().map(|s| 3.0 * s).collect();
        error_figure(
            &path,
            &format!("{title}: heading error"),
            "heading error [deg]",
            &ht,
            &he,
            &hs,
            &three,
            true,
        )?;
        out.push(path);
    }
    Ok(out)
}

#[allow(clippy::too_many_arguments)]
fn error_figure(
    path: &Path,
    caption: &str,
    ydesc: &str,
    t: &[f64],
    err: &[f64],
    s1: &[f64],
    s3: &[f64],
    symmetric: bool,
) -> Result<()> {
    let fold =
        |it: &mut dyn Iterator<Item = f64>| it.filter(|v| v.is_finite()).fold(1e-9, f64::max);
    let emax = fold(&mut err.iter().map(|e| e.abs()));
    let full = fold(&mut err.iter().map(|e| e.abs()).chain(s3.iter().copied())) * 1.05;
    let panels = ErrorPanels {
        caption,
        ydesc,
        full,
        emax,
        symmetric,
    };
    panels.draw(path, t, |chart, y0, ymax| {
        let clip = |v: f64| v.clamp(y0, ymax);
        error_series(chart, t, err.iter().map(|&e| clip(e)))?;
        for (band, color, label) in [(s1, BAND1, "1 sigma"), (s3, BAND3, "3 sigma")] {
            let style = color.stroke_width(2);
            chart
                .draw_series(LineSeries::new(
                    t.iter().copied().zip(band.iter().map(|&v| clip(v))),
                    style,
                ))
                .map_err(pe)?
                .label(label)
                .legend(legend_line(style));
            if symmetric {
                chart
                    .draw_series(LineSeries::new(
                        t.iter().copied().zip(band.iter().map(|&v| clip(-v))),
                        style,
                    ))
                    .map_err(pe)?;
            }
        }
        Ok(())
    })
}

/// A figure of an error against time in two panels, 1100 x 900: the whole range up to `full`
/// on top (the bands of the paper's model can dwarf the errors), and below a zoom on the errors
/// (up to 1.3 `emax`), bands clipped.
struct ErrorPanels<'s> {
    caption: &'s str,
    ydesc: &'s str,
    full: f64,
    emax: f64,
    /// The y axis from `-ymax` (else from 0).
    symmetric: bool,
}

impl ErrorPanels<'_> {
    /// Draws the figure; `series(chart, y0, ymax)` draws a panel's series.
    fn draw(
        &self,
        path: &Path,
        t: &[f64],
        mut series: impl FnMut(&mut Chart, f64, f64) -> Result<()>,
    ) -> Result<()> {
        let root = BitMapBackend::new(path, (1100, 900)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let root = root.titled(self.caption, (FAMILY, 24)).map_err(pe)?;
        let (t0, t1) = range(t.iter().copied(), 0.0);
        let (top, bottom) = root.split_vertically(450);
        for (area, ymax, note) in [
            (&top, self.full, "full range"),
            (&bottom, self.emax * 1.3, "zoom on the errors"),
        ] {
            let y0 = if self.symmetric { -ymax } else { 0.0 };
            let mut chart = ChartBuilder::on(area)
                .caption(note, (FAMILY, 16))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(80)
                .build_cartesian_2d(t0..t1, y0..ymax)
                .map_err(pe)?;
            chart
                .configure_mesh()
                .x_desc("time [s]")
                .y_desc(self.ydesc)
                .label_style((FAMILY, 14))
                .draw()
                .map_err(pe)?;
            series(&mut chart, y0, ymax)?;
            legend_box(&mut chart, 15, SeriesLabelPosition::UpperLeft)?;
        }
        root.present().map_err(pe)?;
        Ok(())
    }
}

/// The error line of an error figure.
fn error_series(chart: &mut Chart, t: &[f64], err: impl Iterator<Item = f64>) -> Result<()> {
    chart
        .draw_series(LineSeries::new(
            t.iter().copied().zip(err),
            ODO.stroke_width(1),
        ))
        .map_err(pe)?
        .label("error")
        .legend(legend_line(ODO.stroke_width(2)));
    Ok(())
}

/// `validate_models.png`: the horizontal error against the 1-sigma (solid) and 3-sigma
/// (thin) bands of each uncertainty model, full range and zoomed on the errors.
pub fn models_figure(
    dir: &Path,
    t: &[f64],
    err: &[f64],
    models: &[(&str, Vec<f64>)],
) -> Result<PathBuf> {
    register_font()?;
    let path = dir.join("validate_models.png");
    draw_models(&path, t, err, models)?;
    Ok(path)
}

fn draw_models(path: &Path, t: &[f64], err: &[f64], models: &[(&str, Vec<f64>)]) -> Result<()> {
    let emax = err
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(1e-9, f64::max);
    let full = models
        .iter()
        .flat_map(|(_, s)| s.iter().map(|v| 3.0 * v))
        .filter(|v| v.is_finite())
        .fold(emax, f64::max)
        * 1.05;
    let panels = ErrorPanels {
        caption: "Horizontal error and the uncertainty models' bands",
        ydesc: "horizontal error [m]",
        full,
        emax,
        symmetric: false,
    };
    panels.draw(path, t, |chart, _, ymax| {
        let clip = |v: f64| v.min(ymax);
        error_series(chart, t, err.iter().map(|&e| clip(e)))?;
        for (i, (name, s)) in models.iter().enumerate() {
            let color = if i == 0 { BAND1 } else { BAND3 };
            chart
                .draw_series(LineSeries::new(
                    t.iter().copied().zip(s.iter().map(|&v| clip(v))),
                    color.stroke_width(2),
                ))
                .map_err(pe)?
                .label(format!("{name}: 1 and 3 sigma"))
                .legend(legend_line(color.stroke_width(2)));
            chart
                .draw_series(LineSeries::new(
                    t.iter().copied().zip(s.iter().map(|&v| clip(3.0 * v))),
                    color.stroke_width(1),
                ))
                .map_err(pe)?;
        }
        Ok(())
    })
}

const PARAM_NAMES: [&str; 3] = ["left_diameter [m]", "right_diameter [m]", "track_width [m]"];

fn palette(i: usize) -> RGBColor {
    const C: [RGBColor; 6] = [
        RGBColor(30, 120, 200),
        RGBColor(200, 30, 30),
        RGBColor(30, 150, 60),
        RGBColor(150, 60, 180),
        RGBColor(230, 140, 20),
        RGBColor(60, 60, 60),
    ];
    C[i % C.len()]
}

/// The stability study: `windows_history.png` (estimates along the run per sub-trajectory
/// length, Fig. 7) and `windows_histograms.png` (Fig. 8) of the accepted windows (failed
/// ones are counted in the title, not drawn); returns their paths.
pub fn window_figures(dir: &Path, est: &[WindowEstimate], full: [f64; 3]) -> Result<Vec<PathBuf>> {
    register_font()?;
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?;
    let mut lengths: Vec<f64> = est.iter().map(|e| e.length).collect();
    lengths.sort_by(f64::total_cmp);
    lengths.dedup();
    let ok: Vec<(&WindowEstimate, [f64; 4])> = est
        .iter()
        .filter_map(|e| e.estimate.as_ref().ok().map(|v| (e, *v)))
        .collect();
    let mut out = Vec::new();

    let path = dir.join("windows_history.png");
    {
        let root = BitMapBackend::new(&path, (1100, 1000)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let failed = est.len() - ok.len();
        let title = if failed == 0 {
            "Estimates on consecutive sub-trajectories".to_string()
        } else {
            format!("Estimates on consecutive sub-trajectories ({failed} failed windows not drawn)")
        };
        let root = root.titled(&title, (FAMILY, 24)).map_err(pe)?;
        let panels = root.split_evenly((3, 1));
        let (d0, d1) = range(est.iter().map(|e| e.start_dist), 0.02);
        for (p, area) in panels.iter().enumerate() {
            let (v0, v1) = robust_range(ok.iter().map(|(_, v)| v[p]), full[p]);
            let mut chart = ChartBuilder::on(area)
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(80)
                .build_cartesian_2d(d0..d1, v0..v1)
                .map_err(pe)?;
            chart
                .configure_mesh()
                .x_desc("sub-trajectory start [m of path]")
                .y_desc(PARAM_NAMES[p])
                .label_style((FAMILY, 14))
                .draw()
                .map_err(pe)?;
            for (li, &l) in lengths.iter().enumerate() {
                let color = palette(li);
                let pts: Vec<(f64, f64)> = ok
                    .iter()
                    .filter(|(e, v)| e.length == l && v[p].is_finite())
                    .map(|(e, v)| (e.start_dist, v[p].clamp(v0, v1)))
                    .collect();
                chart
                    .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(1)))
                    .map_err(pe)?
                    .label(format!("{l} m"))
                    .legend(legend_line(color.stroke_width(2)));
                chart
                    .draw_series(pts.iter().map(|&q| Circle::new(q, 3, color.filled())))
                    .map_err(pe)?;
            }
            chart
                .draw_series(LineSeries::new(
                    [(d0, full[p]), (d1, full[p])],
                    BLACK.stroke_width(1),
                ))
                .map_err(pe)?
                .label("whole run")
                .legend(legend_line(BLACK));
            legend_box(&mut chart, 14, SeriesLabelPosition::UpperRight)?;
        }
        root.present().map_err(pe)?;
    }
    out.push(path);

    let path = dir.join("windows_histograms.png");
    {
        let rows = lengths.len().max(1);
        let root = BitMapBackend::new(&path, (1200, 260 * rows as u32 + 60)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let root = root
            .titled("Histograms of the sub-trajectory estimates", (FAMILY, 24))
            .map_err(pe)?;
        let cells = root.split_evenly((rows, 3));
        for (ri, &l) in lengths.iter().enumerate() {
            for p in 0..3 {
                let area: &DrawingArea<BitMapBackend, Shift> = &cells[ri * 3 + p];
                let vals: Vec<f64> = ok
                    .iter()
                    .filter(|(e, v)| e.length == l && v[p].is_finite())
                    .map(|(_, v)| v[p])
                    .collect();
                histogram(
                    area,
                    &vals,
                    &format!("{} ({l} m)", PARAM_NAMES[p]),
                    palette(ri),
                    full[p],
                )?;
            }
        }
        root.present().map_err(pe)?;
    }
    out.push(path);
    Ok(out)
}

/// A value range that ignores wild outliers (ill-conditioned windows): the 5-95 % range
/// widened, always containing `centre`.
fn robust_range(values: impl Iterator<Item = f64>, centre: f64) -> (f64, f64) {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (centre * 0.99, centre * 1.01);
    }
    v.sort_by(f64::total_cmp);
    let lo = crate::stats::quantile_sorted(&v, 0.05).min(centre);
    let hi = crate::stats::quantile_sorted(&v, 0.95).max(centre);
    let span = (hi - lo).max(centre.abs() * 1e-4).max(1e-9);
    (lo - 0.3 * span, hi + 0.3 * span)
}

fn histogram(
    area: &DrawingArea<BitMapBackend, Shift>,
    vals: &[f64],
    caption: &str,
    color: RGBColor,
    full: f64,
) -> Result<()> {
    let (lo, hi) = robust_range(vals.iter().copied(), full);
    let bins = 15usize;
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for &v in vals {
        let i = (((v - lo) / width).floor().max(0.0) as usize).min(bins - 1);
        counts[i] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.1;
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FAMILY, 15))
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(35)
        .build_cartesian_2d(lo..hi, 0.0..top)
        .map_err(pe)?;
    chart
        .configure_mesh()
        .x_labels(4)
        .y_labels(4)
        .label_style((FAMILY, 11))
        .draw()
        .map_err(pe)?;
    chart
        .draw_series(counts.iter().enumerate().map(|(i, &c)| {
            let x0 = lo + i as f64 * width;
            Rectangle::new([(x0, 0.0), (x0 + width, c as f64)], color.mix(0.7).filled())
        }))
        .map_err(pe)?;
    chart
        .draw_series(LineSeries::new(
            [(full, 0.0), (full, top)],
            BLACK.stroke_width(1),
        ))
        .map_err(pe)?;
    Ok(())
}

/// The ensemble coverage of several runs: `<prefix>_coverage.png`, the share of
/// horizontal and heading errors inside 1 and 3 sigma at each checkpoint against the distance
/// travelled, with the nominal 68.3 % and 99.7 % and the band 60-76 % a calibrated model's
/// 1-sigma coverage should stay in; and `<prefix>_reliability.png`, the observed against the
/// nominal coverage at levels 10-90 % (the diagonal is a calibrated model). `models` are the
/// names and ensembles of the models evaluated. Returns the paths.
pub fn ensemble_figures(
    dir: &Path,
    prefix: &str,
    models: &[(&str, &crate::calib::Ensemble)],
) -> Result<Vec<PathBuf>> {
    register_font()?;
    let cov = dir.join(format!("{prefix}_coverage.png"));
    draw_ensemble_coverage(&cov, models)?;
    let rel = dir.join(format!("{prefix}_reliability.png"));
    draw_reliability(&rel, models)?;
    Ok(vec![cov, rel])
}

fn draw_ensemble_coverage(path: &Path, models: &[(&str, &crate::calib::Ensemble)]) -> Result<()> {
    let root = BitMapBackend::new(path, (1400, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let xmax = models
        .iter()
        .flat_map(|(_, e)| e.distances.iter().copied())
        .fold(1.0, f64::max)
        * 1.05;
    let panels = root.split_evenly((1, 2));
    for (panel, heading) in panels.iter().zip([false, true]) {
        let mut chart = ChartBuilder::on(panel)
            .caption(
                if heading {
                    "Heading: share inside 1 and 3 sigma"
                } else {
                    "Horizontal: share inside 1 and 3 sigma_h"
                },
                (FAMILY, 22),
            )
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..xmax, 0.0..105.0)
            .map_err(pe)?;
        chart
            .configure_mesh()
            .x_desc("distance travelled [m]")
            .y_desc("coverage [%]")
            .label_style((FAMILY, 15))
            .draw()
            .map_err(pe)?;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(0.0, 60.0), (xmax, 76.0)],
                BAND1.mix(0.12).filled(),
            )))
            .map_err(pe)?
            .label("1-sigma target 60-76 %")
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 5), (x + 20, y + 5)], BAND1.mix(0.3).filled())
            });
        for (nominal, label) in [(68.27, "nominal 68.3 %"), (99.73, "nominal 99.7 %")] {
            chart
                .draw_series(LineSeries::new(
                    [(0.0, nominal), (xmax, nominal)],
                    BLACK.stroke_width(1),
                ))
                .map_err(pe)?
                .label(label)
                .legend(legend_line(BLACK.stroke_width(1)));
        }
        for (i, (name, e)) in models.iter().enumerate() {
            let color = palette(i);
            let c = e.coverage();
            let pick = |k: &crate::calib::CheckpointCoverage, three: bool| {
                let (one, three_v) = if heading { k.heading } else { k.horizontal };
                100.0 * if three { three_v } else { one }
            };
            for three in [false, true] {
                let pts: Vec<(f64, f64)> = c
                    .iter()
                    .map(|k| (k.distance, pick(k, three)))
                    .filter(|p| p.1.is_finite())
                    .collect();
                let width = if three { 1 } else { 2 };
                let series = chart
                    .draw_series(LineSeries::new(pts.clone(), color.stroke_width(width)))
                    .map_err(pe)?;
                if !three {
                    series
                        .label(format!("{name} (1 sigma bold, 3 sigma thin)"))
                        .legend(legend_line(color.stroke_width(2)));
                }
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                    .map_err(pe)?;
            }
        }
        legend_box(&mut chart, 14, SeriesLabelPosition::LowerRight)?;
    }
    root.present().map_err(pe)
}

fn draw_reliability(path: &Path, models: &[(&str, &crate::calib::Ensemble)]) -> Result<()> {
    let root = BitMapBackend::new(path, (1400, 650)).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let panels = root.split_evenly((1, 2));
    for (panel, heading) in panels.iter().zip([false, true]) {
        let mut chart = ChartBuilder::on(panel)
            .caption(
                if heading {
                    "Reliability: heading (normal)"
                } else {
                    "Reliability: horizontal (round 2-D normal)"
                },
                (FAMILY, 22),
            )
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..100.0, 0.0..100.0)
            .map_err(pe)?;
        chart
            .configure_mesh()
            .x_desc("nominal coverage [%]")
            .y_desc("observed coverage [%]")
            .label_style((FAMILY, 15))
            .draw()
            .map_err(pe)?;
        chart
            .draw_series(LineSeries::new(
                [(0.0, 0.0), (100.0, 100.0)],
                BLACK.stroke_width(1),
            ))
            .map_err(pe)?
            .label("calibrated")
            .legend(legend_line(BLACK.stroke_width(1)));
        for (i, (name, e)) in models.iter().enumerate() {
            let color = palette(i);
            let pts: Vec<(f64, f64)> = e
                .reliability()
                .into_iter()
                .map(|(p, h, a)| (100.0 * p, 100.0 * if heading { a } else { h }))
                .filter(|p| p.1.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(pe)?
                .label(name.to_string())
                .legend(legend_line(color.stroke_width(2)));
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                .map_err(pe)?;
        }
        legend_box(&mut chart, 14, SeriesLabelPosition::UpperLeft)?;
    }
    root.present().map_err(pe)
}
