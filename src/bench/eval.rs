//! The evaluation (docs/benchmark.md): every method on every scene, images and error
//! at a list of sample counts, error at equal time, per-pass statistics and
//! pictures of what was learned.

use super::{learned, BenchError, Config};
use crate::gpu::{GpuContext, PassTiming};
use crate::guide::{GuideSources, SarsaGuide};
use crate::image::{self, ErrorMetrics, Image};
use crate::render::settings::MAX_SPP;
use crate::render::{
    Checkpoint, Control, Method, Overrides, PassRecord, RenderSettings, Renderer, Run,
    SettingsError,
};
use crate::scene::Scene;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub struct EvalPlan {
    pub scenes: Vec<PathBuf>,
    pub configs: Vec<Config>,
    /// Sample counts at which images are kept (sorted, distinct).
    pub spp_list: Vec<u32>,
    pub width: u32,
    pub height: u32,
    /// A reference image for a single scene; otherwise one is rendered and cached.
    pub reference: Option<PathBuf>,
    pub reference_spp: u32,
    pub seed: u32,
    pub out: PathBuf,
    pub cache_dir: PathBuf,
    /// Guide settings beyond each scene's tables.
    pub guides: GuideSources,
    /// XML scenes' `-D name=value` parameters.
    pub defines: Vec<(String, String)>,
    /// Each method renders for this many seconds of its own render time,
    /// instead of to the largest of `spp_list`.
    pub seconds: Option<f64>,
}

impl EvalPlan {
    /// Small images and few samples: seconds per scene on lavapipe.
    pub fn quick(scenes: Vec<PathBuf>, configs: Vec<Config>, out: PathBuf) -> Self {
        Self {
            scenes,
            configs,
            spp_list: vec![1, 4, 16, 32],
            width: 64,
            height: 64,
            reference: None,
            reference_spp: 256,
            seed: 1,
            out,
            cache_dir: default_cache_dir(),
            guides: GuideSources::default(),
            defines: Vec::new(),
            seconds: None,
        }
    }

    /// Sorts and dedups the sample counts, and checks the plan is one a
    /// bench can run; the message names the option.
    pub fn validate(&mut self) -> Result<(), String> {
        self.spp_list.sort_unstable();
        self.spp_list.dedup();
        let max = crate::render::settings::MAX_SPP;
        if self.spp_list.first() == Some(&0) || self.spp_list.last().is_some_and(|&n| n > max) {
            return Err(format!("--spp-list values must lie in 1..={max}"));
        }
        if self.spp_list.is_empty() || self.configs.is_empty() {
            return Err("bench needs at least one method and one sample count".into());
        }
        if self.reference.is_some() && self.scenes.len() != 1 {
            return Err(
                "--reference applies to one scene; give one scene or let bench render references"
                    .into(),
            );
        }
        if self.reference_spp == 0 {
            return Err("--reference-spp must be at least 1".into());
        }
        let most = crate::render::settings::MAX_SECONDS;
        if let Some(t) = self
            .seconds
            .filter(|t| !(t.is_finite() && *t > 0.0 && *t <= most))
        {
            return Err(format!("--seconds {t} must be positive and at most {most}"));
        }
        Ok(())
    }
}

