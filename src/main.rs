//! The `qtrace` command line.

use anyhow::Result;
use clap::{Parser, Subcommand};
use qtrace::bench::{Config, EvalPlan, SpeedPlan};
use qtrace::cli::{self, DeviceChoice, RenderOutputs};
use qtrace::guide::GuideSources;
use qtrace::render::{Method, Overrides, Sampling};
use std::path::PathBuf;

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
    /// How the trace kernels read the scene (also QTRACE_READS); default: the
    /// faster for the driver, as `qtrace devices` shows. Images are the same.
    #[arg(long, value_enum, env = "QTRACE_READS")]
    reads: Option<qtrace::gpu::Reads>,
}

impl DeviceArgs {
    fn choice(&self) -> DeviceChoice {
        DeviceChoice {
            device: self.device.clone(),
            validation: self.validation,
            reads: self.reads,
        }
    }
}

/// Mitsuba's `-D name=value`: a parameter of an XML scene (its `$name`).
fn parse_define(text: &str) -> Result<(String, String), String> {
    match text.split_once('=') {
        Some((k, v))
            if !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') =>
        {
            Ok((k.to_string(), v.to_string()))
        }
        _ => Err(format!("'{text}' is not NAME=VALUE")),
    }
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
    /// Random seed; the same seed gives the same image, bit for bit (sarsa:
    /// with its default fixed-point tallies).
    #[arg(long)]
    seed: Option<u32>,
    /// How diffuse surfaces sample directions (alone, or as the BSDF half of a guide's mixture); metal and glass always sample their own lobes.
    #[arg(long, value_enum)]
    sampling: Option<Sampling>,
    #[command(flatten)]
    guides: GuideArgs,
}

/// Guide settings beyond the scene's `[sarsa]` and `[neural]` tables.
#[derive(clap::Args, Clone)]
struct GuideArgs {
    /// Guide settings: a TOML file of [sarsa] and [neural] tables (keys as
    /// in the scene file's tables; docs/guides.md lists them).
    #[arg(long, value_name = "FILE")]
    guide_config: Option<PathBuf>,
    /// One guide setting, e.g. sarsa.epsilon=0.3 or neural.grid=[8,8]
    /// (repeatable; after the scene's tables and --guide-config).
    #[arg(long = "set", value_name = "GUIDE.KEY=VALUE")]
    sets: Vec<String>,
}

impl GuideArgs {
    fn sources(&self) -> GuideSources {
        GuideSources {
            config: self.guide_config.clone(),
            sets: self.sets.clone(),
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
            guide: None,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to OpenEXR (and optionally PNG and stats JSON).
    Render {
        /// Scene file: qtrace TOML, or Mitsuba 3 XML (.xml).
        scene: PathBuf,
        /// A parameter of an XML scene, as Mitsuba's -D (repeatable).
        #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
        define: Vec<(String, String)>,
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
        /// Write the image, PNG and stats so far every this many seconds, and
        /// keep the render's state beside the EXR (OUT.exr.qtrace-state).
        #[arg(long, value_name = "SECONDS")]
        checkpoint: Option<f64>,
        /// Go on from the state a --checkpoint render left beside -o, to
        /// --spp in all or for --time more seconds.
        #[arg(long)]
        resume: bool,
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
    /// Average renders of one scene and method, made apart with different
    /// --seed values, weighted by their sample counts.
    Merge {
        /// EXR parts written by `qtrace render`.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// Merged linear float RGB OpenEXR output.
        #[arg(short, long)]
        output: PathBuf,
        /// Statistics JSON output: the parts and the total.
        #[arg(long)]
        stats: Option<PathBuf>,
    },
    /// List Vulkan devices and the features qtrace uses.
    Devices,
    /// Triangles, lights, BVH statistics of a scene.
    Inspect {
        /// Scene file: qtrace TOML, or Mitsuba 3 XML (.xml).
        scene: PathBuf,
        /// A parameter of an XML scene, as Mitsuba's -D (repeatable).
        #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
        define: Vec<(String, String)>,
    },
    /// Compare methods: images, error vs spp and vs time, per-pass statistics,
    /// pictures of what was learned, charts, CSV/JSON and an HTML page
    /// (with --speed: only a table of samples/s, rays/s and GPU ms per pass).
    Bench {
        /// Scenes to evaluate (TOML, or Mitsuba 3 XML).
        #[arg(default_values = ["scenes/cornell-box.toml"])]
        scenes: Vec<PathBuf>,
        /// A parameter of the XML scenes, as Mitsuba's -D (repeatable).
        #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
        define: Vec<(String, String)>,
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
        /// Render each method for this many seconds (of its own render
        /// time) instead of to the largest --spp-list count, and compare
        /// errors there: equal time that means a render on a fast device.
        #[arg(long, conflicts_with = "speed")]
        seconds: Option<f64>,
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
        guides: GuideArgs,
        #[command(flatten)]
        device: DeviceArgs,
    },
}

fn run(cli: Cli) -> Result<()> {
    match &cli.command {
        Command::Render {
            scene,
            define,
            args,
            output,
            png,
            stats,
            profile,
            checkpoint,
            resume,
            device,
        } => cli::render(
            scene,
            define,
            args.overrides(),
            &args.guides.sources(),
            &RenderOutputs {
                exr: output.clone(),
                png: png.clone(),
                stats: stats.clone(),
                profile: *profile,
                checkpoint: *checkpoint,
                resume: *resume,
            },
            &device.choice(),
        )
        .map(|code| {
            if code != 0 {
                std::process::exit(code);
            }
        }),
        Command::Compare { image, reference } => cli::compare(image, reference),
        Command::Merge {
            parts,
            output,
            stats,
        } => cli::merge(parts, output, stats.as_deref()),
        Command::Devices => cli::devices(),
        Command::Inspect { scene, define } => cli::inspect(scene, define),
        Command::Bench {
            scenes,
            define,
            methods,
            spp_list,
            width,
            height,
            reference,
            reference_spp,
            out,
            quick,
            seed,
            seconds,
            speed,
            spp,
            repeats,
            json,
            peer,
            guides,
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
                    guides: &guides.sources(),
                    defines: define,
                };
                return cli::bench_speed(&plan, json.as_deref(), &device.choice());
            }
            let mut plan = EvalPlan::quick(scenes.clone(), methods.clone(), out.clone());
            if !*quick {
                plan.spp_list = spp_list.clone();
                plan.reference_spp = 1024;
            }
            plan.width = width;
            plan.height = height;
            plan.seed = *seed;
            plan.seconds = *seconds;
            plan.reference = reference.clone();
            plan.guides = guides.sources();
            plan.defines = define.clone();
            if let Some(n) = reference_spp {
                plan.reference_spp = *n;
            }
            cli::evaluate(plan, &device.choice())
        }
    }
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn"))
        .format_timestamp(None)
        .init();
    // Output into a closed pipe (`qtrace devices | head -1`) ends the process
    // quietly, as SIGPIPE ends other tools, where println! would panic.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.starts_with("failed printing to stdout") && message.contains("Broken pipe") {
            std::process::exit(141);
        }
        default_hook(info);
    }));
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
