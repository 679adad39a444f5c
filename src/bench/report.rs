//! The report files: CSV and JSON of every number, PNG charts, and one static
//! HTML page that shows it all side by side.

use super::charts::{line_chart, Chart, Series};
use super::eval::{Report, SceneReport};
use super::BenchError;
use crate::image::write_atomically;
use std::fmt::Write as _;
use std::path::Path;

fn write_text(path: &Path, text: &str) -> Result<(), BenchError> {
    write_atomically(path, |tmp| {
        std::fs::write(tmp, text).map_err(|e| e.to_string())
    })?;
    Ok(())
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x}"))
}

/// CSV files, one row per number kind; headers are the column names tests check.
fn write_csv(report: &Report, out: &Path) -> Result<(), BenchError> {
    let mut checkpoints =
        String::from("scene,config,spp,seconds,mse,rel_mse,mape,zero_contribution_fraction\n");
    let mut passes =
        String::from("scene,config,pass,zero_contribution_fraction,mean_path_length,rays,loss\n");
    let mut equal = String::from("scene,config,equal_time_seconds,mse,rel_mse,mape\n");
    let mut gpu = String::from("scene,config,pass_name,count,total_ms,median_ms,min_ms,max_ms\n");
    let mut summary = String::from(
        "scene,config,spp,wall_seconds,samples_per_second,rays_per_second,zero_contribution_fraction,mean_path_length,final_rel_mse,equal_time_rel_mse,guide_bytes,over_plain\n",
    );
    for s in &report.scenes {
        for r in &s.runs {
            for c in &r.checkpoints {
                let _ = writeln!(
                    checkpoints,
                    "{},{},{},{},{},{},{},{}",
                    s.name,
                    r.config,
                    c.spp,
                    c.seconds,
                    c.error.mse,
                    c.error.rel_mse,
                    c.error.mape,
                    c.zero_contribution_fraction
                );
            }
            for p in &r.passes {
                let _ = writeln!(
                    passes,
                    "{},{},{},{},{},{},{}",
                    s.name,
                    r.config,
                    p.pass,
                    p.zero_contribution_fraction,
                    p.mean_path_length,
                    p.rays,
                    opt(p.loss)
                );
            }
            let e = &r.error_at_equal_time;
            let _ = writeln!(
                equal,
                "{},{},{},{},{},{}",
                s.name, r.config, s.equal_time_seconds, e.mse, e.rel_mse, e.mape
            );
            for t in &r.gpu_passes {
                let _ = writeln!(
                    gpu,
                    "{},{},{},{},{},{},{},{}",
                    s.name, r.config, t.name, t.count, t.total_ms, t.median_ms, t.min_ms, t.max_ms
                );
            }
            let last = r.checkpoints.last();
            let _ = writeln!(
                summary,
                "{},{},{},{},{},{},{},{},{},{},{},{}",
                s.name,
                r.config,
                last.map_or(0, |c| c.spp),
                r.wall_seconds,
                r.samples_per_second,
                r.rays_per_second,
                r.zero_contribution_fraction,
                r.mean_path_length,
                last.map_or(f64::NAN, |c| c.error.rel_mse),
                e.rel_mse,
                r.guide_bytes,
                opt(r.over_plain)
            );
        }
    }
    write_text(&out.join("checkpoints.csv"), &checkpoints)?;
    write_text(&out.join("passes.csv"), &passes)?;
    write_text(&out.join("equal_time.csv"), &equal)?;
    write_text(&out.join("gpu_passes.csv"), &gpu)?;
    write_text(&out.join("summary.csv"), &summary)?;
    Ok(())
}

