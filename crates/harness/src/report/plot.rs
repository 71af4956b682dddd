//! Log–log plots of error against run time for `skybake-harness report`: one PNG per product, one curve
//! per method and regime (cold CPU time on x, relative RMS error on y), the presets marked by their
//! initial (d, s, h). The reference point (error 0 by construction) is left out of the curve.

use super::{Curve, Report};
use crate::{Error, Result};
use image::ImageEncoder;
use plotters::prelude::*;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::ProductKind;
use std::sync::Once;

/// Plot size, pixels.
const SIZE: (u32, u32) = (900, 600);
/// The embedded font (DejaVu Sans, see assets/fonts/DejaVuSans-LICENSE.txt).
static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
const FAMILY: &str = "skybake-sans";

fn register_font() -> Result<()> {
    static REGISTER: Once = Once::new();
    let mut ok = true;
    REGISTER.call_once(|| {
        ok = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok();
    });
    if ok {
        Ok(())
    } else {
        Err(Error::internal("report", "the embedded font did not load"))
    }
}

fn plot_err<E: std::fmt::Debug>(e: E) -> Error {
    Error::internal("report", format!("plot: {e:?}"))
}

/// Curve colour: blue shades for fast, red shades for precise, one shade per regime.
fn colour(method: MsMethod, index: usize, count: usize) -> RGBColor {
    let t = if count > 1 {
        index as f64 / (count - 1) as f64
    } else {
        0.0
    };
    let shade = |a: f64, b: f64| (a + (b - a) * t).round() as u8;
    match method {
        MsMethod::Fast => RGBColor(shade(30.0, 120.0), shade(90.0, 190.0), shade(200.0, 240.0)),
        _ => RGBColor(shade(200.0, 240.0), shade(40.0, 150.0), shade(30.0, 110.0)),
    }
}

fn preset_letter(q: Quality) -> &'static str {
    match q {
        Quality::Draft => "d",
        Quality::Standard => "s",
        Quality::High => "h",
        Quality::Reference => "r",
    }
}

/// The (time ms, rel_rms) points of a curve that can go on log axes.
fn drawable(c: &Curve) -> Vec<(f64, f64, Quality)> {
    c.points
        .iter()
        .map(|p| {
            (
                p.cold_cpu_ms.unwrap_or(p.cold_ms) / 1e3,
                p.rel_rms,
                p.quality,
            )
        })
        .filter(|&(t, e, _)| e > 0.0 && e.is_finite() && t > 0.0)
        .collect()
}

/// The PNG of `product`'s curves.
pub fn error_time_png(report: &Report, product: ProductKind) -> Result<Vec<u8>> {
    register_font()?;
    let curves: Vec<&Curve> = report
        .curves
        .iter()
        .filter(|c| c.product == product)
        .collect();
    let all: Vec<(f64, f64, Quality)> = curves.iter().flat_map(|c| drawable(c)).collect();
    let (mut t0, mut t1, mut e0, mut e1) = all.iter().fold(
        (f64::MAX, f64::MIN_POSITIVE, f64::MAX, f64::MIN_POSITIVE),
        |(a, b, c, d), &(t, e, _)| (a.min(t), b.max(t), c.min(e), d.max(e)),
    );
    if all.is_empty() {
        (t0, t1, e0, e1) = (0.1, 10.0, 1e-4, 1e-1);
    }
    let (t0, t1, e0, e1) = (t0 / 1.5, t1 * 1.5, e0 / 1.5, e1 * 1.5);
    let mut buf = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: error against cold CPU time", product.name()),
                (FAMILY, 22),
            )
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d((t0..t1).log_scale(), (e0..e1).log_scale())
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("cold CPU time, s, all threads (tables built + product)")
            .y_desc("relative RMS error vs reference")
            .label_style((FAMILY, 14))
            .axis_desc_style((FAMILY, 15))
            .x_labels(8)
            .y_labels(8)
            .light_line_style(WHITE)
            .y_label_formatter(&|v| format!("{:.2}%", v * 100.0))
            .x_label_formatter(&|v| format!("{v:.3}"))
            .draw()
            .map_err(plot_err)?;
        let per_method = |m: MsMethod| curves.iter().filter(|c| c.method == m).count();
        let mut index = [0usize; 2];
        for c in &curves {
            let slot = usize::from(c.method == MsMethod::Precise);
            let colour = colour(c.method, index[slot], per_method(c.method));
            index[slot] += 1;
            let pts = drawable(c);
            let label = format!(
                "{} {}",
                match c.method {
                    MsMethod::Fast => "fast",
                    MsMethod::Precise => "precise",
                    MsMethod::None => "none",
                },
                c.regime
            );
            chart
                .draw_series(LineSeries::new(
                    pts.iter().map(|&(t, e, _)| (t, e)),
                    colour.stroke_width(2),
                ))
                .map_err(plot_err)?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(pts.iter().map(|&(t, e, q)| {
                    EmptyElement::at((t, e))
                        + Circle::new((0, 0), 4, colour.filled())
                        + Text::new(preset_letter(q), (6, -14), (FAMILY, 13))
                }))
                .map_err(plot_err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FAMILY, 12))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    encode_png(&buf)
}

