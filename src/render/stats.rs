//! What a render reports (docs/usage.md, "Stats JSON"). The top-level keys are fixed.

use crate::gpu::PassTiming;
use serde::Serialize;
use std::collections::BTreeMap;

/// One sample pass.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct PassRecord {
    pub pass: u32,
    pub zero_contribution_fraction: f64,
    pub mean_path_length: f64,
    pub rays: u64,
    /// Mean over the pass's samples of the squared deviation from their
    /// pixel's mean before the pass, relative as relMSE weighs it (0 for
    /// the first pass): the pass's noise, as a race compares it.
    #[serde(default)]
    pub deviation: f64,
    /// Learned methods: mean squared temporal-difference error of this pass's updates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct RenderStats {
    pub method: String,
    pub nee: bool,
    pub device: String,
    /// How the trace kernels read (`--reads`): speeds differ, images do not.
    pub reads: crate::gpu::Reads,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub seed: u32,
    /// Sample passes traced.
    pub spp: u32,
    /// Whether a signal stopped the render before its budget was spent
    /// (`spp` is what it did).
    pub interrupted: bool,
    /// Samples per pixel in the image (fewer than `spp` after a guide's reset).
    pub image_spp: u32,
    /// The render's time: its batches' wall time, less the driver's first
    /// compile of each kernel (`compile_seconds`).
    pub wall_seconds: f64,
    /// Seconds the driver spent compiling kernels at their first dispatch
    /// (llvmpipe; 0 where the pipelines were compiled when made).
    pub compile_seconds: f64,
    pub samples_per_second: f64,
    pub rays_per_second: f64,
    pub paths: u64,
    pub rays: u64,
    /// Paths whose estimate has mean RGB below 1e-4.
    pub zero_contribution_fraction: f64,
    /// Surface hits per path.
    pub mean_path_length: f64,
    /// Paths whose estimate was NaN or infinite (left out of the image).
    pub invalid_paths: u64,
    /// GPU milliseconds per pass name.
    pub gpu_ms: BTreeMap<String, f64>,
    /// Count, total, min and max per pass name.
    pub gpu_passes: Vec<PassTiming>,
    /// The guide's settings, every key (None for `pt`): as a `[sarsa]` or
    /// `[neural]` table they render the same guide again.
    pub guide: Option<crate::guide::GuideSettings>,
    /// Device memory held by a learned guide (0 for `pt`).
    pub guide_bytes: u64,
    /// Radiance volumes of the Sarsa guide (0 otherwise).
    pub guide_volumes: u64,
    pub passes: Vec<PassRecord>,
    /// Trace dispatches: fewer than `spp` where passes that learn nothing
    /// shared them.
    pub trace_dispatches: u32,
    /// The passes after which the guide stood back, if it did: every later
    /// pass was plain path tracing (see `Common::stand_back`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide_stood_back_after: Option<u32>,
    /// The races between the guide and plain path tracing, one per check
    /// the guide did not stand back at by its shares (see
    /// `crate::render::race`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub guide_races: Vec<super::RaceRecord>,
    /// How the guide sized its work to the device (Neural-Q's training
    /// steps per pass that trains, from the first pass's costs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide_fit: Option<crate::guide::DeviceFit>,
    /// How the guide update between passes ran: `invocation` (one a
    /// volume) or `workgroup` (one a volume).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide_update: Option<crate::guide::Update>,
}

impl RenderStats {
    /// Why the guide stood back, if it did: the race it lost, or its shares.
    pub fn stood_back_because(&self) -> Option<String> {
        self.guide_stood_back_after?;
        let races = &self.guide_races;
        Some(match races.last().filter(|r| r.stands_back) {
            Some(r) => format!(
                "plain path tracing won the races after {} and {} passes (its noise times time {:.2}x the guide's in the last)",
                races[races.len().saturating_sub(2)].after,
                r.after,
                r.plain_over_guide
            ),
            None => "every volume learned to sample the BSDF".into(),
        })
    }

    /// The `--profile` table: one line per pass name.
    pub fn profile_table(&self) -> String {
        let total: f64 = self.gpu_passes.iter().map(|t| t.total_ms).sum();
        let w = self
            .gpu_passes
            .iter()
            .map(|t| t.name.chars().count())
            .max()
            .unwrap_or(0)
            .max(20);
        let mut s = format!(
            "{:<w$} {:>7} {:>11} {:>7} {:>10} {:>10} {:>10} {:>10}\n",
            "pass", "count", "total ms", "share", "mean ms", "median ms", "min ms", "max ms"
        );
        for t in &self.gpu_passes {
            s += &format!(
                "{:<w$} {:>7} {:>11.3} {:>6.1}% {:>10.4} {:>10.4} {:>10.4} {:>10.4}\n",
                t.name,
                t.count,
                t.total_ms,
                if total > 0.0 {
                    100.0 * t.total_ms / total
                } else {
                    0.0
                },
                t.mean_ms(),
                t.median_ms,
                t.min_ms,
                t.max_ms
            );
        }
        if self.gpu_passes.is_empty() {
            s += "(this device has no timestamp queries)\n";
        }
        if self.compile_seconds > 0.0 {
            s += &format!(
                "and {:.3} ms compiling kernels at their first dispatch (not in the passes' times)\n",
                1e3 * self.compile_seconds
            );
        }
        s
    }
}