/// `$QTRACE_CACHE`, else `$XDG_CACHE_HOME/qtrace`, else `~/.cache/qtrace`.
pub fn default_cache_dir() -> PathBuf {
    if let Ok(d) = std::env::var("QTRACE_CACHE") {
        return PathBuf::from(d);
    }
    let base = std::env::var("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|_| std::env::var("HOME").map(|h| Path::new(&h).join(".cache")))
        .unwrap_or_else(|_| std::env::temp_dir());
    base.join("qtrace")
}

#[derive(Clone, Debug, Serialize)]
pub struct CheckpointRow {
    pub spp: u32,
    pub seconds: f64,
    #[serde(flatten)]
    pub error: ErrorMetrics,
    pub zero_contribution_fraction: f64,
    /// Relative paths under the report directory, where an image was kept.
    pub png: Option<String>,
    pub exr: Option<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct LearnedPictures {
    /// Voronoi regions of the radiance volumes (guides that have volumes).
    pub voronoi: Option<String>,
    /// Which light NEE picks at each volume (guides that learn it), and
    /// which colour is which light.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_choice: Option<(String, String)>,
    pub hemispheres: String,
    /// Where the hemispheres are, for their caption.
    pub hemispheres_at: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub config: String,
    pub checkpoints: Vec<CheckpointRow>,
    pub passes: Vec<PassRecord>,
    pub gpu_passes: Vec<PassTiming>,
    pub wall_seconds: f64,
    pub rays_per_second: f64,
    pub samples_per_second: f64,
    pub zero_contribution_fraction: f64,
    pub mean_path_length: f64,
    pub guide_bytes: u64,
    /// The passes after which the guide stood back, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide_stood_back_after: Option<u32>,
    /// Why (see `RenderStats::stood_back_because`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide_stood_back_because: Option<String>,
    /// Error interpolated (log-log) at the scene's equal-time budget.
    pub error_at_equal_time: ErrorMetrics,
    /// Whether that budget fell before the first checkpoint, so the error
    /// is extrapolated from it (see `error_at_time`).
    pub equal_time_extrapolated: bool,
    /// Its later half of samples' time over the scene's first method's
    /// (see `later_half_cost`).
    pub later_half_cost: Option<f64>,
    /// For a guided run, its relMSE at the time its plain counterpart (`pt`,
    /// with NEE as it has) took for all its samples, over that counterpart's
    /// relMSE: the equal-time figure a guide is judged by (see `over_plain`).
    pub over_plain: Option<f64>,
    pub learned: Option<LearnedPictures>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Config with the fewest zero-contribution paths over the whole render.
    pub fewest_zero_contribution: String,
    /// Config with the lowest relMSE at the largest sample count.
    pub lowest_error_equal_spp: String,
    /// Config with the lowest relMSE at equal time.
    pub lowest_error_equal_time: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    pub scene: String,
    /// File-name-safe short name; the scene's folder in the report.
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub reference: String,
    pub reference_spp: Option<u32>,
    /// The reference's own expected relMSE, from its per-pixel sample
    /// variance (unknown for a given reference): it adds to every error.
    pub reference_rel_mse: Option<f64>,
    /// The smallest relMSE measured against the reference (at equal samples
    /// or at equal time), to compare the reference's own error with.
    pub smallest_rel_mse: f64,
    pub equal_time_seconds: f64,
    /// Where the crops look (fractions of width and height): the region where
    /// the first method's final image is farthest from the reference.
    pub crop_centre: [f64; 2],
    pub runs: Vec<RunReport>,
    pub summary: Summary,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub device: String,
    pub spp_list: Vec<u32>,
    pub configs: Vec<String>,
    pub scenes: Vec<SceneReport>,
}

/// One configuration's render in [`evaluate`], and what it has kept so far.
struct Stepped {
    label: String,
    message: String,
    run_dir: PathBuf,
    renderer: Renderer,
    run: Run,
    rows: Vec<CheckpointRow>,
    kept: Vec<Image>,
    /// Progress counted so far: passes, or with a time budget milliseconds.
    units: u64,
}

/// FNV-1a, stable across runs and builds (unlike std's hasher).
fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

fn scene_key(path: &Path, scene: &Scene, plan: &EvalPlan, max_depth: u32) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325;
    h = fnv1a(&std::fs::read(path).unwrap_or_default(), h);
    h = fnv1a(bytemuck::cast_slice(&scene.triangles), h);
    // Materials come from the MTL, which the scene file does not contain.
    for m in &scene.materials {
        h = fnv1a(bytemuck::bytes_of(&m.gpu()), h);
    }
    let settings = format!(
        "{}x{} spp{} depth{} seed{} v{}",
        plan.width,
        plan.height,
        plan.reference_spp,
        max_depth,
        plan.seed,
        env!("CARGO_PKG_VERSION")
    );
    fnv1a(settings.as_bytes(), h)
}

fn short_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| {
            s.to_string_lossy()
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect()
        })
        .unwrap_or_else(|| "scene".into())
}

/// Centre (fractions) of the 16×16-pixel block with the largest squared error.
fn worst_block(image: &Image, reference: &Image) -> [f64; 2] {
    let b = 16usize.min(image.width).min(image.height).max(1);
    let mut best = (f64::NEG_INFINITY, [0.5, 0.5]);
    for by in (0..image.height).step_by(b) {
        for bx in (0..image.width).step_by(b) {
            let mut e = 0.0f64;
            for y in by..(by + b).min(image.height) {
                for x in bx..(bx + b).min(image.width) {
                    let (p, q) = (
                        image.pixels[y * image.width + x],
                        reference.pixels[y * image.width + x],
                    );
                    e += (0..3).map(|c| ((p[c] - q[c]) as f64).powi(2)).sum::<f64>();
                }
            }
            if e > best.0 {
                let cx = (bx as f64 + b as f64 / 2.0) / image.width as f64;
                let cy = (by as f64 + b as f64 / 2.0) / image.height as f64;
                best = (e, [cx, cy]);
            }
        }
    }
    best.1
}

/// Samples per pixel a run had rendered by time `t`: linear in time between
/// its checkpoints, and before the first in proportion to it.
pub fn spp_at_time(rows: &[CheckpointRow], t: f64) -> f64 {
    let Some(first) = rows.first() else {
        return 0.0;
    };
    if t <= first.seconds {
        return first.spp as f64 * t / first.seconds.max(f64::MIN_POSITIVE);
    }
    for w in rows.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if t <= b.seconds {
            let f = (t - a.seconds) / (b.seconds - a.seconds).max(f64::MIN_POSITIVE);
            return a.spp as f64 + f * (b.spp as f64 - a.spp as f64);
        }
    }
    rows.last().map_or(0.0, |r| r.spp as f64)
}

/// Below this many samples per pixel at equal time, a guided run was still
/// learning in most of its passes (every pass up to `thin_after`, 16 by
/// default, then every other to twice that): equal time then weighs its
/// start-up rather than a render.
pub const LEARNING_SPP: f64 = 32.0;

