//! Line charts drawn with plotters into PNG files.

use crate::image::write_atomically;
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::OnceLock;

/// Where a TrueType font for chart text may be (Debian's fonts-dejavu-core first).
const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

/// Registers a font for chart text once; plotters draws no text without one.
/// `QTRACE_FONT`, when set and not empty, is the only font tried. The bench calls this
/// before it renders anything, so that a machine without a font learns so
/// at once, not after the renders.
pub fn ensure_font() -> Result<(), String> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let given = std::env::var("QTRACE_FONT").ok().filter(|p| !p.is_empty());
        let candidates: Vec<String> = match &given {
            Some(path) => vec![path.clone()],
            None => FONT_PATHS.iter().map(|s| s.to_string()).collect(),
        };
        for path in &candidates {
            if let Ok(bytes) = std::fs::read(path) {
                // plotters keeps fonts for the whole run.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
            }
        }
        Err(match given {
            Some(path) => format!("QTRACE_FONT={path}: not a TrueType font that can be read"),
            None => {
                "charts need a TrueType font: install fonts-dejavu-core or set QTRACE_FONT".into()
            }
        })
    })
    .clone()
}

/// A named series of (x, y) points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

pub struct Chart<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub log_x: bool,
    pub log_y: bool,
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { (0.1, 1.0) } else { (0.0, 1.0) };
    }
    if log {
        (lo / 1.5, hi * 1.5)
    } else {
        let pad = ((hi - lo) * 0.05).max(1e-9);
        (lo - pad, hi + pad)
    }
}

/// Axis numbers without float noise: 3 significant digits, scientific when tiny or huge.
fn short(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e4 || v.abs() < 1e-2 {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Draws `series` as lines with markers into a 720 x 420 PNG at `path`.
pub fn line_chart(path: &Path, chart: &Chart<'_>, series: &[Series]) -> Result<(), String> {
    ensure_font()?;
    let (w, h) = (720u32, 420u32);
    let mut buffer = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let xs = range(
            series.iter().flat_map(|s| s.points.iter().map(|p| p.0)),
            chart.log_x,
        );
        let ys = range(
            series.iter().flat_map(|s| s.points.iter().map(|p| p.1)),
            chart.log_y,
        );
        let mut builder = ChartBuilder::on(&root);
        builder
            .caption(chart.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70);
        // plotters types differ per axis scale, hence four arms.
        macro_rules! draw {
            ($x:expr, $y:expr) => {{
                let mut ctx = builder
                    .build_cartesian_2d($x, $y)
                    .map_err(|e| e.to_string())?;
                ctx.configure_mesh()
                    .x_labels(8)
                    .y_labels(8)
                    .light_line_style(RGBColor(242, 242, 242))
                    .x_label_formatter(&|v| short(*v))
                    .y_label_formatter(&|v| short(*v))
                    .x_desc(chart.x_label)
                    .y_desc(chart.y_label)
                    .label_style(("sans-serif", 13))
                    .draw()
                    .map_err(|e| e.to_string())?;
                for (i, s) in series.iter().enumerate() {
                    let colour = PALETTE[i % PALETTE.len()];
                    let pts: Vec<(f64, f64)> = s
                        .points
                        .iter()
                        .cloned()
                        .filter(|(x, y)| {
                            x.is_finite()
                                && y.is_finite()
                                && (!chart.log_x || *x > 0.0)
                                && (!chart.log_y || *y > 0.0)
                        })
                        .collect();
                    ctx.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                        .map_err(|e| e.to_string())?
                        .label(s.name.as_str())
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                        });
                    if pts.len() <= 64 {
                        ctx.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                            .map_err(|e| e.to_string())?;
                    }
                }
                ctx.configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 13))
                    .draw()
                    .map_err(|e| e.to_string())?;
            }};
        }
        match (chart.log_x, chart.log_y) {
            (true, true) => draw!((xs.0..xs.1).log_scale(), (ys.0..ys.1).log_scale()),
            (true, false) => draw!((xs.0..xs.1).log_scale(), ys.0..ys.1),
            (false, true) => draw!(xs.0..xs.1, (ys.0..ys.1).log_scale()),
            (false, false) => draw!(xs.0..xs.1, ys.0..ys.1),
        }
        root.present().map_err(|e| e.to_string())?;
    }
    write_atomically(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &buffer,
            w,
            h,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })
    .map_err(|e| e.to_string())
}
