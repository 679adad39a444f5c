//! The `qtrace` command line.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use qtrace::bench::{self, Config, EvalPlan, SpeedEvent, SpeedPlan};
use qtrace::gpu::{self, ContextOptions, GpuContext};
use qtrace::guide::neural::{Encoding, Target};
use qtrace::guide::sarsa::{Atomics, Distribution};
use qtrace::guide::{NeuralSettings, SarsaSettings};
use qtrace::image::{self, Image};
use qtrace::render::{self, Method, Overrides, Progress, RenderSettings, Sampling};
use qtrace::Scene;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "qtrace",
    version,
    about = "Vulkan path tracer with learned path guiding"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args, Clone)]
struct DeviceArgs {
    /// Vulkan device by index or name substring (also QTRACE_DEVICE); default:
    /// discrete GPU, then integrated, then CPU.
    #[arg(long, env = "QTRACE_DEVICE")]
    device: Option<String>,
    /// Enable the Khronos validation layer (also QTRACE_VALIDATION=1).
    #[arg(long)]
    validation: bool,
}

#[derive(clap::Args, Clone)]
struct RenderArgs {
    /// Path-tracing method.
    #[arg(long, value_enum)]
    method: Option<Method>,
    /// Samples per pixel (default: the scene's, else 64).
    #[arg(long, conflicts_with = "time")]
    spp: Option<u32>,
    /// Render for this many seconds instead of a fixed sample count.
    #[arg(long)]
    time: Option<f64>,
    /// Image width in pixels (default: the scene's, else 256).
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels (default: the scene's, else 256).
    #[arg(long)]
    height: Option<u32>,
    /// Most bounces a path may take.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Next-event estimation with multiple importance sampling.
    #[arg(long)]
    nee: bool,
    /// Random seed; the same seed gives the same image.
    #[arg(long)]
    seed: Option<u32>,
    /// BSDF direction sampling (`pt`).
    #[arg(long, value_enum)]
    sampling: Option<Sampling>,
    #[command(flatten)]
    sarsa: SarsaArgs,
    #[command(flatten)]
    neural: NeuralArgs,
}

/// Options of `--method sarsa`.
#[derive(clap::Args, Clone)]
#[command(next_help_heading = "Sarsa guide (--method sarsa)")]
struct SarsaArgs {
    /// Radiance volumes placed over the surfaces (uniformly by area); default
    /// one per 64 pixels of the image (1024 at 256×256), at least 64.
    #[arg(long)]
    sarsa_volumes: Option<u32>,
    /// Volumes per unit² of surface instead of a count (the thesis used 1000).
    #[arg(long)]
    sarsa_density: Option<f64>,
    /// Device-memory budget for the guide in MiB (caps the volume count).
    #[arg(long)]
    sarsa_memory_mib: Option<f64>,
    /// Sector grid AxB per hemisphere (n = A·B sectors of equal solid angle).
    #[arg(long, default_value = "12x12", value_parser = parse_grid)]
    sarsa_sectors: [u32; 2],
    /// Share of cosine sampling in the mixture, in (0, 1].
    #[arg(long, default_value_t = SarsaSettings::default().epsilon)]
    sarsa_epsilon: f32,
    /// Sample sectors in proportion to Q or to Q·cos θ.
    #[arg(long, value_enum, default_value_t = Distribution::Qcos)]
    sarsa_distribution: Distribution,
    /// Stop learning after this many sample passes.
    #[arg(long)]
    sarsa_freeze_after: Option<u32>,
    /// Restart the image after this many passes (they only train the guide).
    #[arg(long)]
    sarsa_reset_after: Option<u32>,
    /// How targets are added on the GPU.
    #[arg(long, value_enum, default_value_t = Atomics::Auto)]
    sarsa_atomics: Atomics,
}

/// Options of `--method neural`.
#[derive(clap::Args, Clone)]
#[command(next_help_heading = "Neural-Q guide (--method neural)")]
struct NeuralArgs {
    /// Sector grid AxB per hemisphere: the network's A·B outputs.
    #[arg(long, default_value = "12x12", value_parser = parse_grid)]
    neural_sectors: [u32; 2],
    /// Units per hidden layer.
    #[arg(long, default_value_t = NeuralSettings::default().width)]
    neural_width: u32,
    /// Hidden layers.
    #[arg(long, default_value_t = NeuralSettings::default().layers)]
    neural_layers: u32,
    /// Adam's learning rate.
    #[arg(long, default_value_t = NeuralSettings::default().learning_rate)]
    neural_lr: f32,
    /// Training transitions gathered per sample pass.
    #[arg(long, default_value_t = NeuralSettings::default().batch)]
    neural_batch: u32,
    /// Training steps on each pass's transitions.
    #[arg(long, default_value_t = NeuralSettings::default().steps)]
    neural_steps: u32,
    /// Share of cosine sampling in the mixture, in (0, 1].
    #[arg(long, default_value_t = NeuralSettings::default().epsilon)]
    neural_epsilon: f32,
    /// Sample sectors in proportion to Q or to Q·cos θ.
    #[arg(long, value_enum, default_value_t = Distribution::Qcos)]
    neural_distribution: Distribution,
    /// Bootstrap target: expected (rendering equation) or max (deep Q-learning).
    #[arg(long, value_enum, default_value_t = Target::Expected)]
    neural_target: Target,
    /// State encoding: position at several frequencies (scales to any
    /// scene), or the scene's vertices relative to the point (the thesis's;
    /// scenes of a few dozen vertices).
    #[arg(long, value_enum, default_value_t = Encoding::Frequency)]
    neural_encoding: Encoding,
    /// Stop training after this many sample passes.
    #[arg(long)]
    neural_freeze_after: Option<u32>,
    /// Restart the image after this many passes (they only train the network).
    #[arg(long)]
    neural_reset_after: Option<u32>,
}

impl NeuralArgs {
    fn settings(&self) -> NeuralSettings {
        NeuralSettings {
            grid: self.neural_sectors,
            width: self.neural_width,
            layers: self.neural_layers,
            learning_rate: self.neural_lr,
            batch: self.neural_batch,
            steps: self.neural_steps,
            epsilon: self.neural_epsilon,
            distribution: self.neural_distribution,
            target: self.neural_target,
            encoding: self.neural_encoding,
            freeze_after: self.neural_freeze_after,
            reset_after: self.neural_reset_after,
            ..Default::default()
        }
    }
}

fn parse_grid(s: &str) -> Result<[u32; 2], String> {
    let (a, b) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}' is not AxB, e.g. 12x12"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{s}' is not AxB, e.g. 12x12"))
    };
    Ok([parse(a)?, parse(b)?])
}