/// Error at time `t` by log-log interpolation between checkpoints. Before
/// the first one it is extrapolated as Monte Carlo error falls: MSE and
/// relMSE as 1/time, MAPE as 1/sqrt(time) (`t_extrapolated` says so).
pub fn error_at_time(rows: &[CheckpointRow], t: f64) -> ErrorMetrics {
    let first = &rows[0];
    if t_extrapolated(rows, t) {
        let scale = first.seconds / t;
        return ErrorMetrics {
            mse: first.error.mse * scale,
            rel_mse: first.error.rel_mse * scale,
            mape: first.error.mape * scale.sqrt(),
        };
    }
    if t <= first.seconds || rows.len() == 1 {
        return first.error;
    }
    for w in rows.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if t <= b.seconds {
            let f = ((t / a.seconds).ln() / (b.seconds / a.seconds).ln()).clamp(0.0, 1.0);
            let lerp = |x: f64, y: f64| {
                if x > 0.0 && y > 0.0 {
                    (x.ln() + f * (y.ln() - x.ln())).exp()
                } else {
                    x + f * (y - x)
                }
            };
            return ErrorMetrics {
                mse: lerp(a.error.mse, b.error.mse),
                rel_mse: lerp(a.error.rel_mse, b.error.rel_mse),
                mape: lerp(a.error.mape, b.error.mape),
            };
        }
    }
    rows[rows.len() - 1].error
}

/// Whether time `t` falls before the first checkpoint.
pub fn t_extrapolated(rows: &[CheckpointRow], t: f64) -> bool {
    t > 0.0 && t < rows[0].seconds
}

/// The time `rows` took for their later half of samples (from N/2 to N spp,
/// N the largest checkpoint both have with its half) over the time `base`
/// took for the same: what a pass costs once a guide's learning has thinned
/// out, against plain path tracing's. None without such checkpoints.
pub fn later_half_cost(rows: &[CheckpointRow], base: &[CheckpointRow]) -> Option<f64> {
    let at =
        |rows: &[CheckpointRow], spp: u32| rows.iter().find(|r| r.spp == spp).map(|r| r.seconds);
    let span = |rows: &[CheckpointRow], n: u32| Some(at(rows, n)? - at(rows, n / 2)?);
    let (run, plain) = rows
        .iter()
        .rev()
        .filter(|r| r.spp >= 2)
        .find_map(|r| Some((span(rows, r.spp)?, span(base, r.spp)?)))?;
    (plain > 0.0).then(|| run / plain)
}

/// The relMSE of `rows` at the time `plain` took for all its samples, over
/// the relMSE `plain` ended with: a guide against plain path tracing at
/// plain path tracing's time (under 1 the guide wins), each with its own
/// NEE. The scene's equal time is the fastest run's, `pt`'s where it runs,
/// which for a method with NEE falls early, while its guide still learns.
/// None without checkpoints or with an exact plain image.
pub fn over_plain(rows: &[CheckpointRow], plain: &[CheckpointRow]) -> Option<f64> {
    let last = plain.last()?;
    (!rows.is_empty() && last.error.rel_mse > 0.0)
        .then(|| error_at_time(rows, last.seconds).rel_mse / last.error.rel_mse)
}

/// What the evaluation is doing, for a progress bar.
pub struct EvalProgress<'a> {
    pub message: &'a str,
    /// Sample passes done and planned, over the whole evaluation.
    pub done: u64,
    pub total: u64,
}

/// A cached reference's own relMSE, its samples per pixel and, when known,
/// the seconds its rendering took, beside its image (none for a reference
/// cached without them).
fn read_floor(path: &Path) -> Option<(f64, u32, Option<f64>)> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut words = text.split_whitespace();
    let floor = words.next()?.parse().ok()?;
    let spp = words.next()?.parse().ok()?;
    Some((floor, spp, words.next().and_then(|w| w.parse().ok())))
}

fn write_floor(path: &Path, floor: f64, spp: u32, seconds: Option<f64>) -> Result<(), BenchError> {
    let seconds = seconds.map_or(String::new(), |s| format!(" {s:e}"));
    std::fs::write(path, format!("{floor:e} {spp}{seconds}\n"))
        .map_err(|e| BenchError::Io(path.to_path_buf(), e.to_string()))
}

/// A refinement that doubles a reference takes about as long as the
/// reference took so far; past 8x `--reference-spp` it goes on only while
/// that is under this (a fast GPU, a small image).
pub const QUICK_DOUBLING_SECONDS: f64 = 60.0;

/// The samples to add to a reference of `spp` whose own relMSE `floor` is
/// not yet under a tenth of `smallest`, the error measured against it, or
/// None when refining stops: up to `cap` (8x `--reference-spp`) by
/// doubling, beyond it while a doubling is quick (`seconds`: the time the
/// reference took so far), never past MAX_SPP.
pub fn refinement(
    floor: f64,
    smallest: f64,
    spp: u32,
    cap: u32,
    seconds: Option<f64>,
) -> Option<u32> {
    if floor <= 0.1 * smallest || spp >= MAX_SPP {
        return None;
    }
    if spp < cap {
        return Some(spp.min(cap - spp));
    }
    seconds
        .is_some_and(|s| s <= QUICK_DOUBLING_SECONDS)
        .then(|| spp.min(MAX_SPP - spp))
}

