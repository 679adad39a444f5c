//! Measurements: the speed table (samples/s, rays/s, GPU time per pass from
//! timestamp queries) and the evaluation report (docs/benchmark.md).

pub mod charts;
pub mod eval;
pub(crate) mod learned;
pub mod peer;
pub mod report;

pub use eval::{evaluate, EvalPlan, EvalProgress, Report};

use crate::gpu::GpuContext;
use crate::guide::GuideSources;
use crate::render::{self, Method, Overrides, RenderError, RenderSettings, SettingsError};
use crate::scene::{Scene, SceneError};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;

/// A method with or without next-event estimation, written `pt`, `pt+nee`,
/// `sarsa`, `sarsa+nee`, `neural`, `neural+nee`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Config {
    pub method: Method,
    pub nee: bool,
}

impl Config {
    pub fn label(&self) -> String {
        self.method.label(self.nee)
    }
}

impl std::str::FromStr for Config {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (name, nee) = match s.strip_suffix("+nee") {
            Some(n) => (n, true),
            None => (s, false),
        };
        let method = <Method as clap::ValueEnum>::from_str(name, true).map_err(|_| {
            format!("unknown method '{name}' in '{s}' (pt, sarsa, neural; add +nee for NEE)")
        })?;
        Ok(Self { method, nee })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Image(#[from] crate::image::ImageError),
    #[error("{0}: {1}")]
    Io(PathBuf, String),
}

/// One configuration on one scene: the fastest of the repeats.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedRow {
    pub scene: PathBuf,
    pub config: String,
    pub spp: u32,
    pub width: u32,
    pub height: u32,
    pub wall_seconds: f64,
    pub samples_per_second: f64,
    pub rays_per_second: f64,
    /// GPU ms of a sample pass, all its dispatches together, averaged over
    /// the passes (see [`mean_pass_ms`]).
    pub pass_ms: f64,
    /// Median GPU ms per pass name, where it ran.
    pub pass_breakdown_ms: Vec<(String, f64)>,
    /// `pass_ms` over the first configuration's on the same scene.
    pub pass_cost_ratio: f64,
    /// The same per path vertex (surface hit): what a pass costs apart from
    /// how long its paths are.
    pub vertex_cost_ratio: f64,
    pub zero_contribution_fraction: f64,
    pub mean_path_length: f64,
}

pub struct SpeedPlan<'a> {
    pub scenes: &'a [PathBuf],
    pub configs: &'a [Config],
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub repeats: u32,
    /// Also time Mitsuba 3 on each scene (see [`peer`]).
    pub peer: bool,
    /// Guide settings beyond each scene's tables.
    pub guides: &'a GuideSources,
    /// XML scenes' `-D name=value` parameters.
    pub defines: &'a [(String, String)],
}

/// The speed table: our rows, and the peer's where it was measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SpeedReport {
    pub rows: Vec<SpeedRow>,
    pub peers: Vec<peer::PeerRow>,
    /// Why the peer was not measured, if it was asked for and was not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peer_missing: Option<String>,
}