impl SarsaArgs {
    fn settings(&self) -> SarsaSettings {
        SarsaSettings {
            volumes: self.sarsa_volumes,
            density: self.sarsa_density,
            memory_mib: self.sarsa_memory_mib,
            grid: self.sarsa_sectors,
            epsilon: self.sarsa_epsilon,
            distribution: self.sarsa_distribution,
            freeze_after: self.sarsa_freeze_after,
            reset_after: self.sarsa_reset_after,
            atomics: self.sarsa_atomics,
            ..Default::default()
        }
    }
}

impl RenderArgs {
    fn overrides(&self) -> Overrides {
        Overrides {
            method: self.method,
            spp: self.spp,
            time: self.time,
            width: self.width,
            height: self.height,
            max_depth: self.max_depth,
            nee: self.nee,
            seed: self.seed,
            sampling: self.sampling,
            sarsa: self.sarsa.settings(),
            neural: self.neural.settings(),
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to OpenEXR (and optionally PNG and stats JSON).
    Render {
        /// Scene file (TOML).
        scene: PathBuf,
        #[command(flatten)]
        args: RenderArgs,
        /// Linear float RGB OpenEXR output.
        #[arg(short, long, default_value = "out.exr")]
        output: PathBuf,
        /// Tonemapped sRGB PNG output.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Statistics JSON output.
        #[arg(long)]
        stats: Option<PathBuf>,
        /// Print GPU time per pass.
        #[arg(long)]
        profile: bool,
        #[command(flatten)]
        device: DeviceArgs,
    },
    /// Error metrics of an image against a reference (MSE, relMSE, MAPE).
    Compare {
        /// Image to measure (OpenEXR).
        image: PathBuf,
        /// Reference image (OpenEXR) of the same size.
        reference: PathBuf,
    },
    /// List Vulkan devices and the features qtrace uses.
    Devices,
    /// Triangles, lights, BVH statistics of a scene.
    Inspect {
        /// Scene file (TOML).
        scene: PathBuf,
    },
    /// Compare methods: images, error vs spp and vs time, per-pass statistics,
    /// pictures of what was learned, charts, CSV/JSON and an HTML page
    /// (with --speed: only a table of samples/s, rays/s and GPU ms per pass).
    Bench {
        /// Scenes to evaluate.
        #[arg(default_values = ["scenes/cornell-box.toml"])]
        scenes: Vec<PathBuf>,
        /// Methods to compare (pt, sarsa, neural; add +nee for next-event estimation).
        #[arg(long, alias = "configs", value_delimiter = ',', default_values = ["pt", "sarsa"])]
        methods: Vec<Config>,
        /// Sample counts at which images and errors are kept.
        #[arg(long, value_delimiter = ',', default_values = ["1", "16", "32", "64", "128", "256"])]
        spp_list: Vec<u32>,
        /// Image width (default 256; 64 with --quick).
        #[arg(long)]
        width: Option<u32>,
        /// Image height (default 256; 64 with --quick).
        #[arg(long)]
        height: Option<u32>,
        /// Reference image (single scene only); otherwise pt+nee renders one, cached.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// Samples per pixel of a rendered reference (default 1024; 256 with --quick).
        #[arg(long)]
        reference_spp: Option<u32>,
        /// Report directory.
        #[arg(long, default_value = "bench-report")]
        out: PathBuf,
        /// Small images and few samples (spp 1,4,16,32 at 64x64): seconds per scene.
        #[arg(long)]
        quick: bool,
        /// Random seed of the methods' renders.
        #[arg(long, default_value_t = 1)]
        seed: u32,
        /// Only the speed table: each method at --spp, fastest of --repeats runs.
        #[arg(long)]
        speed: bool,
        /// Samples per pixel of each --speed run.
        #[arg(long, default_value_t = 32)]
        spp: u32,
        /// Runs per method with --speed; the fastest counts.
        #[arg(long, default_value_t = 2)]
        repeats: u32,
        /// Speed table as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// With --speed: also time this peer renderer on each scene (mitsuba:
        /// Mitsuba 3 llvm_ad_rgb through scripts/mitsuba_speed.py), or none.
        #[arg(long, default_value = "mitsuba", value_parser = ["mitsuba", "none"])]
        peer: String,
        #[command(flatten)]
        device: DeviceArgs,
    },
}

fn open_device(args: &DeviceArgs) -> Result<Arc<GpuContext>> {
    let validation = args.validation || std::env::var("QTRACE_VALIDATION").is_ok_and(|v| v == "1");
    Ok(GpuContext::new(&ContextOptions {
        device: args.device.clone(),
        validation,
    })?)
}

/// A progress bar on a terminal; nothing otherwise.
fn progress_bar(total: Option<u32>) -> Option<ProgressBar> {
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = match total {
        Some(n) => ProgressBar::new(n as u64).with_style(
            ProgressStyle::with_template(
                "{bar:40.cyan/blue} {pos}/{len} spp  {msg}  elapsed {elapsed}  eta {eta}",
            )
            .unwrap(),
        ),
        None => ProgressBar::new(1000).with_style(
            ProgressStyle::with_template("{bar:40.cyan/blue} {msg}  elapsed {elapsed}").unwrap(),
        ),
    };
    Some(bar)
}

fn update_bar(bar: &Option<ProgressBar>, p: &Progress) {
    let Some(bar) = bar else { return };
    let rate = format!("{:.2} Mrays/s", p.rays_per_second / 1e6);
    match p.budget_seconds {
        Some(t) => {
            bar.set_position(((p.elapsed / t).min(1.0) * 1000.0) as u64);
            bar.set_message(format!("{} spp  {rate}", p.passes_done));
        }
        None => {
            bar.set_position(p.passes_done as u64);
            bar.set_message(rate);
        }
    }
}

fn check_output(path: &Path, ext: &str) -> Result<()> {
    let ok = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if !ok {
        bail!("{}: output file must end in .{ext}", path.display());
    }
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() && !d.is_dir() => {
            bail!(
                "{}: directory {} does not exist",
                path.display(),
                d.display()
            )
        }
        _ => Ok(()),
    }
}

fn cmd_render(
    scene_path: &Path,
    args: &RenderArgs,
    output: &Path,
    png: Option<&Path>,
    stats_path: Option<&Path>,
    profile: bool,
    device: &DeviceArgs,
) -> Result<()> {
    // Check everything the user gave before any GPU work.
    check_output(output, "exr")?;
    if let Some(p) = png {
        check_output(p, "png")?;
    }
    if let Some(p) = stats_path {
        check_output(p, "json")?;
    }
    let scene = Scene::load(scene_path)?;
    let settings = RenderSettings::resolve(&scene, &args.overrides())
        .with_context(|| format!("{}: bad render settings", scene_path.display()))?;
    let ctx = open_device(device)?;
    let total = match settings.budget {
        render::Budget::Samples(n) => Some(n),
        render::Budget::Seconds(_) => None,
    };
    let bar = progress_bar(total);
    let out = render::render(&ctx, &scene, settings, &mut |p| update_bar(&bar, p))?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    out.image.write_exr(output)?;
    if let Some(p) = png {
        out.image.write_png(p)?;
    }
    if let Some(p) = stats_path {
        let json = serde_json::to_string_pretty(&out.stats)?;
        image::write_atomically(p, |tmp| {
            std::fs::write(tmp, &json).map_err(|e| e.to_string())
        })?;
    }
    let s = &out.stats;
    eprintln!(
        "{}: {} spp {}x{} in {:.2} s on {} | {:.2} Mrays/s | zero-contribution {:.1}% | mean path length {:.2}",
        s.method,
        s.spp,
        s.width,
        s.height,
        s.wall_seconds,
        s.device,
        s.rays_per_second / 1e6,
        100.0 * s.zero_contribution_fraction,
        s.mean_path_length
    );
    if s.invalid_paths > 0 {
        eprintln!(
            "warning: {} paths gave NaN or infinite radiance and were left out",
            s.invalid_paths
        );
    }
    if profile {
        eprint!("{}", s.profile_table());
    }
    check_validation(&ctx)
}

fn check_validation(ctx: &GpuContext) -> Result<()> {
    if ctx.validation_errors() > 0 {
        bail!(
            "the Vulkan validation layer reported {} errors",
            ctx.validation_errors()
        );
    }
    Ok(())
}

fn cmd_compare(image_path: &Path, reference_path: &Path) -> Result<()> {
    let a = Image::read_exr(image_path)?;
    let b = Image::read_exr(reference_path)?;
    let m = image::compare_named(
        &a,
        &image_path.display().to_string(),
        &b,
        &reference_path.display().to_string(),
    )?;
    println!("mean    {:.6e} (reference {:.6e})", a.mean(), b.mean());
    println!("MSE     {:.6e}", m.mse);
    println!("relMSE  {:.6e}", m.rel_mse);
    println!("MAPE    {:.6e}", m.mape);
    Ok(())
}

fn cmd_devices() -> Result<()> {
    let devices = gpu::list_devices()?;
    if devices.is_empty() {
        bail!("no Vulkan device found; install a Vulkan driver (mesa-vulkan-drivers provides lavapipe)");
    }
    for d in devices {
        println!(
            "[{}] {} ({}, Vulkan {}, {})",
            d.index, d.name, d.kind, d.api_version, d.driver
        );
        println!(
            "    float atomics: {}  int64 atomics: {}  timestamps: {}  subgroup: {} (arithmetic: {})  max storage buffer: {} MiB  workgroup memory: {} KiB",
            yes(d.float_atomics),
            yes(d.int64_atomics),
            yes(d.timestamps),
            d.subgroup_size,
            yes(d.subgroup_arithmetic),
            d.max_storage_buffer_range >> 20,
            d.max_shared_memory >> 10
        );
    }
    Ok(())
}

fn yes(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}

fn cmd_inspect(path: &Path) -> Result<()> {
    let scene = Scene::load(path)?;
    let area: f32 = scene.triangles.iter().map(|t| t.area).sum();
    let light_area: f32 = scene
        .lights
        .iter()
        .map(|l| scene.triangles[l.triangle as usize].area)
        .sum();
    println!("scene        {}", path.display());
    println!("triangles    {}", scene.triangles.len());
    println!("materials    {}", scene.materials.len());
    println!(
        "emitters     {} triangles, {:.4} units² of {:.4} total",
        scene.lights.len(),
        light_area,
        area
    );
    println!("environment  {:?}", scene.environment.to_array());
    println!(
        "bvh          {} nodes of two child boxes, one triangle per leaf, depth {}",
        scene.nodes.len(),
        scene.bvh_depth,
    );
    let c = &scene.camera;
    println!(
        "camera       at {:?} looking {:?}, fov_y {}°",
        c.position.to_array(),
        c.forward.to_array(),
        c.fov_y_degrees
    );
    println!("scene extent {:.3} (bounding-box diagonal)", scene.extent);
    Ok(())
}

fn cmd_bench(plan: &SpeedPlan<'_>, json: Option<&Path>, device: &DeviceArgs) -> Result<()> {
    if let Some(p) = json {
        check_output(p, "json")?;
    }
    let ctx = open_device(device)?;
    println!("device: {} ({})", ctx.info().name, ctx.info().driver);
    println!(
        "{:<28} {:<10} {:>5} {:>9} {:>11} {:>9} {:>9} {:>6} {:>6} {:>8} {:>7}  per pass (ms)",
        "scene",
        "config",
        "spp",
        "wall s",
        "samples/s",
        "Mrays/s",
        "pass ms",
        "cost",
        "length",
        "cost/hit",
        "zero %"
    );
    let report = bench::speed(&ctx, plan, &mut |event| {
        let r = match event {
            SpeedEvent::Row(r) => r,
            SpeedEvent::Peer(p) => {
                let ratio = p.pt_nee_ratio.map_or(String::new(), |x| {
                    format!("  (pt+nee does {x:.2}x its samples/s)")
                });
                println!(
                    "{:<28} {:<10} {:>5} {:>9} {:>11.0} {:>9} {:>9}  mitsuba {} {}, JIT batch excluded{ratio}",
                    p.scene.display().to_string(),
                    "mitsuba",
                    p.spp,
                    "",
                    p.samples_per_second,
                    "",
                    "",
                    p.version,
                    p.variant
                );
                return;
            }
            SpeedEvent::PeerMissing(why) => {
                println!("mitsuba not measured: {why}");
                return;
            }
        };
        let breakdown: Vec<String> = r
            .pass_breakdown_ms
            .iter()
            .map(|(n, ms)| format!("{n} {ms:.2}"))
            .collect();
        println!(
            "{:<28} {:<10} {:>5} {:>9.3} {:>11.0} {:>9.3} {:>9.3} {:>5.2}x {:>6.2} {:>7.2}x {:>7.2}  {}",
            r.scene.display().to_string(),
            r.config,
            r.spp,
            r.wall_seconds,
            r.samples_per_second,
            r.rays_per_second / 1e6,
            r.pass_ms,
            r.pass_cost_ratio,
            r.mean_path_length,
            r.vertex_cost_ratio,
            100.0 * r.zero_contribution_fraction,
            breakdown.join(", ")
        );
    })?;
    if let Some(p) = json {
        let text = serde_json::to_string_pretty(&report)?;
        image::write_atomically(p, |tmp| {
            std::fs::write(tmp, &text).map_err(|e| e.to_string())
        })?;
    }
    check_validation(&ctx)
}

/// The reference's own error beside the smallest one measured against it.
fn reference_floor_line(s: &bench::eval::SceneReport) -> String {
    match s.reference_rel_mse {
        Some(floor) => {
            let share = floor / s.smallest_rel_mse;
            let advice = if share > 0.1 {
                ": above a tenth, so it blurs the comparison; raise --reference-spp"
            } else {
                ""
            };
            format!(
                "{}: the reference's own relMSE is about {floor:.2e}, {share:.2}x the smallest error measured against it ({:.2e}){advice}",
                s.name, s.smallest_rel_mse
            )
        }
        None => format!(
            "{}: the reference's own error is unknown (a given reference, or one cached without it)",
            s.name
        ),
    }
}

fn cmd_evaluate(mut plan: EvalPlan, device: &DeviceArgs) -> Result<()> {
    plan.spp_list.sort_unstable();
    plan.spp_list.dedup();
    if plan.spp_list.first() == Some(&0)
        || plan
            .spp_list
            .last()
            .is_some_and(|&n| n > qtrace::render::settings::MAX_SPP)
    {
        bail!(
            "--spp-list values must lie in 1..={}",
            qtrace::render::settings::MAX_SPP
        );
    }
    if plan.spp_list.is_empty() || plan.configs.is_empty() {
        bail!("bench needs at least one method and one sample count");
    }
    if plan.reference.is_some() && plan.scenes.len() != 1 {
        bail!("--reference applies to one scene; give one scene or let bench render references");
    }
    if plan.reference_spp == 0 {
        bail!("--reference-spp must be at least 1");
    }
    // Check the scenes before any GPU work, so a typo fails at once.
    for s in &plan.scenes {
        Scene::load(s)?;
    }
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("{}: cannot create the report directory", plan.out.display()))?;
    let ctx = open_device(device)?;
    let bar = std::io::stderr().is_terminal().then(|| {
        ProgressBar::new(1).with_style(
            ProgressStyle::with_template(
                "{bar:40.cyan/blue} {percent:>3}%  {msg}  elapsed {elapsed}  eta {eta}",
            )
            .unwrap(),
        )
    });
    let report = bench::evaluate(&ctx, &plan, &mut |p| {
        if let Some(b) = &bar {
            b.set_length(p.total.max(1));
            b.set_position(p.done);
            b.set_message(p.message.to_string());
        }
    })?;
    bench::report::write(&report, &plan.out)?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    println!(
        "{:<20} {:<12} {:>8} {:>12} {:>14} {:>10}",
        "scene", "method", "zero %", "relMSE", "relMSE@time", "Mrays/s"
    );
    for s in &report.scenes {
        for r in &s.runs {
            println!(
                "{:<20} {:<12} {:>8.2} {:>12.5} {:>14.5} {:>10.3}",
                s.name,
                r.config,
                100.0 * r.zero_contribution_fraction,
                r.checkpoints.last().map_or(f64::NAN, |c| c.error.rel_mse),
                r.error_at_equal_time.rel_mse,
                r.rays_per_second / 1e6
            );
        }
        println!("{}", reference_floor_line(s));
    }
    println!("report: {}", plan.out.join("index.html").display());
    check_validation(&ctx)
}

