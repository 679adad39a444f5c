//! Named GPU timings from timestamp query pools.

use super::{GpuContext, Result};
use ash::vk;
use std::sync::Arc;

/// Most passes one submit may time; later ones in the same submit go
/// untimed. A submit of 16 passes that train a network holds hundreds of
/// dispatches (a cap of 64 once left most of their training untimed), and
/// each query pair is reset where it is used, so a large pool costs nothing.
const MAX_TIMED_PASSES: u32 = 16384;

/// Totals for one pass name.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct PassTiming {
    pub name: String,
    pub count: u64,
    pub total_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
    /// Median of the individual timings: robust to the first dispatch, which
    /// may include the driver's shader compilation.
    pub median_ms: f64,
    #[serde(skip)]
    samples: Vec<f32>,
}

impl PassTiming {
    pub fn mean_ms(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.total_ms / self.count as f64
        }
    }
}

/// Collects per-pass GPU time across submits. Does nothing on devices without
/// timestamp support.
pub struct Profiler {
    ctx: Arc<GpuContext>,
    pool: Option<vk::QueryPool>,
    pending: Vec<(String, u32)>,
    timings: Vec<PassTiming>,
    /// Milliseconds of every timed dispatch of the last submit.
    last_submit_ms: Option<f64>,
    /// Milliseconds the driver spent compiling kernels at their first
    /// dispatch (see `Recorder::dispatch_covering`), in all submits.
    compile_ms: f64,
    valid_mask: u64,
}

impl Profiler {
    pub fn new(ctx: &Arc<GpuContext>) -> Result<Self> {
        let pool = if ctx.info().timestamps {
            let info = vk::QueryPoolCreateInfo::default()
                .query_type(vk::QueryType::TIMESTAMP)
                .query_count(2 * MAX_TIMED_PASSES);
            let pool = unsafe { ctx.device.create_query_pool(&info, None)? };
            ctx.set_name(pool, "pass timestamps");
            Some(pool)
        } else {
            None
        };
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            pending: Vec::new(),
            timings: Vec::new(),
            last_submit_ms: None,
            compile_ms: 0.0,
            valid_mask: u64::MAX,
        })
    }

    pub(super) fn reset(&mut self) {
        self.pending.clear();
    }

    /// A dispatch doing the work of `passes` passes counts as that many, each
    /// with an equal share of its time; `passes` 0 times a kernel's compile.
    pub(super) fn begin(&mut self, cmd: vk::CommandBuffer, name: &str, passes: u32) -> Option<u32> {
        let pool = self.pool?;
        let index = self.pending.len() as u32;
        if index >= MAX_TIMED_PASSES {
            return None;
        }
        self.pending.push((name.to_string(), passes));
        unsafe {
            self.ctx
                .device
                .cmd_reset_query_pool(cmd, pool, 2 * index, 2);
            self.ctx.device.cmd_write_timestamp(
                cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                pool,
                2 * index,
            )
        };
        Some(index)
    }

    pub(super) fn end(&mut self, cmd: vk::CommandBuffer, index: u32) {
        if let Some(pool) = self.pool {
            unsafe {
                self.ctx.device.cmd_write_timestamp(
                    cmd,
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    pool,
                    2 * index + 1,
                )
            };
        }
    }

    /// Reads the finished submit's timestamps into the totals.
    pub(super) fn collect(&mut self) -> Result<()> {
        self.last_submit_ms = None;
        let Some(pool) = self.pool else {
            return Ok(());
        };
        if self.pending.is_empty() {
            return Ok(());
        }
        let mut ticks = vec![0u64; 2 * self.pending.len()];
        unsafe {
            self.ctx.device.get_query_pool_results(
                pool,
                0,
                &mut ticks,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )?
        };
        let period_ms = self.ctx.info().timestamp_period_ns as f64 * 1e-6;
        for (i, (name, passes)) in std::mem::take(&mut self.pending).into_iter().enumerate() {
            let start = ticks[2 * i] & self.valid_mask;
            let end = ticks[2 * i + 1] & self.valid_mask;
            let all_ms = end.saturating_sub(start) as f64 * period_ms;
            if passes == 0 {
                self.compile_ms += all_ms;
                continue;
            }
            let ms = all_ms / passes as f64;
            *self.last_submit_ms.get_or_insert(0.0) += ms * passes as f64;
            let t = match self.timings.iter_mut().find(|t| t.name == name) {
                Some(t) => t,
                None => {
                    self.timings.push(PassTiming {
                        name,
                        min_ms: f64::INFINITY,
                        ..Default::default()
                    });
                    self.timings.last_mut().unwrap()
                }
            };
            t.count += passes as u64;
            t.total_ms += ms * passes as f64;
            t.min_ms = t.min_ms.min(ms);
            t.max_ms = t.max_ms.max(ms);
            t.samples
                .extend(std::iter::repeat_n(ms as f32, passes as usize));
        }
        Ok(())
    }

    /// GPU milliseconds of the last submit's dispatches (None where the
    /// device has no timestamps or nothing was timed).
    pub fn last_submit_ms(&self) -> Option<f64> {
        self.last_submit_ms
    }

    /// Milliseconds spent compiling kernels so far (0 on drivers that compile
    /// them when the pipeline is made, or without timestamps).
    pub fn compile_ms(&self) -> f64 {
        self.compile_ms
    }

    /// Totals per pass name, in first-seen order.
    pub fn timings(&self) -> Vec<PassTiming> {
        self.timings
            .iter()
            .map(|t| {
                let mut sorted = t.samples.clone();
                sorted.sort_by(f32::total_cmp);
                PassTiming {
                    median_ms: sorted.get(sorted.len() / 2).map_or(0.0, |&m| m as f64),
                    samples: Vec::new(),
                    ..t.clone()
                }
            })
            .collect()
    }
}

impl Drop for Profiler {
    fn drop(&mut self) {
        if let Some(pool) = self.pool {
            unsafe { self.ctx.device.destroy_query_pool(pool, None) };
        }
    }
}