/// What [`speed`] reports as it goes.
pub enum SpeedEvent<'a> {
    Row(&'a SpeedRow),
    Peer(&'a peer::PeerRow),
    /// The peer could not run; said once.
    PeerMissing(&'a str),
}

/// GPU ms per sample pass: each dispatch kind's time over the `spp` passes,
/// so one that runs in some passes only (a guide's update once its
/// learning thins out) counts as often as it runs. (No dispatch's time holds
/// the driver's compile of its kernel: see `Recorder::dispatch_covering`.)
pub fn mean_pass_ms(timings: &[crate::gpu::PassTiming], spp: u32) -> f64 {
    timings.iter().map(|t| t.total_ms).sum::<f64>() / spp.max(1) as f64
}

/// Renders every configuration on every scene `repeats` times, the repeats
/// going round the configurations, keeping each one's fastest run, then the
/// peer once per scene; `progress` hears of each.
pub fn speed(
    ctx: &Arc<GpuContext>,
    plan: &SpeedPlan<'_>,
    progress: &mut dyn FnMut(SpeedEvent<'_>),
) -> Result<SpeedReport, BenchError> {
    let mut report = SpeedReport::default();
    for path in plan.scenes {
        let scene = Scene::load_defined(path, plan.defines)?;
        let first_row = report.rows.len();
        let mut overrides = Vec::new();
        for config in plan.configs {
            overrides.push(Overrides {
                method: Some(config.method),
                spp: Some(plan.spp),
                width: Some(plan.width),
                height: Some(plan.height),
                nee: config.nee,
                guide: plan
                    .guides
                    .resolve(&scene, config.method.name())
                    .map_err(|e| RenderError::from(SettingsError(e)))?,
                ..Default::default()
            });
        }
        // The repeats go round the methods (A B C A B C), so that a slow
        // spell of the machine's falls on one repeat of each, not on all of
        // one method's.
        let mut best: Vec<Option<SpeedRow>> = vec![None; plan.configs.len()];
        for _ in 0..plan.repeats.max(1) {
            for ((config, o), best) in plan.configs.iter().zip(&overrides).zip(&mut best) {
                let settings = RenderSettings::resolve(&scene, o).map_err(RenderError::from)?;
                let s = render::render(ctx, &scene, settings, &mut |_| {})?.stats;
                let breakdown: Vec<(String, f64)> = s
                    .gpu_passes
                    .iter()
                    .map(|t| (t.name.clone(), t.median_ms))
                    .collect();
                let pass_ms = mean_pass_ms(&s.gpu_passes, s.spp);
                let row = SpeedRow {
                    scene: path.clone(),
                    config: config.label(),
                    spp: s.spp,
                    width: s.width,
                    height: s.height,
                    wall_seconds: s.wall_seconds,
                    samples_per_second: s.samples_per_second,
                    rays_per_second: s.rays_per_second,
                    pass_ms,
                    pass_breakdown_ms: breakdown,
                    pass_cost_ratio: 1.0,
                    vertex_cost_ratio: 1.0,
                    zero_contribution_fraction: s.zero_contribution_fraction,
                    mean_path_length: s.mean_path_length,
                };
                if best.as_ref().is_none_or(|b| row.pass_ms < b.pass_ms) {
                    *best = Some(row);
                }
            }
        }
        let mut baseline = None;
        for best in best {
            let mut row = best.expect("at least one repeat");
            let (base_ms, base_length) =
                *baseline.get_or_insert((row.pass_ms, row.mean_path_length));
            row.pass_cost_ratio = row.pass_ms / base_ms;
            row.vertex_cost_ratio =
                row.pass_cost_ratio * base_length / row.mean_path_length.max(1e-9);
            progress(SpeedEvent::Row(&row));
            report.rows.push(row);
        }
        if plan.peer && report.peer_missing.is_none() {
            let o = Overrides {
                width: Some(plan.width),
                height: Some(plan.height),
                ..Default::default()
            };
            let max_depth = RenderSettings::resolve(&scene, &o)
                .map_err(RenderError::from)?
                .max_depth;
            match peer::mitsuba(
                path,
                plan.defines,
                plan.width,
                plan.height,
                plan.spp,
                max_depth,
            ) {
                Ok(mut p) => {
                    p.pt_nee_ratio = report.rows[first_row..]
                        .iter()
                        .find(|r| r.config == "pt+nee")
                        .map(|r| r.samples_per_second / p.samples_per_second);
                    progress(SpeedEvent::Peer(&p));
                    report.peers.push(p);
                }
                Err(e) => {
                    let why = e.to_string();
                    progress(SpeedEvent::PeerMissing(&why));
                    report.peer_missing = Some(why);
                }
            }
        }
    }
    Ok(report)
}