fn run(cli: Cli) -> Result<()> {
    match &cli.command {
        Command::Render {
            scene,
            args,
            output,
            png,
            stats,
            profile,
            device,
        } => cmd_render(
            scene,
            args,
            output,
            png.as_deref(),
            stats.as_deref(),
            *profile,
            device,
        ),
        Command::Compare { image, reference } => cmd_compare(image, reference),
        Command::Devices => cmd_devices(),
        Command::Inspect { scene } => cmd_inspect(scene),
        Command::Bench {
            scenes,
            methods,
            spp_list,
            width,
            height,
            reference,
            reference_spp,
            out,
            quick,
            seed,
            speed,
            spp,
            repeats,
            json,
            peer,
            device,
        } => {
            let (w, h) = if *quick { (64, 64) } else { (256, 256) };
            let (width, height) = (width.unwrap_or(w), height.unwrap_or(h));
            if *speed {
                let plan = SpeedPlan {
                    scenes,
                    configs: methods,
                    width,
                    height,
                    spp: *spp,
                    repeats: *repeats,
                    peer: peer == "mitsuba",
                };
                return cmd_bench(&plan, json.as_deref(), device);
            }
            let mut plan = EvalPlan::quick(scenes.clone(), methods.clone(), out.clone());
            if !*quick {
                plan.spp_list = spp_list.clone();
                plan.reference_spp = 1024;
            }
            plan.width = width;
            plan.height = height;
            plan.seed = *seed;
            plan.reference = reference.clone();
            if let Some(n) = reference_spp {
                plan.reference_spp = *n;
            }
            cmd_evaluate(plan, device)
        }
    }
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn"))
        .format_timestamp(None)
        .init();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if e.use_stderr() => {
            // Usage errors in one line, like every other error.
            let text = e.to_string();
            let first = text.lines().next().unwrap_or("invalid arguments");
            eprintln!("{first} (see qtrace --help)");
            std::process::exit(2);
        }
        Err(e) => e.exit(),
    };
    if let Err(e) = run(cli) {
        // One line: the outermost context, then its causes.
        // Causes already quoted by the message before them are not repeated.
        let mut line = String::new();
        for cause in e.chain().map(|c| c.to_string()) {
            if !line.contains(&cause) {
                if !line.is_empty() {
                    line.push_str(": ");
                }
                line.push_str(&cause);
            }
        }
        eprintln!("error: {line}");
        std::process::exit(1);
    }
}