fn render_settings(
    scene: &Scene,
    plan: &EvalPlan,
    config: &Config,
    (spp, time): (Option<u32>, Option<f64>),
    seed: u32,
) -> Result<RenderSettings, BenchError> {
    let guide = plan
        .guides
        .resolve(scene, config.method.name())
        .map_err(|e| BenchError::Render(SettingsError(e).into()))?;
    let o = Overrides {
        method: Some(config.method),
        spp,
        time,
        width: Some(plan.width),
        height: Some(plan.height),
        nee: config.nee,
        seed: Some(seed),
        guide,
        ..Default::default()
    };
    RenderSettings::resolve(scene, &o).map_err(|e| BenchError::Render(e.into()))
}

/// Writes a guide's pictures of its volumes under `dir` (see
/// `learned::volume_pictures`): the Voronoi PNG's path, and where it
/// learns NEE's choice of light, that picture's path and legend.
fn write_volume_pictures(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    plan: &EvalPlan,
    dir: &Path,
) -> Result<(String, Option<(String, String)>), BenchError> {
    let (voronoi, light_choice) =
        learned::volume_pictures(ctx, scene, guide, plan.width.max(128), plan.height.max(128))?;
    let (vpng, _) = write_image(&voronoi, dir, "voronoi", &plan.out)?;
    let light_choice = light_choice
        .map(|(image, legend)| {
            write_image(&image, dir, "light-choice", &plan.out).map(|(png, _)| (png, legend))
        })
        .transpose()?;
    Ok((vpng, light_choice))
}

fn write_image(
    image: &Image,
    dir: &Path,
    stem: &str,
    out: &Path,
) -> Result<(String, String), BenchError> {
    let exr = dir.join(format!("{stem}.exr"));
    let png = dir.join(format!("{stem}.png"));
    image.write_exr(&exr)?;
    image.write_png(&png)?;
    let rel = |p: &Path| p.strip_prefix(out).unwrap_or(p).display().to_string();
    Ok((rel(&png), rel(&exr)))
}