/// One curve of a generic error-against-time plot: its legend, colour and points
/// (time s, error, marker text).
pub struct Series {
    pub label: String,
    pub colour: RGBColor,
    pub points: Vec<(f64, f64, String)>,
}

/// A log–log plot of `series` (points with a non-positive or non-finite coordinate are left out).
pub fn log_log_png(title: &str, x_desc: &str, y_desc: &str, series: &[Series]) -> Result<Vec<u8>> {
    register_font()?;
    let ok = |p: &&(f64, f64, String)| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite();
    let all: Vec<&(f64, f64, String)> = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(ok)
        .collect();
    let (mut t0, mut t1, mut e0, mut e1) = all.iter().fold(
        (f64::MAX, f64::MIN_POSITIVE, f64::MAX, f64::MIN_POSITIVE),
        |(a, b, c, d), &&(t, e, _)| (a.min(t), b.max(t), c.min(e), d.max(e)),
    );
    if all.is_empty() {
        (t0, t1, e0, e1) = (0.1, 10.0, 1e-4, 1e-1);
    }
    let (t0, t1, e0, e1) = (t0 / 1.5, t1 * 1.5, e0 / 1.5, e1 * 1.5);
    let mut buf = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FAMILY, 22))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d((t0..t1).log_scale(), (e0..e1).log_scale())
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .label_style((FAMILY, 14))
            .axis_desc_style((FAMILY, 15))
            .x_labels(8)
            .y_labels(8)
            .light_line_style(WHITE)
            .y_label_formatter(&|v| format!("{:.2}%", v * 100.0))
            .x_label_formatter(&|v| format!("{v:.3}"))
            .draw()
            .map_err(plot_err)?;
        for s in series {
            let colour = s.colour;
            let pts: Vec<&(f64, f64, String)> = s.points.iter().filter(ok).collect();
            chart
                .draw_series(LineSeries::new(
                    pts.iter().map(|&&(t, e, _)| (t, e)),
                    colour.stroke_width(2),
                ))
                .map_err(plot_err)?
                .label(s.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(pts.iter().map(|&&(t, e, ref text)| {
                    EmptyElement::at((t, e))
                        + Circle::new((0, 0), 4, colour.filled())
                        + Text::new(text.clone(), (6, -14), (FAMILY, 13))
                }))
                .map_err(plot_err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FAMILY, 12))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    encode_png(&buf)
}

/// The plot's RGB buffer as a PNG file.
fn encode_png(buf: &[u8]) -> Result<Vec<u8>> {
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(buf, SIZE.0, SIZE.1, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::internal("report", format!("PNG encoding: {e}")))?;
    Ok(png)
}