/// The charts of one scene; returns their paths relative to the report.
fn write_charts(s: &SceneReport, out: &Path) -> Result<Vec<(String, String)>, BenchError> {
    let dir = out.join(&s.name);
    let series = |f: &dyn Fn(&super::eval::RunReport) -> Vec<(f64, f64)>| -> Vec<Series> {
        s.runs
            .iter()
            .map(|r| Series {
                name: r.config.clone(),
                points: f(r),
            })
            .collect()
    };
    let has_loss = s
        .runs
        .iter()
        .any(|r| r.passes.iter().any(|p| p.loss.is_some()));
    let mut charts: Vec<(&str, Chart<'_>, Vec<Series>)> = vec![
        (
            "error-vs-spp",
            Chart {
                title: "relMSE vs samples per pixel",
                x_label: "spp",
                y_label: "relMSE",
                log_x: true,
                log_y: true,
            },
            series(&|r| {
                r.checkpoints
                    .iter()
                    .map(|c| (c.spp as f64, c.error.rel_mse))
                    .collect()
            }),
        ),
        (
            "error-vs-time",
            Chart {
                title: "relMSE vs render time",
                x_label: "seconds",
                y_label: "relMSE",
                log_x: true,
                log_y: true,
            },
            series(&|r| {
                r.checkpoints
                    .iter()
                    .map(|c| (c.seconds, c.error.rel_mse))
                    .collect()
            }),
        ),
        (
            "zero-vs-pass",
            Chart {
                title: "zero-contribution paths per pass",
                x_label: "pass",
                y_label: "fraction",
                log_x: false,
                log_y: false,
            },
            series(&|r| {
                r.passes
                    .iter()
                    .map(|p| (p.pass as f64, p.zero_contribution_fraction))
                    .collect()
            }),
        ),
        (
            "length-vs-pass",
            Chart {
                title: "mean path length per pass",
                x_label: "pass",
                y_label: "surface hits",
                log_x: false,
                log_y: false,
            },
            series(&|r| {
                r.passes
                    .iter()
                    .map(|p| (p.pass as f64, p.mean_path_length))
                    .collect()
            }),
        ),
    ];
    if has_loss {
        charts.push((
            "loss-vs-pass",
            Chart {
                title: "training loss per pass (mean squared TD error)",
                x_label: "pass",
                y_label: "loss",
                log_x: false,
                log_y: true,
            },
            s.runs
                .iter()
                .filter(|r| r.passes.iter().any(|p| p.loss.is_some()))
                .map(|r| Series {
                    name: r.config.clone(),
                    points: r
                        .passes
                        .iter()
                        .filter_map(|p| p.loss.map(|l| (p.pass as f64, l)))
                        .collect(),
                })
                .collect(),
        ));
    }
    let mut paths = Vec::new();
    for (stem, chart, data) in &charts {
        let path = dir.join(format!("{stem}.png"));
        line_chart(&path, chart, data).map_err(|e| BenchError::Io(path.clone(), e))?;
        paths.push((chart.title.to_string(), format!("{}/{stem}.png", s.name)));
    }
    Ok(paths)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px;max-width:1400px;color:#222}
table{border-collapse:collapse;margin:8px 0 20px}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
.row{display:flex;flex-wrap:wrap;gap:12px}.cell{text-align:center;font-size:12px}
.cell img{image-rendering:pixelated;border:1px solid #999}
.crop{width:192px;height:192px;border:1px solid #999;background-repeat:no-repeat;image-rendering:pixelated}
.win{font-weight:bold;color:#075}";

/// An enlarged crop of an image: the region around `centre` (fractions of
/// width and height), zoomed 3×.
fn crop(src: &str, width: u32, height: u32, centre: [f64; 2]) -> String {
    let zoom = 3.0 * 192.0 / width.max(height) as f64;
    let (w, h) = (width as f64 * zoom, height as f64 * zoom);
    // Keep the 192-pixel window inside the enlarged image.
    let cx = (centre[0] * w).clamp(96.0, (w - 96.0).max(96.0));
    let cy = (centre[1] * h).clamp(96.0, (h - 96.0).max(96.0));
    format!(
        "<div class=\"crop\" style=\"background-image:url('{}');background-size:{w:.0}px {h:.0}px;background-position:{:.0}px {:.0}px\"></div>",
        esc(src),
        -(cx - 96.0),
        -(cy - 96.0)
    )
}

/// A scene's table of its methods' figures, winners marked.
fn runs_table(h: &mut String, s: &SceneReport) {
    *h += "<table><tr><th>method</th><th>zero-contribution</th><th>mean path length</th><th>Mrays/s</th><th>samples/s</th>\
          <th>relMSE (final)</th><th>MAPE (final)</th><th>relMSE at equal time</th><th>MAPE at equal time</th><th>time of the later half of samples, over the first method's</th><th>relMSE at plain path tracing's time (with NEE as it has) over its</th><th>guide memory</th><th>GPU ms per pass</th></tr>";
    for r in &s.runs {
        let last = r.checkpoints.last();
        let win = |cond: bool, text: String| {
            if cond {
                format!("<span class=\"win\">{text}</span>")
            } else {
                text
            }
        };
        let gpu: Vec<String> = r
            .gpu_passes
            .iter()
            .map(|t| format!("{} {:.2}", t.name, t.median_ms))
            .collect();
        // A guide that stood back rendered the rest as plain path tracing.
        let method = match r.guide_stood_back_after {
            Some(n) => format!(
                "{} <small>(stood back after {n} passes: {})</small>",
                esc(&r.config),
                esc(r.guide_stood_back_because.as_deref().unwrap_or("")),
            ),
            None => esc(&r.config),
        };
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td><td>{:.0}</td><td>{}</td><td>{:.4}</td><td>{}</td><td>{:.4}</td><td>{}</td><td>{}</td><td>{:.1} MiB</td><td>{}</td></tr>",
            method,
            win(r.config == s.summary.fewest_zero_contribution, format!("{:.1}%", 100.0 * r.zero_contribution_fraction)),
            r.mean_path_length,
            r.rays_per_second / 1e6,
            r.samples_per_second,
            win(r.config == s.summary.lowest_error_equal_spp, format!("{:.4}", last.map_or(f64::NAN, |c| c.error.rel_mse))),
            last.map_or(f64::NAN, |c| c.error.mape),
            win(r.config == s.summary.lowest_error_equal_time, format!("{:.4}{}", r.error_at_equal_time.rel_mse, if r.equal_time_extrapolated { "*" } else { "" })),
            r.error_at_equal_time.mape,
            r.later_half_cost.map_or("-".to_string(), |c| format!("{c:.2}×")),
            r.over_plain.map_or("-".to_string(), |c| format!("{c:.2}×")),
            r.guide_bytes as f64 / (1024.0 * 1024.0),
            esc(&gpu.join(", "))
        );
    }
    *h += "</table>";
}

/// A scene's images side by side per sample count, with crops, and its
/// reference beside them.
fn images_table(h: &mut String, spp_list: &[u32], s: &SceneReport) {
    let spps: Vec<u32> = spp_list.to_vec();
    *h += "<h3>Images</h3><table><tr><th>spp</th>";
    for r in &s.runs {
        let _ = write!(h, "<th>{}</th>", esc(&r.config));
    }
    *h += "<th>reference</th></tr>";
    let reference = format!("{}/reference.png", s.name);
    for (row, spp) in spps.iter().rev().enumerate() {
        let _ = write!(h, "<tr><td>{spp}</td>");
        for r in &s.runs {
            match r
                .checkpoints
                .iter()
                .find(|c| c.spp == *spp && c.png.is_some())
            {
                Some(c) => {
                    let png = c.png.as_deref().unwrap_or_default();
                    let _ = write!(
                        h,
                        "<td><div class=\"row\"><div class=\"cell\"><img src=\"{0}\" width=\"192\" height=\"192\"><br>relMSE {1:.4} · MAPE {2:.4}</div>{3}</div></td>",
                        esc(png),
                        c.error.rel_mse,
                        c.error.mape,
                        crop(png, s.width, s.height, s.crop_centre)
                    );
                }
                None => *h += "<td></td>",
            }
        }
        // The reference once, beside all rows.
        if row == 0 {
            let _ = write!(
                h,
                "<td rowspan=\"{0}\" style=\"vertical-align:top\"><div class=\"cell\"><img src=\"{1}\" width=\"192\" height=\"192\"><br>{2}</div>{3}</td>",
                spps.len(),
                esc(&reference),
                s.reference_spp.map_or("given".to_string(), |n| format!("pt+nee, {n} spp")),
                crop(&reference, s.width, s.height, s.crop_centre)
            );
        }
        *h += "</tr>";
    }
}

/// Pictures of what each guide of a scene learned.
fn learned_pictures(h: &mut String, s: &SceneReport) {
    for r in s.runs.iter().filter(|r| r.learned.is_some()) {
        let l = r.learned.as_ref().unwrap();
        let _ = write!(
            h,
            "<h3>What {} learned</h3><div class=\"row\">",
            esc(&r.config)
        );
        if let Some(voronoi) = &l.voronoi {
            let _ = write!(
                h,
                "<div class=\"cell\"><img src=\"{}\" width=\"256\"><br>Voronoi regions: \
                 each pixel coloured by the radiance volume its first hit uses</div>",
                esc(voronoi)
            );
        }
        if let Some((choice, legend)) = &l.light_choice {
            let _ = write!(
                h,
                "<div class=\"cell\"><img src=\"{}\" width=\"256\"><br>Which light NEE picks: \
                 each pixel in the lights' colours ({}), mixed by the probabilities its volume learned</div>",
                esc(choice),
                esc(legend)
            );
        }
        let _ = write!(
            h,
            "<div class=\"cell\"><img src=\"{}\" height=\"120\"><br>Q hemispheres at {}, \
             seen from above; brighter = more incoming radiance, relative to each one's largest</div></div>",
            esc(&l.hemispheres),
            esc(&l.hemispheres_at)
        );
    }
}

fn write_html(
    report: &Report,
    charts: &[Vec<(String, String)>],
    out: &Path,
) -> Result<(), BenchError> {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>qtrace bench</title><style>{STYLE}</style></head><body>"
    );
    let _ = write!(
        h,
        "<h1>qtrace evaluation</h1><p>Device: {}. Methods: {}. Images at {} spp. Error is against the reference named per scene; \
         equal time is the time the fastest method needed for its largest sample count, other methods' errors interpolated there (log–log; \
         * marks one extrapolated from a method's first checkpoint, relMSE as 1/time, where equal time came before it). \
         A scene's methods render side by side, a batch of passes each in turn, each timed by its own batches only. \
         Numbers: <a href=\"summary.csv\">summary.csv</a>, <a href=\"checkpoints.csv\">checkpoints.csv</a>, \
         <a href=\"passes.csv\">passes.csv</a>, <a href=\"equal_time.csv\">equal_time.csv</a>, \
         <a href=\"gpu_passes.csv\">gpu_passes.csv</a>, <a href=\"results.json\">results.json</a>.</p>",
        esc(&report.device),
        esc(&report.configs.join(", ")),
        report.spp_list.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(", ")
    );
    // The answers first: one line per scene.
    let _ = write!(
        h,
        "<h2>Summary</h2><table><tr><th>scene</th><th>fewest zero-contribution paths</th>\
         <th>lowest relMSE at equal spp</th><th>lowest relMSE at equal time</th><th>equal time (s)</th></tr>"
    );
    for s in &report.scenes {
        let _ = write!(
            h,
            "<tr><td><a href=\"#{0}\">{0}</a></td><td>{1}</td><td>{2}</td><td>{3}</td><td>{4:.3}</td></tr>",
            esc(&s.name),
            esc(&s.summary.fewest_zero_contribution),
            esc(&s.summary.lowest_error_equal_spp),
            esc(&s.summary.lowest_error_equal_time),
            s.equal_time_seconds
        );
    }
    h += "</table>";
    for (s, scene_charts) in report.scenes.iter().zip(charts) {
        let _ = write!(
            h,
            "<h2 id=\"{0}\">{0}</h2><p>{1}, {2}×{3}; reference: {4}{5}. {6}</p>",
            esc(&s.name),
            esc(&s.scene),
            s.width,
            s.height,
            esc(&s.reference),
            s.reference_spp
                .map_or(String::new(), |n| format!(" (pt+nee, {n} spp)")),
            s.reference_rel_mse.map_or(
                "Its own error is unknown.".to_string(),
                |f| format!(
                    "Its own relMSE, from its per-pixel variance, is about {f:.2e}: {:.2}× the smallest error measured against it ({:.2e}), and it adds to every error here.",
                    f / s.smallest_rel_mse,
                    s.smallest_rel_mse
                )
            )
        );
        runs_table(&mut h, s);
        images_table(&mut h, &report.spp_list, s);
        h += "</table><h3>Charts</h3><div class=\"row\">";
        for (title, path) in scene_charts {
            let _ = write!(
                h,
                "<div class=\"cell\"><img src=\"{}\" alt=\"{}\" width=\"576\"></div>",
                esc(path),
                esc(title)
            );
        }
        h += "</div>";
        learned_pictures(&mut h, s);
    }
    h += "</body></html>\n";
    write_text(&out.join("index.html"), &h)
}

/// Writes every report file under `out`.
pub fn write(report: &Report, out: &Path) -> Result<(), BenchError> {
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| BenchError::Io(out.join("results.json"), e.to_string()))?;
    write_text(&out.join("results.json"), &json)?;
    write_csv(report, out)?;
    let charts = report
        .scenes
        .iter()
        .map(|s| write_charts(s, out))
        .collect::<Result<Vec<_>, _>>()?;
    write_html(report, &charts, out)
}