/// Every configuration's render of a scene, to its last checkpoint, with
/// each checkpoint's error against `reference` and images kept.
/// Every configuration's render, stepped a batch each in turn, so
/// that a change in the machine's speed (this one drifts by 15-30%
/// over minutes) falls on all of them alike rather than on whichever
/// rendered then: each render's clock counts its own batches only.
fn render_configs(
    ctx: &Arc<GpuContext>,
    plan: &EvalPlan,
    (scene, name, dir): (&Scene, &str, &Path),
    reference: &Image,
    checkpoints: &[u32],
    (done, total): (&mut u64, u64),
    progress: &mut dyn FnMut(&EvalProgress<'_>),
) -> Result<Vec<Stepped>, BenchError> {
    let max_spp = *plan.spp_list.iter().max().unwrap_or(&1);
    let mut renders = Vec::new();
    for config in &plan.configs {
        let label = config.label();
        let run_dir = dir.join(&label);
        std::fs::create_dir_all(&run_dir)
            .map_err(|e| BenchError::Io(run_dir.clone(), e.to_string()))?;
        let budget = match plan.seconds {
            Some(t) => (None, Some(t)),
            None => (Some(max_spp), None),
        };
        let settings = render_settings(scene, plan, config, budget, plan.seed)?;
        let mut renderer = Renderer::new(ctx, scene, settings)?;
        let run = renderer.start();
        renders.push(Stepped {
            message: format!("{name}: {label}"),
            label,
            run_dir,
            renderer,
            run,
            rows: Vec::new(),
            kept: Vec::new(),
            units: 0,
        });
    }
    let control = Control {
        at_passes: checkpoints,
        ..Default::default()
    };
    while renders.iter().any(|r| !r.run.finished()) {
        for r in renders.iter_mut().filter(|r| !r.run.finished()) {
            let mut failure: Option<BenchError> = None;
            let (rows, kept, run_dir, units) = (&mut r.rows, &mut r.kept, &r.run_dir, &mut r.units);
            let timed = plan.seconds.is_some();
            r.renderer.step(
                &mut r.run,
                &mut |pr| {
                    let now = if timed {
                        (pr.elapsed * 1e3) as u64
                    } else {
                        pr.passes_done as u64
                    };
                    *done += now.saturating_sub(*units);
                    *units = now;
                    progress(&EvalProgress {
                        message: &r.message,
                        done: *done,
                        total,
                    })
                },
                &control,
                &mut |c: &Checkpoint| {
                    let error = match image::compare(&c.image, reference) {
                        Ok(e) => e,
                        Err(e) => {
                            failure.get_or_insert(e.into());
                            return;
                        }
                    };
                    let (png, exr) = if plan.spp_list.contains(&c.spp) {
                        match write_image(
                            &c.image,
                            run_dir,
                            &format!("spp-{:04}", c.spp),
                            &plan.out,
                        ) {
                            Ok((p, e)) => (Some(p), Some(e)),
                            Err(e) => {
                                failure.get_or_insert(e);
                                (None, None)
                            }
                        }
                    } else {
                        (None, None)
                    };
                    kept.push(c.image.clone());
                    rows.push(CheckpointRow {
                        spp: c.spp,
                        seconds: c.seconds,
                        error,
                        zero_contribution_fraction: c.zero_contribution_fraction,
                        png,
                        exr,
                    });
                },
            )?;
            if let Some(e) = failure {
                return Err(e);
            }
        }
    }
    Ok(renders)
}

/// Pictures of what a finished render's guide learned, if it has one.
fn learned_pictures(
    ctx: &Arc<GpuContext>,
    plan: &EvalPlan,
    scene: &Scene,
    renderer: &Renderer,
    run_dir: &Path,
) -> Result<Option<LearnedPictures>, BenchError> {
    let Some(guide) = renderer.guide() else {
        return Ok(None);
    };
    // Where it samples from the volumes' tables, their pictures too.
    let (voronoi, light_choice) = match guide.volume_table() {
        Some(table) => {
            let (vpng, choice) = write_volume_pictures(ctx, scene, table, plan, run_dir)?;
            (Some(vpng), choice)
        }
        None => (None, None),
    };
    let (rows, at) = guide.sample_rows(ctx, scene, 6)?;
    let hemis = learned::hemispheres(guide.grid(), &rows, 96);
    let (hpng, _) = write_image(&hemis, run_dir, "hemispheres", &plan.out)?;
    Ok(Some(LearnedPictures {
        voronoi,
        light_choice,
        hemispheres: hpng,
        hemispheres_at: at,
    }))
}

/// A reference rendered here is refined until its own error is under
/// a tenth of the smallest error measured against it (or it has 8x
/// its samples and a doubling would be slow: `refinement`); then
/// every error is measured again.
/// Whether it was refined.
fn refine_reference(
    ctx: &Arc<GpuContext>,
    plan: &EvalPlan,
    (scene, name, dir): (&Scene, &str, &Path),
    reference: &mut SceneReference,
    (runs, images): (&mut [RunReport], &[Vec<Image>]),
    (done, total): (&u64, u64),
    progress: &mut dyn FnMut(&EvalProgress<'_>),
) -> Result<bool, BenchError> {
    let pt = Config {
        method: Method::PT,
        nee: true,
    };
    if let (Some(first_floor), Some(first_spp), None) =
        (reference.rel_mse, reference.spp, plan.reference.as_ref())
    {
        let smallest = |runs: &[RunReport]| {
            runs.iter()
                .filter_map(|r| r.checkpoints.last().map(|c| c.error.rel_mse))
                .fold(f64::INFINITY, f64::min)
        };
        let (mut floor, mut spp, mut seconds) = (first_floor, first_spp, reference.seconds);
        let cap = plan.reference_spp.saturating_mul(8);
        while let Some(more) = refinement(floor, smallest(runs), spp, cap, seconds) {
            let settings = render_settings(
                scene,
                plan,
                &pt,
                (Some(more), None),
                plan.seed.wrapping_add(7919).wrapping_add(spp),
            )?;
            let message = format!("{name}: refining the reference to {} spp", spp + more);
            let out = Renderer::new(ctx, scene, settings)?.run(&mut |pr| {
                progress(&EvalProgress {
                    message: &message,
                    done: *done,
                    total: total.max(*done + pr.passes_done as u64),
                })
            })?;
            let added = image::expected_rel_mse(&out.image, &out.variance, more);
            let (n1, n2) = (spp as f64, more as f64);
            for (p, q) in reference.image.pixels.iter_mut().zip(&out.image.pixels) {
                for c in 0..3 {
                    p[c] = ((p[c] as f64 * n1 + q[c] as f64 * n2) / (n1 + n2)) as f32;
                }
            }
            // Each floor is a variance over a sample count: pool them.
            floor = (n1 * n1 * floor + n2 * n2 * added) / ((n1 + n2) * (n1 + n2));
            // A reference cached without its time: its own, estimated
            // from this refinement's.
            let took = out.stats.wall_seconds;
            seconds = Some(seconds.unwrap_or(took * n1 / n2) + took);
            spp += more;
            for (run, kept) in runs.iter_mut().zip(images) {
                for (row, img) in run.checkpoints.iter_mut().zip(kept) {
                    row.error = image::compare(img, &reference.image)?;
                }
            }
        }
        if spp != first_spp {
            let cached = PathBuf::from(&reference.label);
            reference.image.write_exr(&cached)?;
            write_floor(&cached.with_extension("relmse"), floor, spp, seconds)?;
            write_image(&reference.image, dir, "reference", &plan.out)?;
        }
        reference.rel_mse = Some(floor);
        reference.spp = Some(spp);
        return Ok(spp != first_spp);
    }
    Ok(false)
}

/// Each run against the others: its error at equal time (the budget the
/// fastest configuration needed for all its samples), its cost and its
/// error over plain path tracing's; and which runs win.
fn compare_runs(plan: &EvalPlan, runs: &mut [RunReport]) -> (f64, Summary) {
    let equal_time = runs
        .iter()
        .filter_map(|r| r.checkpoints.last().map(|c| c.seconds))
        .fold(f64::INFINITY, f64::min);
    let first: Vec<CheckpointRow> = runs
        .first()
        .map(|r| r.checkpoints.clone())
        .unwrap_or_default();
    for r in runs.iter_mut() {
        r.error_at_equal_time = error_at_time(&r.checkpoints, equal_time);
        r.equal_time_extrapolated = t_extrapolated(&r.checkpoints, equal_time);
        r.later_half_cost = later_half_cost(&r.checkpoints, &first);
    }
    for (i, c) in plan.configs.iter().enumerate() {
        let label = Config {
            method: Method::PT,
            nee: c.nee,
        }
        .label();
        if c.method != Method::PT {
            runs[i].over_plain = runs
                .iter()
                .find(|r| r.config == label)
                .and_then(|p| over_plain(&runs[i].checkpoints, &p.checkpoints));
        }
    }
    let best = |key: &dyn Fn(&RunReport) -> f64| {
        runs.iter()
            .min_by(|a, b| key(a).total_cmp(&key(b)))
            .map(|r| r.config.clone())
            .unwrap_or_default()
    };
    let summary = Summary {
        fewest_zero_contribution: best(&|r| r.zero_contribution_fraction),
        lowest_error_equal_spp: best(&|r| {
            r.checkpoints
                .last()
                .map_or(f64::INFINITY, |c| c.error.rel_mse)
        }),
        lowest_error_equal_time: best(&|r| r.error_at_equal_time.rel_mse),
    };
    (equal_time, summary)
}

/// A finished run's report, before it is compared with the others.
fn run_report(
    config: String,
    checkpoints: Vec<CheckpointRow>,
    s: crate::render::RenderStats,
    learned: Option<LearnedPictures>,
) -> RunReport {
    let because = s.stood_back_because();
    RunReport {
        config,
        checkpoints,
        passes: s.passes,
        gpu_passes: s.gpu_passes,
        wall_seconds: s.wall_seconds,
        rays_per_second: s.rays_per_second,
        samples_per_second: s.samples_per_second,
        zero_contribution_fraction: s.zero_contribution_fraction,
        mean_path_length: s.mean_path_length,
        guide_bytes: s.guide_bytes,
        guide_stood_back_after: s.guide_stood_back_after,
        guide_stood_back_because: because,
        error_at_equal_time: ErrorMetrics {
            mse: 0.0,
            rel_mse: 0.0,
            mape: 0.0,
        },
        equal_time_extrapolated: false,
        later_half_cost: None,
        over_plain: None,
        learned,
    }
}

/// A scene's reference and what is known of it.
struct SceneReference {
    image: Image,
    /// The file it was read from.
    label: String,
    /// Its samples per pixel and own relMSE, where qtrace rendered it.
    spp: Option<u32>,
    rel_mse: Option<f64>,
    seconds: Option<f64>,
}

/// The reference of scene `name` at `path`: given, cached, or rendered now
/// with pt + NEE (counted in `done` of `total` passes).
fn scene_reference(
    ctx: &Arc<GpuContext>,
    plan: &EvalPlan,
    (path, scene, name): (&Path, &Scene, &str),
    (done, total): (&mut u64, u64),
    progress: &mut dyn FnMut(&EvalProgress<'_>),
) -> Result<SceneReference, BenchError> {
    let pt = Config {
        method: Method::PT,
        nee: true,
    };
    let ref_settings = render_settings(
        scene,
        plan,
        &pt,
        (Some(plan.reference_spp), None),
        plan.seed.wrapping_add(7919),
    )?;
    let reference_passes = plan.reference_spp as u64;
    let (image, label, spp, rel_mse, seconds) = match &plan.reference {
        Some(r) => (
            Image::read_exr(r)?,
            r.display().to_string(),
            None,
            None,
            None,
        ),
        None => {
            std::fs::create_dir_all(&plan.cache_dir)
                .map_err(|e| BenchError::Io(plan.cache_dir.clone(), e.to_string()))?;
            let key = scene_key(path, scene, plan, ref_settings.max_depth);
            let cached = plan
                .cache_dir
                .join(format!("reference-{name}-{key:016x}.exr"));
            let floor_file = cached.with_extension("relmse");
            let cached_floor = read_floor(&floor_file);
            let (image, floor) = match Image::read_exr(&cached) {
                Ok(img) => {
                    *done += reference_passes;
                    (img, cached_floor)
                }
                Err(_) => {
                    let message = format!("{name}: reference (pt+nee, {} spp)", plan.reference_spp);
                    let start = *done;
                    let mut renderer = Renderer::new(ctx, scene, ref_settings)?;
                    let out = renderer.run(&mut |pr| {
                        progress(&EvalProgress {
                            message: &message,
                            done: start + pr.passes_done as u64,
                            total,
                        })
                    })?;
                    *done += reference_passes;
                    out.image.write_exr(&cached)?;
                    let spp = out.stats.image_spp;
                    let floor = image::expected_rel_mse(&out.image, &out.variance, spp);
                    let seconds = Some(out.stats.wall_seconds);
                    write_floor(&floor_file, floor, spp, seconds)?;
                    (out.image, Some((floor, spp, seconds)))
                }
            };
            (
                image,
                cached.display().to_string(),
                Some(floor.map_or(plan.reference_spp, |f| f.1)),
                floor.map(|f| f.0),
                floor.and_then(|f| f.2),
            )
        }
    };
    Ok(SceneReference {
        image,
        label,
        spp,
        rel_mse,
        seconds,
    })
}

/// Runs the plan, writing images and pictures under `plan.out`; the report
/// files themselves are written by [`super::report::write`].
pub fn evaluate(
    ctx: &Arc<GpuContext>,
    plan: &EvalPlan,
    progress: &mut dyn FnMut(&EvalProgress<'_>),
) -> Result<Report, BenchError> {
    let max_spp = *plan.spp_list.iter().max().unwrap_or(&1);
    let mut checkpoints: Vec<u32> = plan.spp_list.clone();
    // With a time budget, every power of two until time runs out.
    let last = match plan.seconds {
        Some(_) => crate::render::settings::MAX_SPP,
        None => max_spp,
    };
    let mut p = 1;
    while p <= last {
        checkpoints.push(p);
        p *= 2;
    }
    checkpoints.push(max_spp);
    checkpoints.sort_unstable();
    checkpoints.dedup();

    let reference_passes = if plan.reference.is_some() {
        0
    } else {
        plan.reference_spp as u64
    };
    // Progress: passes, and with a time budget each method's milliseconds.
    let per_run = plan.seconds.map_or(max_spp as u64, |t| (t * 1e3) as u64);
    let total = plan.scenes.len() as u64 * (reference_passes + plan.configs.len() as u64 * per_run);
    let mut done = 0u64;
    let mut scenes = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for path in &plan.scenes {
        let scene = Scene::load_defined(path, &plan.defines)?;
        let mut name = short_name(path);
        while names.contains(&name) {
            name.push('_');
        }
        names.push(name.clone());
        let dir = plan.out.join(&name);
        std::fs::create_dir_all(&dir).map_err(|e| BenchError::Io(dir.clone(), e.to_string()))?;

        let mut reference = scene_reference(
            ctx,
            plan,
            (path, &scene, &name),
            (&mut done, total),
            progress,
        )?;
        if (reference.image.width, reference.image.height)
            != (plan.width as usize, plan.height as usize)
        {
            return Err(BenchError::Io(
                PathBuf::from(&reference.label),
                format!(
                    "reference is {}x{}, the bench renders {}x{}",
                    reference.image.width, reference.image.height, plan.width, plan.height
                ),
            ));
        }
        write_image(&reference.image, &dir, "reference", &plan.out)?;

        let renders = render_configs(
            ctx,
            plan,
            (&scene, &name, &dir),
            &reference.image,
            &checkpoints,
            (&mut done, total),
            progress,
        )?;
        let control = Control {
            at_passes: &checkpoints,
            ..Default::default()
        };

        let mut runs = Vec::new();
        // Every checkpoint's image, to measure again if the reference is refined.
        let mut images: Vec<Vec<Image>> = Vec::new();
        let mut crop_centre = [0.5, 0.5];
        for r in renders {
            let Stepped {
                label,
                run_dir,
                mut renderer,
                run,
                mut rows,
                mut kept,
                ..
            } = r;
            let seconds = run.seconds();
            let out = renderer.finish(run, &control)?;
            // A time budget's render ends between checkpoints: its last
            // image is one more.
            if plan.seconds.is_some() && rows.last().is_none_or(|c| c.spp < out.stats.spp) {
                let (png, exr) = write_image(
                    &out.image,
                    &run_dir,
                    &format!("spp-{:04}", out.stats.spp),
                    &plan.out,
                )?;
                rows.push(CheckpointRow {
                    spp: out.stats.spp,
                    seconds,
                    error: image::compare(&out.image, &reference.image)?,
                    zero_contribution_fraction: out.stats.zero_contribution_fraction,
                    png: Some(png),
                    exr: Some(exr),
                });
                kept.push(out.image.clone());
            }
            if runs.is_empty() {
                crop_centre = worst_block(&out.image, &reference.image);
            }
            let learned = learned_pictures(ctx, plan, &scene, &renderer, &run_dir)?;
            images.push(kept);
            runs.push(run_report(label, rows, out.stats, learned));
        }

        let refined = refine_reference(
            ctx,
            plan,
            (&scene, &name, &dir),
            &mut reference,
            (&mut runs, &images),
            (&done, total),
            progress,
        )?;
        if refined {
            if let Some(last) = images.first().and_then(|k| k.last()) {
                crop_centre = worst_block(last, &reference.image);
            }
        }

        let (equal_time, summary) = compare_runs(plan, &mut runs);
        scenes.push(SceneReport {
            scene: path.display().to_string(),
            name,
            width: plan.width,
            height: plan.height,
            reference: reference.label,
            reference_spp: reference.spp,
            reference_rel_mse: reference.rel_mse,
            smallest_rel_mse: runs
                .iter()
                .flat_map(|r| {
                    [
                        r.checkpoints
                            .last()
                            .map_or(f64::INFINITY, |c| c.error.rel_mse),
                        r.error_at_equal_time.rel_mse,
                    ]
                })
                .fold(f64::INFINITY, f64::min),
            equal_time_seconds: equal_time,
            crop_centre,
            runs,
            summary,
        });
    }
    Ok(Report {
        device: ctx.info().name.clone(),
        spp_list: plan.spp_list.clone(),
        configs: plan.configs.iter().map(|c| c.label()).collect(),
        scenes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(spp: u32, seconds: f64, rel_mse: f64) -> CheckpointRow {
        CheckpointRow {
            spp,
            seconds,
            error: ErrorMetrics {
                mse: rel_mse,
                rel_mse,
                mape: rel_mse.sqrt(),
            },
            zero_contribution_fraction: 0.0,
            png: None,
            exr: None,
        }
    }

    #[test]
    fn equal_time_errors_interpolate_and_extrapolate_before_the_first_checkpoint() {
        let rows = [row(16, 1.0, 0.4), row(64, 4.0, 0.1)];
        // Between checkpoints, log-log: halfway in log time, halfway in log error.
        let mid = error_at_time(&rows, 2.0);
        assert!((mid.rel_mse - 0.2).abs() < 1e-12, "{mid:?}");
        assert!(!t_extrapolated(&rows, 2.0));
        // Before the first, as 1/time (MAPE as 1/sqrt(time)), and said so.
        let early = error_at_time(&rows, 0.5);
        assert!((early.rel_mse - 0.8).abs() < 1e-12, "{early:?}");
        assert!((early.mape - 0.4f64.sqrt() * 2f64.sqrt()).abs() < 1e-12);
        assert!(t_extrapolated(&rows, 0.5));
        assert!((error_at_time(&rows, 4.0).rel_mse - 0.1).abs() < 1e-12);
    }

    #[test]
    fn a_reference_floor_keeps_its_time_and_older_files_still_read() {
        let dir = std::env::temp_dir().join(format!("qtrace-floor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.relmse");
        write_floor(&path, 2.5e-4, 4096, Some(12.5)).unwrap();
        assert_eq!(read_floor(&path), Some((2.5e-4, 4096, Some(12.5))));
        write_floor(&path, 1e-3, 1024, None).unwrap();
        assert_eq!(read_floor(&path), Some((1e-3, 1024, None)));
        // As the bench wrote them before it kept the time.
        std::fs::write(&path, "3e-4 2048\n").unwrap();
        assert_eq!(read_floor(&path), Some((3e-4, 2048, None)));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn references_double_to_8x_then_while_a_doubling_is_quick() {
        // Under a tenth already: done.
        assert_eq!(refinement(0.009, 0.1, 1024, 8192, None), None);
        // Up to the cap by doubling, the last step to the cap.
        assert_eq!(refinement(0.02, 0.1, 1024, 8192, None), Some(1024));
        assert_eq!(refinement(0.02, 0.1, 6144, 8192, Some(900.0)), Some(2048));
        // At the cap: on only while a doubling (as long as the reference
        // took so far) is quick, and never past MAX_SPP.
        assert_eq!(refinement(0.02, 0.1, 8192, 8192, None), None);
        assert_eq!(refinement(0.02, 0.1, 8192, 8192, Some(600.0)), None);
        assert_eq!(refinement(0.02, 0.1, 8192, 8192, Some(3.0)), Some(8192));
        assert_eq!(refinement(0.02, 0.1, MAX_SPP - 5, 8192, Some(3.0)), Some(5));
        assert_eq!(refinement(0.02, 0.1, MAX_SPP, 8192, Some(3.0)), None);
    }

    #[test]
    fn a_guide_is_measured_at_its_plain_counterparts_time() {
        // Plain: relMSE 0.1 after 4 s. The guide's relMSE at 4 s lies
        // between its checkpoints (log-log): 0.06 at 2 s, 0.015 at 8 s.
        let plain = [row(16, 1.0, 0.4), row(64, 4.0, 0.1)];
        let guided = [row(16, 2.0, 0.06), row(64, 8.0, 0.015)];
        let r = over_plain(&guided, &plain).unwrap();
        assert!((r - 0.3).abs() < 1e-9, "{r}");
        assert!((over_plain(&plain, &plain).unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(over_plain(&guided, &[]), None);
        assert_eq!(over_plain(&[], &plain), None);
    }

    #[test]
    fn samples_at_a_time_interpolate_between_checkpoints() {
        let rows = [row(16, 1.0, 0.4), row(64, 4.0, 0.1)];
        assert_eq!(spp_at_time(&rows, 0.5), 8.0);
        assert_eq!(spp_at_time(&rows, 2.5), 40.0);
        assert_eq!(spp_at_time(&rows, 9.0), 64.0);
        assert_eq!(spp_at_time(&[], 1.0), 0.0);
    }

    #[test]
    fn the_later_half_of_samples_is_timed_against_the_first_method() {
        let plain = [row(64, 1.0, 0.0), row(128, 2.0, 0.0), row(256, 4.0, 0.0)];
        // Dear while learning, 1.5x once it thinned out.
        let guided = [row(64, 3.0, 0.0), row(128, 4.5, 0.0), row(256, 7.5, 0.0)];
        assert_eq!(later_half_cost(&guided, &plain), Some(1.5));
        assert_eq!(later_half_cost(&plain, &plain), Some(1.0));
        // Without the half-way checkpoint there is nothing to tell.
        assert_eq!(later_half_cost(&guided[2..], &plain), None);
        // Runs of one time budget end at different counts: the largest
        // both reached, with its half, tells.
        assert_eq!(later_half_cost(&guided, &plain[..2]), Some(1.5));
        let timed = [row(64, 3.0, 0.0), row(128, 4.5, 0.0), row(200, 5.0, 0.0)];
        assert_eq!(later_half_cost(&timed, &plain), Some(1.5));
    }
}
