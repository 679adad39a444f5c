//! What each `qtrace` command does, once `main.rs` has parsed its arguments:
//! checks, progress bars, output files and the lines it prints.

use crate::bench::{self, EvalPlan, SpeedEvent, SpeedPlan};
use crate::gpu::{self, ContextOptions, GpuContext};
use crate::guide::GuideSources;
use crate::image::{self, Image};
use crate::render::{self, Method, Overrides, Progress, RenderSettings};
use crate::scene::Scene;
use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Which Vulkan device, and whether to validate.
#[derive(Clone, Debug, Default)]
pub struct DeviceChoice {
    pub device: Option<String>,
    pub validation: bool,
    pub reads: Option<gpu::Reads>,
}

pub fn open_device(choice: &DeviceChoice) -> Result<Arc<GpuContext>> {
    let validation =
        choice.validation || std::env::var("QTRACE_VALIDATION").is_ok_and(|v| v == "1");
    Ok(GpuContext::new(&ContextOptions {
        device: choice.device.clone(),
        validation,
        reads: choice.reads,
    })?)
}

/// Checks an output path ends in `.ext` and its directory exists.
pub fn check_output(path: &Path, ext: &str) -> Result<()> {
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

/// A progress bar on a terminal; nothing otherwise.
fn progress_bar(total: Option<u32>) -> Option<ProgressBar> {
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let style = match total {
        Some(_) => "{bar:40.cyan/blue} {pos}/{len} spp  {msg}  elapsed {elapsed}  eta {eta}",
        None => "{bar:40.cyan/blue} {msg}  elapsed {elapsed}",
    };
    let bar = ProgressBar::new(total.map_or(1000, |n| n as u64));
    Some(bar.with_style(ProgressStyle::with_template(style).expect("valid template")))
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

/// What `qtrace render` writes.
#[derive(Clone, Debug)]
pub struct RenderOutputs {
    pub exr: PathBuf,
    pub png: Option<PathBuf>,
    pub stats: Option<PathBuf>,
    pub profile: bool,
    /// Also write all of them every this many seconds, and keep the
    /// render's state beside the EXR to resume it.
    pub checkpoint: Option<f64>,
    /// Go on from the state beside the EXR.
    pub resume: bool,
}

/// Where a render keeps its state: beside its EXR.
pub fn state_path(exr: &Path) -> PathBuf {
    let mut name = exr.file_name().unwrap_or_default().to_os_string();
    name.push(".qtrace-state");
    exr.with_file_name(name)
}

impl RenderOutputs {
    /// Writes the image (with its provenance), the PNG and the stats JSON,
    /// each atomically.
    fn write(&self, scene: &Scene, image: &Image, stats: &render::RenderStats) -> Result<()> {
        let provenance = image::Provenance {
            spp: stats.image_spp,
            method: render::settings::label(&stats.method, stats.nee),
            scene: scene.id(),
            seeds: vec![stats.seed],
        };
        image.write_exr_with(&self.exr, Some(&provenance))?;
        if let Some(p) = &self.png {
            image.write_png(p)?;
        }
        if let Some(p) = &self.stats {
            write_json(p, stats)?;
        }
        Ok(())
    }
}

/// Exit status of a render a signal stopped: 128 + the signal's number.
pub const EXIT_SIGINT: i32 = 130;
pub const EXIT_SIGTERM: i32 = 143;

pub fn render(
    scene_path: &Path,
    defines: &[(String, String)],
    overrides: Overrides,
    guides: &GuideSources,
    out: &RenderOutputs,
    device: &DeviceChoice,
) -> Result<i32> {
    // Check everything the user gave before any GPU work.
    check_outputs(out)?;
    let scene = Scene::load_defined(scene_path, defines)?;
    if !overrides.nee && !scene.delta_lights.is_empty() {
        log::warn!(
            "{}: its point, spot and directional lights reach the image only through NEE (--nee); without, they light nothing",
            scene_path.display()
        );
    }
    let bad = || format!("{}: bad render settings", scene_path.display());
    let method = overrides.method.unwrap_or(Method::PT).name();
    guides
        .check_used(&[method])
        .map_err(anyhow::Error::msg)
        .with_context(bad)?;
    let overrides = Overrides {
        guide: guides
            .resolve(&scene, method)
            .map_err(anyhow::Error::msg)
            .with_context(bad)?,
        ..overrides
    };
    let settings = RenderSettings::resolve(&scene, &overrides).with_context(bad)?;
    let ctx = open_device(device)?;
    let total = match settings.budget {
        render::Budget::Samples(n) => Some(n),
        render::Budget::Seconds(_) => None,
    };
    // SIGINT and SIGTERM end the render after the batch in flight, with
    // every output written; a second one ends the process at once.
    use signal_hook::consts::{SIGINT, SIGTERM};
    let stop = Arc::new(AtomicBool::new(false));
    let by_term = Arc::new(AtomicBool::new(false));
    for (signal, code) in [(SIGINT, EXIT_SIGINT), (SIGTERM, EXIT_SIGTERM)] {
        signal_hook::flag::register_conditional_shutdown(signal, code, stop.clone())?;
        signal_hook::flag::register(signal, stop.clone())?;
    }
    signal_hook::flag::register(SIGTERM, by_term.clone())?;
    let budget = settings.budget;
    let mut renderer = render::Renderer::new(&ctx, &scene, settings)?;
    let state = state_path(&out.exr);
    if out.resume {
        if !state.exists() {
            bail!(
                "{}: no render state to resume (a render keeps one with --checkpoint)",
                state.display()
            );
        }
        let done = renderer.resume(&state)?;
        if let render::Budget::Samples(n) = budget {
            if n <= done {
                bail!(
                    "{}: the render already holds {done} samples per pixel; ask for more with --spp",
                    state.display()
                );
            }
        }
    }
    let bar = progress_bar(total);
    let control = render::Control {
        every_seconds: out.checkpoint,
        stop: Some(&stop),
        state: (out.checkpoint.is_some() || out.resume).then_some(state.as_path()),
        ..Default::default()
    };
    let mut failed = None;
    let result = renderer.run_controlled(
        &mut |p| {
            update_bar(&bar, p);
            if let (Some(b), true) = (&bar, stop.load(Ordering::Relaxed)) {
                b.set_message("stopping after this pass (again to quit at once)");
            }
        },
        &control,
        &mut |c| {
            if failed.is_none() {
                failed = out.write(&scene, &c.image, &c.stats).err();
            }
        },
    )?;
    if let Some(e) = failed {
        return Err(e.context("writing a checkpoint"));
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    out.write(&scene, &result.image, &result.stats)?;
    let s = &result.stats;
    print_summary(s, out.profile);
    check_validation(&ctx)?;
    if s.interrupted {
        eprintln!(
            "interrupted: wrote the {} samples per pixel done",
            s.image_spp
        );
        return Ok(if by_term.load(Ordering::Relaxed) {
            EXIT_SIGTERM
        } else {
            EXIT_SIGINT
        });
    }
    Ok(0)
}

/// The output paths and checkpoint interval a render was given, checked
/// before any work.
fn check_outputs(out: &RenderOutputs) -> Result<()> {
    check_output(&out.exr, "exr")?;
    if let Some(t) = out.checkpoint {
        if !(t.is_finite() && t > 0.0) {
            bail!("--checkpoint {t} must be a positive number of seconds");
        }
    }
    if let Some(p) = &out.png {
        check_output(p, "png")?;
    }
    if let Some(p) = &out.stats {
        check_output(p, "json")?;
    }
    Ok(())
}

/// The lines a finished render prints: its figures, and what the user
/// should know of it.
fn print_summary(s: &render::RenderStats, profile: bool) {
    // Start-up the clock leaves out, where it is worth a mention.
    let compile = if s.compile_seconds >= 0.05 {
        format!(" (+{:.2} s compiling kernels)", s.compile_seconds)
    } else {
        String::new()
    };
    eprintln!(
        "{}: {} spp {}x{} in {:.2} s{compile} on {} | {:.2} Mrays/s | zero-contribution {:.1}% | mean path length {:.2}",
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
    if let (Some(after), Some(because)) = (s.guide_stood_back_after, s.stood_back_because()) {
        eprintln!(
            "the guide stood back after {after} passes: {because}, so the rest was plain path tracing (stand_back = false keeps it)"
        );
    }
    if s.invalid_paths > 0 {
        eprintln!(
            "warning: {} paths gave NaN or infinite radiance and were left out",
            s.invalid_paths
        );
    }
    if profile {
        eprint!("{}", s.profile_table());
        if let Some(f) = &s.guide_fit {
            eprintln!(
                "training: {} steps a pass that trains (measured in the first pass on this device: a step {:.2} ms, a trace pass {:.1} ms)",
                f.training_steps, f.step_ms, f.pass_ms
            );
        }
        if let Some(u) = s.guide_update {
            eprintln!(
                "guide update: one {} a volume",
                if u == crate::guide::Update::Workgroup {
                    "workgroup"
                } else {
                    "invocation"
                }
            );
        }
    }
}

/// `qtrace merge`: averages parts by their sample counts.
pub fn merge(parts: &[PathBuf], output: &Path, stats: Option<&Path>) -> Result<()> {
    check_output(output, "exr")?;
    if let Some(p) = stats {
        check_output(p, "json")?;
    }
    let parts: Vec<image::Part> = parts
        .iter()
        .map(|p| image::Part::read(p))
        .collect::<Result<_, _>>()?;
    let (merged, provenance) = image::merge(&parts).map_err(anyhow::Error::msg)?;
    merged.write_exr_with(output, Some(&provenance))?;
    if let Some(p) = stats {
        #[derive(serde::Serialize)]
        struct PartStats<'a> {
            path: String,
            spp: u32,
            seeds: &'a [u32],
        }
        #[derive(serde::Serialize)]
        struct MergeStats<'a> {
            #[serde(flatten)]
            merged: &'a image::Provenance,
            width: usize,
            height: usize,
            parts: Vec<PartStats<'a>>,
        }
        write_json(
            p,
            &MergeStats {
                merged: &provenance,
                width: merged.width,
                height: merged.height,
                parts: parts
                    .iter()
                    .map(|q| PartStats {
                        path: q.path.display().to_string(),
                        spp: q.provenance.spp,
                        seeds: &q.provenance.seeds,
                    })
                    .collect(),
            },
        )?;
    }
    eprintln!(
        "merged {} parts: {} spp {}x{} of {} ({})",
        parts.len(),
        provenance.spp,
        merged.width,
        merged.height,
        provenance.scene,
        provenance.method
    );
    Ok(())
}

fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let json = serde_json::to_string_pretty(value)?;
    image::write_atomically(path, |tmp| {
        std::fs::write(tmp, &json).map_err(|e| e.to_string())
    })?;
    Ok(())
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

pub fn compare(image_path: &Path, reference_path: &Path) -> Result<()> {
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

pub fn devices() -> Result<()> {
    let devices = gpu::list_devices()?;
    if devices.is_empty() {
        bail!("no Vulkan device found; install a Vulkan driver (mesa-vulkan-drivers provides lavapipe)");
    }
    let yes = |b: bool| if b { "yes" } else { "no" };
    for d in devices {
        println!(
            "[{}] {} ({}, Vulkan {}, {})",
            d.index, d.name, d.kind, d.api_version, d.driver
        );
        println!(
            "    float atomics: {}  int64 atomics: {}  timestamps: {}  subgroup: {} (arithmetic: {}, ballot and vote: {})  max storage buffer: {} MiB  workgroup memory: {} KiB",
            yes(d.float_atomics),
            yes(d.int64_atomics),
            yes(d.timestamps),
            d.subgroup_size,
            yes(d.subgroup_arithmetic),
            yes(d.subgroup_ballot),
            d.max_storage_buffer_range >> 20,
            d.max_shared_memory >> 10
        );
        println!("    trace kernels: {} reads (--reads)", d.reads.name());
    }
    Ok(())
}

/// How many textures the materials use, their files, and the device
/// memory they take.
fn texture_summary(scene: &Scene) -> String {
    if scene.textures.is_empty() {
        return "none".into();
    }
    let bytes = crate::scene::texture::pack(&scene.textures, u64::MAX).map_or(0, |w| 16 * w.len());
    // Mesh attributes: three texels of 16 bytes per triangle each.
    let bytes = bytes + 48 * scene.triangles.len() * scene.attributes.len();
    let mut names: Vec<&str> = scene.textures.iter().map(|t| t.name.as_str()).collect();
    let count = names.len();
    names.sort_unstable();
    names.dedup();
    let mapped = |bump: bool| {
        let maps = scene
            .materials
            .iter()
            .filter(|m| m.normal_map.is_some_and(|n| n.bump.is_some() == bump))
            .count();
        match (maps, bump) {
            (0, _) => String::new(),
            (_, false) => format!("; {maps} normal-mapped materials"),
            (_, true) => format!("; {maps} bump-mapped materials"),
        }
    };
    format!(
        "{count} ({}), {:.2} MiB on the device{}{}",
        names.join(", "),
        bytes as f64 / (1 << 20) as f64,
        mapped(false),
        mapped(true)
    )
}

/// What the emitters' BSDFs do with the paths that reach them, where
/// they do not end them.
fn emitter_bsdfs(scene: &Scene) -> String {
    let count =
        |f: fn(&crate::scene::Material) -> bool| scene.materials.iter().filter(|m| f(m)).count();
    let (passes, scatters) = (
        count(|m| m.emitter_passes()),
        count(|m| m.emitter_reflects()),
    );
    let mut out = String::new();
    if passes > 0 {
        out += &format!("; paths pass through {passes} (a null BSDF)");
    }
    if scatters > 0 {
        out += &format!("; {scatters} scatter them (their BSDF)");
    }
    out
}

/// How many lights the emitters make and how NEE picks among them.
fn light_summary(scene: &Scene) -> String {
    let max = crate::shaders::MAX_GUIDED_LIGHTS;
    let lights = scene.light_group_count();
    let how = if scene.lights_to_pick() {
        "guides learn which one NEE picks where (`pick_lights`)".to_string()
    } else if lights > max as usize {
        format!("NEE picks by emitted power (guides learn the choice among up to {max})")
    } else {
        "NEE picks by emitted power".to_string()
    };
    format!("{lights} (each an emitter's connected triangles, a delta light or the sky; beyond {max}, nearby ones together); {how}")
}

/// The `qtrace inspect` summary of a scene.
pub fn inspect_summary(scene: &Scene) -> String {
    // Folded from +0 (a float sum of nothing is -0, which prints "-0.0000").
    let area = scene.triangles.iter().fold(0.0, |a, t| a + t.area);
    let light_area = scene
        .lights
        .iter()
        .fold(0.0, |a, l| a + scene.triangles[l.triangle as usize].area);
    let c = &scene.camera;
    let mut lines = vec![
        format!("scene        {}", scene.path.display()),
        format!("triangles    {}", scene.triangles.len()),
        format!("materials    {}", material_summary(scene)),
        format!(
            "emitters     {} triangles, {:.4} units² of {:.4} total{}",
            scene.lights.len(),
            light_area,
            area,
            emitter_bsdfs(scene)
        ),
        format!("lights       {}", light_summary(scene)),
        format!("textures     {}", texture_summary(scene)),
        format!(
            "environment  {}",
            match &scene.environment {
                None => "none".to_string(),
                Some(e) if e.name == "constant" => format!("constant {:?}", e.texels[0].to_array()),
                Some(e) if e.model.is_some() => format!(
                    "{} (its model evaluated; NEE draws from a {}x{} map of it), NEE picks it with probability {:.3}",
                    e.name,
                    e.width,
                    e.height,
                    scene.environment_pick()
                ),
                Some(e) => format!(
                    "{} ({}x{}), NEE picks it with probability {:.3}",
                    e.name,
                    e.width,
                    e.height,
                    scene.environment_pick()
                ),
            }
        ),
        format!(
            "bvh          {} nodes of two child boxes, one triangle per leaf, depth {}",
            scene.nodes.len(),
            scene.bvh_depth,
        ),
        format!(
            "camera       at {:?} looking {:?}, fov {}° ({:?} axis), filter {:?}{}{}",
            c.position.to_array(),
            c.forward.to_array(),
            c.fov_degrees,
            c.fov_axis,
            scene.filter,
            c.crop.map_or(String::new(), |k| format!(
                ", the crop {}x{} at ({}, {}) of a {}x{} film",
                k.size.0, k.size.1, k.offset.0, k.offset.1, k.film.0, k.film.1
            )),
            if let Some(o) = c.orthographic {
                format!(", orthographic, {} across half the width", o.half_width)
            } else if c.aperture_radius > 0.0 {
                format!(
                    ", thin lens of radius {} in focus at {}",
                    c.aperture_radius, c.focus_distance
                )
            } else {
                String::new()
            }
        ),
        format!("scene extent {:.3} (bounding-box diagonal)", scene.extent),
        format!("defaults     {}", defaults_summary(&scene.defaults)),
    ];
    for (name, table) in &scene.guide_tables {
        if !table.is_empty() {
            lines.push(format!("[{name}]      {table}").replace('\n', " "));
        }
    }
    lines.join("\n") + "\n"
}

/// The render settings a scene suggests, "(qtrace's)" where it gives none.
fn defaults_summary(d: &crate::scene::file::RenderDefaults) -> String {
    let or =
        |v: Option<u32>, default: u32| v.map_or(format!("{default} (qtrace's)"), |v| v.to_string());
    format!(
        "{} x {} pixels, {} spp, max depth {} bounces{}",
        or(d.width, 256),
        or(d.height, 256),
        or(d.spp, 64),
        or(d.max_depth, 64),
        if d.hide_emitters {
            ", emitters hidden from the camera"
        } else {
            ""
        }
    )
}

pub fn inspect(path: &Path, defines: &[(String, String)]) -> Result<()> {
    let scene = Scene::load_defined(path, defines)?;
    // The guide tables are checked here too, so a typo shows at once.
    RenderSettings::resolve(&scene, &Overrides::default())
        .with_context(|| format!("{}: bad render settings", path.display()))?;
    print!("{}", inspect_summary(&scene));
    Ok(())
}

/// Loads each scene and resolves each method's settings on it, so a typo
/// fails before any GPU work.
fn check_scenes(
    scenes: &[PathBuf],
    defines: &[(String, String)],
    configs: &[bench::Config],
    guides: &GuideSources,
) -> Result<()> {
    let methods: Vec<&str> = configs.iter().map(|c| c.method.name()).collect();
    guides.check_used(&methods).map_err(anyhow::Error::msg)?;
    for path in scenes {
        let scene = Scene::load_defined(path, defines)?;
        for config in configs {
            let guide = guides
                .resolve(&scene, config.method.name())
                .map_err(anyhow::Error::msg)?;
            let o = Overrides {
                method: Some(config.method),
                guide,
                ..Default::default()
            };
            RenderSettings::resolve(&scene, &o)
                .with_context(|| format!("{}: bad render settings", path.display()))?;
        }
    }
    Ok(())
}

pub fn bench_speed(plan: &SpeedPlan<'_>, json: Option<&Path>, device: &DeviceChoice) -> Result<()> {
    if let Some(p) = json {
        check_output(p, "json")?;
    }
    check_scenes(plan.scenes, plan.defines, plan.configs, plan.guides)?;
    let ctx = open_device(device)?;
    let info = ctx.info();
    println!(
        "device: {} ({}; {} reads)",
        info.name,
        info.driver,
        info.reads.name()
    );
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
        write_json(p, &report)?;
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

pub fn evaluate(mut plan: EvalPlan, device: &DeviceChoice) -> Result<()> {
    plan.validate().map_err(anyhow::Error::msg)?;
    check_scenes(&plan.scenes, &plan.defines, &plan.configs, &plan.guides)?;
    bench::charts::ensure_font().map_err(anyhow::Error::msg)?;
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("{}: cannot create the report directory", plan.out.display()))?;
    let ctx = open_device(device)?;
    let bar = std::io::stderr().is_terminal().then(|| {
        ProgressBar::new(1).with_style(
            ProgressStyle::with_template(
                "{bar:40.cyan/blue} {percent:>3}%  {msg}  elapsed {elapsed}  eta {eta}",
            )
            .expect("valid template"),
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
        "{:<20} {:<12} {:>8} {:>12} {:>14} {:>10} {:>11} {:>9}",
        "scene", "method", "zero %", "relMSE", "relMSE@time", "Mrays/s", "later half", "vs plain"
    );
    let mut extrapolated = false;
    for s in &report.scenes {
        for r in &s.runs {
            extrapolated |= r.equal_time_extrapolated;
            println!(
                "{:<20} {:<12} {:>8.2} {:>12.5} {:>13.5}{} {:>10.3} {:>11} {:>9}",
                s.name,
                r.config,
                100.0 * r.zero_contribution_fraction,
                r.checkpoints.last().map_or(f64::NAN, |c| c.error.rel_mse),
                r.error_at_equal_time.rel_mse,
                if r.equal_time_extrapolated { "*" } else { " " },
                r.rays_per_second / 1e6,
                r.later_half_cost
                    .map_or("-".to_string(), |c| format!("{c:.2}x")),
                r.over_plain.map_or("-".to_string(), |c| format!("{c:.2}x"))
            );
        }
        for r in s.runs.iter() {
            if let (Some(after), Some(because)) =
                (r.guide_stood_back_after, &r.guide_stood_back_because)
            {
                println!(
                    "{}: {}'s guide stood back after {after} passes (plain path tracing from there): {because}",
                    s.name, r.config
                );
            }
        }
        for r in s.runs.iter().filter(|r| r.guide_bytes > 0) {
            let spp = bench::eval::spp_at_time(&r.checkpoints, s.equal_time_seconds);
            if spp < bench::eval::LEARNING_SPP {
                let longer = if plan.seconds.is_some() {
                    "more --seconds"
                } else {
                    "a longer --spp-list, --seconds"
                };
                println!(
                    "{}: at equal time ({:.3} s) {} had rendered about {spp:.0} spp, most of them passes that learn: equal time measures its guide's start-up here; {longer} or a larger image measures a render",
                    s.name, s.equal_time_seconds, r.config
                );
            }
        }
        println!("{}", reference_floor_line(s));
    }
    if extrapolated {
        println!(
            "* equal time came before that method's first checkpoint: its error there is extrapolated (relMSE as 1/time); a smaller --spp-list entry measures it"
        );
    }
    println!("report: {}", plan.out.join("index.html").display());
    check_validation(&ctx)
}

/// "7 (5 diffuse, 1 conductor, 1 glass)": how many materials of each kind.
fn material_summary(scene: &Scene) -> String {
    let mut kinds: Vec<(&str, usize)> = Vec::new();
    for m in &scene.materials {
        let name = m.kind_name();
        match kinds.iter_mut().find(|(k, _)| *k == name) {
            Some((_, n)) => *n += 1,
            None => kinds.push((name, 1)),
        }
    }
    kinds.sort_by_key(|&(_, n)| std::cmp::Reverse(n));
    let kinds: Vec<String> = kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
    let anisotropic = scene
        .materials
        .iter()
        .filter(|m| m.surface.anisotropic())
        .count();
    let anisotropic = match anisotropic {
        0 => String::new(),
        n => format!("; {n} with anisotropic roughness"),
    };
    format!(
        "{} ({}){anisotropic}",
        scene.materials.len(),
        kinds.join(", ")
    )
}
