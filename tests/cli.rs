//! Every kind of bad input through the real binary: a one-line error that
//! names the file and the problem, a non-zero exit, no panic, no output file.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn qtrace() -> Command {
    let mut c = common::qtrace();
    c.env_remove("QTRACE_DEVICE").env("RUST_BACKTRACE", "1");
    c
}

/// A scratch directory holding copies of the Cornell box files.
fn scratch(name: &str) -> PathBuf {
    let dir = common::scratch(name);
    for f in ["cornell-box.toml", "cornell-box.obj", "cornell-box.mtl"] {
        std::fs::copy(common::repo(&format!("scenes/{f}")), dir.join(f)).unwrap();
    }
    dir
}

fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{} lacks '{from}'", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

/// Runs `qtrace render <scene> args…` writing into `dir`, expects failure with
/// one line on stderr containing every `needles` item, and no output left behind.
fn expect_error(dir: &Path, scene: &Path, args: &[&str], env: &[(&str, &str)], needles: &[&str]) {
    let out_exr = dir.join("out.exr");
    let out_png = dir.join("out.png");
    let out_json = dir.join("out.json");
    let mut cmd = qtrace();
    cmd.arg("render")
        .arg(scene)
        .args(args)
        .arg("-o")
        .arg(&out_exr);
    cmd.arg("--png").arg(&out_png).arg("--stats").arg(&out_json);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let output = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success(),
        "expected failure for {args:?}, got success; stderr: {stderr}"
    );
    assert_ne!(output.status.code(), Some(101), "panicked: {stderr}");
    assert!(!stderr.contains("panicked"), "panicked: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {stderr}");
    assert!(lines[0].starts_with("error: "), "{stderr}");
    for n in needles {
        assert!(
            lines[0].contains(n),
            "'{}' does not mention '{n}'",
            lines[0]
        );
    }
    for f in [&out_exr, &out_png, &out_json] {
        assert!(!f.exists(), "{} was written despite the error", f.display());
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

#[test]
fn missing_scene() {
    let dir = scratch("missing");
    expect_error(
        &dir,
        &dir.join("nope.toml"),
        &[],
        &[],
        &["nope.toml", "cannot read"],
    );
}

#[test]
fn malformed_toml_names_the_line() {
    let dir = scratch("malformed-toml");
    let scene = dir.join("cornell-box.toml");
    edit(&scene, "fov_y    = 39.3", "fov_y    = = 39.3");
    expect_error(&dir, &scene, &[], &[], &["cornell-box.toml:6"]);
}

#[test]
fn unknown_key_is_an_error() {
    let dir = scratch("unknown-key");
    let scene = dir.join("cornell-box.toml");
    edit(&scene, "[render]", "[render]\nsamples = 4");
    expect_error(&dir, &scene, &[], &[], &["cornell-box.toml", "samples"]);
}

#[test]
fn missing_mesh() {
    let dir = scratch("missing-mesh");
    std::fs::remove_file(dir.join("cornell-box.obj")).unwrap();
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.obj", "not found"],
    );
}

#[test]
fn malformed_obj() {
    let dir = scratch("malformed-obj");
    let obj = dir.join("cornell-box.obj");
    let text = std::fs::read_to_string(&obj).unwrap();
    let first_v = text
        .lines()
        .find(|l| l.starts_with("v "))
        .unwrap()
        .to_string();
    edit(&obj, &first_v, "v 1.0 abc 2.0");
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.obj", "malformed OBJ"],
    );
}

#[test]
fn missing_mtl() {
    let dir = scratch("missing-mtl");
    std::fs::remove_file(dir.join("cornell-box.mtl")).unwrap();
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.obj", "MTL"],
    );
}

#[test]
fn scene_without_emitter() {
    let dir = scratch("no-emitter");
    let mtl = dir.join("cornell-box.mtl");
    let text = std::fs::read_to_string(&mtl).unwrap();
    let cleaned: String = text
        .lines()
        .filter(|l| !l.trim_start().starts_with("Ke"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&mtl, cleaned).unwrap();
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.toml", "no emitter"],
    );
}

fn append_obj(dir: &Path, extra: &str) {
    let obj = dir.join("cornell-box.obj");
    let mut text = std::fs::read_to_string(&obj).unwrap();
    let base = text.lines().filter(|l| l.starts_with("v ")).count();
    text.push_str(
        &extra
            .replace("{n}", &(base + 1).to_string())
            .replace("{n1}", &(base + 2).to_string())
            .replace("{n2}", &(base + 3).to_string()),
    );
    std::fs::write(&obj, text).unwrap();
}

#[test]
fn zero_area_triangle() {
    let dir = scratch("zero-area");
    append_obj(&dir, "\nv 1 1 1\nv 2 2 2\nv 3 3 3\nf {n} {n1} {n2}\n");
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.obj", "zero area"],
    );
}

#[test]
fn nan_vertex() {
    let dir = scratch("nan-vertex");
    append_obj(&dir, "\nv 1 1 1\nv NaN 2 2\nv 3 1 3\nf {n} {n1} {n2}\n");
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &["cornell-box.obj", "NaN"],
    );
}

#[test]
fn absurd_options() {
    let dir = scratch("absurd");
    let scene = dir.join("cornell-box.toml");
    expect_error(
        &dir,
        &scene,
        &["--width", "0", "--height", "0"],
        &[],
        &["0x0"],
    );
    expect_error(&dir, &scene, &["--spp", "0"], &[], &["spp 0"]);
    expect_error(&dir, &scene, &["--width", "100000"], &[], &["exceeds"]);
    expect_error(&dir, &scene, &["--time=-3"], &[], &["time"]);
    expect_error(
        &dir,
        &scene,
        &["--max-depth", "100000"],
        &[],
        &["max depth"],
    );
}

#[test]
fn bad_camera_in_scene() {
    let dir = scratch("bad-camera");
    let scene = dir.join("cornell-box.toml");
    edit(&scene, "fov_y    = 39.3", "fov_y    = 0.0");
    expect_error(&dir, &scene, &[], &[], &["cornell-box.toml", "fov_y"]);
}

#[test]
fn output_directory_missing() {
    let dir = scratch("no-outdir");
    let output = qtrace()
        .args(["render"])
        .arg(dir.join("cornell-box.toml"))
        .arg("-o")
        .arg(dir.join("nowhere/out.exr"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("nowhere") && stderr.contains("does not exist"),
        "{stderr}"
    );
}

#[test]
fn no_vulkan_device() {
    let dir = scratch("no-device");
    let scene = dir.join("cornell-box.toml");
    // A loader that finds no driver at all.
    let icd = dir.join("none.json");
    expect_error(
        &dir,
        &scene,
        &[],
        &[
            ("VK_ICD_FILENAMES", icd.to_str().unwrap()),
            ("VK_DRIVER_FILES", icd.to_str().unwrap()),
        ],
        &["no Vulkan device"],
    );
    expect_error(
        &dir,
        &scene,
        &["--device", "no-such-gpu"],
        &[],
        &["no-such-gpu"],
    );
}

#[test]
fn compare_reports_missing_and_mismatched_images() {
    let dir = scratch("compare");
    let output = qtrace()
        .arg("compare")
        .arg(dir.join("a.exr"))
        .arg(dir.join("b.exr"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(stderr.contains("a.exr"), "{stderr}");
}

#[test]
fn render_writes_exr_png_stats_and_profile() {
    let dir = scratch("happy");
    let (exr, png, json) = (dir.join("a.exr"), dir.join("a.png"), dir.join("a.json"));
    let output = qtrace()
        .arg("render")
        .arg(dir.join("cornell-box.toml"))
        .args([
            "--spp",
            "3",
            "--width",
            "24",
            "--height",
            "16",
            "--nee",
            "--profile",
            "--validation",
            "-o",
        ])
        .arg(&exr)
        .arg("--png")
        .arg(&png)
        .arg("--stats")
        .arg(&json)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("trace") && stderr.contains("accumulate") && stderr.contains("median ms"),
        "no profile table: {stderr}"
    );
    let image = qtrace::image::Image::read_exr(&exr).unwrap();
    assert_eq!((image.width, image.height), (24, 16));
    assert!(std::fs::metadata(&png).unwrap().len() > 0);
    let stats = common::read_json(&json);
    assert_eq!(stats["spp"], 3);
    assert_eq!(stats["method"], "pt");
    assert_eq!(stats["passes"].as_array().unwrap().len(), 3);
    assert!(stats["gpu_ms"]["trace"].as_f64().unwrap() > 0.0);

    // compare: an image against itself has zero error.
    let output = qtrace()
        .arg("compare")
        .arg(&exr)
        .arg(&exr)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success());
    assert!(stdout.contains("MSE     0.000000e0"), "{stdout}");
}

/// llvmpipe compiles a kernel at its first dispatch. With Mesa's shader
/// cache off, every render compiles its kernels: that time is reported apart
/// and is in neither a pass's time nor the render's clock (a bench's equal
/// time would otherwise charge a method's start-up to its samples).
#[test]
fn kernel_compiles_stay_out_of_pass_times_and_the_clock() {
    let dir = scratch("compile");
    let json = dir.join("c.json");
    let output = qtrace()
        .env("MESA_SHADER_CACHE_DISABLE", "true")
        .arg("render")
        .arg(dir.join("cornell-box.toml"))
        .args([
            "--spp", "4", "--width", "16", "--height", "16", "--nee", "-o",
        ])
        .arg(dir.join("c.exr"))
        .arg("--stats")
        .arg(&json)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let stats = common::read_json(&json);
    let compile = stats["compile_seconds"].as_f64().unwrap();
    if !stats["device"].as_str().unwrap().contains("llvmpipe") {
        eprintln!("skipped the size check: only llvmpipe is known to compile at first dispatch");
        return;
    }
    // A kernel's compile takes hundreds of milliseconds, a 16x16 pass a few.
    assert!(compile > 0.05, "compile {compile} s: {stderr}");
    assert!(stderr.contains("compiling kernels"), "{stderr}");
    let wall = stats["wall_seconds"].as_f64().unwrap();
    assert!(
        wall < compile,
        "clock {wall} s holds the compile ({compile} s)"
    );
    for pass in stats["gpu_passes"].as_array().unwrap() {
        let max_ms = pass["max_ms"].as_f64().unwrap();
        assert!(
            max_ms < 1e3 * compile / 2.0,
            "{pass} holds the compile ({compile} s)"
        );
    }
}

#[test]
fn sarsa_render_reports_its_guide() {
    let dir = scratch("sarsa-happy");
    let json = dir.join("s.json");
    let output = qtrace()
        .arg("render")
        .arg(dir.join("cornell-box.toml"))
        .args([
            "--method",
            "sarsa",
            "--spp",
            "4",
            "--width",
            "16",
            "--height",
            "16",
            "--set",
            "sarsa.volumes=64",
        ])
        .args([
            "--set",
            "sarsa.grid=[6, 6]",
            "--set",
            "sarsa.atomics=cas",
            "--set",
            "sarsa.update=workgroup",
            "--validation",
            "-o",
        ])
        .arg(dir.join("s.exr"))
        .arg("--stats")
        .arg(&json)
        .output()
        .unwrap();
    common::assert_success(&output);
    let stats = common::read_json(&json);
    assert_eq!(stats["method"], "sarsa");
    assert_eq!(stats["guide_volumes"], 64);
    assert!(stats["guide_bytes"].as_u64().unwrap() > 64 * 36 * 4);
    assert!(stats["passes"][0]["loss"].as_f64().is_some());
    assert!(stats["gpu_ms"]["guide update"].as_f64().is_some());
    assert_eq!(stats["guide_update"], "workgroup");
}

#[test]
fn bad_sarsa_options() {
    let dir = scratch("bad-sarsa");
    let scene = dir.join("cornell-box.toml");
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "sarsa.epsilon=0"],
        &[],
        &["epsilon"],
    );
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "sarsa.grid=[0, 5]"],
        &[],
        &["[sarsa] grid"],
    );
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "sarsa.grid=twelve"],
        &[],
        &["[sarsa]", "grid"],
    );
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "sarsa.memory_mib=0.0001"],
        &[],
        &["memory"],
    );
    expect_error(
        &dir,
        &scene,
        &[
            "--method",
            "sarsa",
            "--spp",
            "8",
            "--set",
            "sarsa.reset_after=8",
        ],
        &[],
        &["reset"],
    );
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "sarsa.volumes=4000000"],
        &[],
        &["fewer volumes"],
    );
    // 4096 sectors take 80 KiB of a workgroup's memory: more than any
    // device lends (Vulkan asks for at least 16 KiB, lavapipe has 32).
    expect_error(
        &dir,
        &scene,
        &[
            "--method",
            "sarsa",
            "--set",
            "sarsa.grid=[64, 64]",
            "--set",
            "sarsa.update=workgroup",
        ],
        &[],
        &["[sarsa] update = \"workgroup\"", "KiB of workgroup memory"],
    );
}

#[test]
fn devices_and_inspect() {
    let output = qtrace().arg("devices").output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    common::assert_success(&output);
    assert!(stdout.contains("float atomics"), "{stdout}");
    let output = qtrace()
        .arg("inspect")
        .arg(common::repo("scenes/complex-direct.toml"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success());
    let triangles: u64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("triangles"))
        .and_then(|v| v.trim().parse().ok())
        .expect("a triangle count");
    assert!(triangles >= 100_000, "{stdout}");
    assert!(
        stdout.contains("lights       1 (each an emitter's connected triangles, a delta light or the sky; beyond 16, nearby ones together); NEE picks by emitted power"),
        "{stdout}"
    );
    let output = qtrace()
        .arg("inspect")
        .arg(common::repo("scenes/several-lights.toml"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        stdout.contains("lights       3 (each an emitter's connected triangles, a delta light or the sky; beyond 16, nearby ones together); guides learn which one NEE picks"),
        "{stdout}"
    );
    // A TOML scene's emitters end paths, whatever their Kd.
    assert!(!stdout.contains("scatter them"), "{stdout}");
    // A thin lens, hidden emitters, normal and bump maps, masks and blends,
    // principled materials, anisotropic roughness, mesh attributes (on the
    // device: three corners of each of four per triangle) and what emitters'
    // BSDFs do with paths show.
    for (scene, want) in [
        ("coverage-i.xml", "thin lens of radius 0.12 in focus at 4"),
        ("coverage-h.xml", "emitters hidden from the camera"),
        ("coverage-j.xml", "4 normal-mapped materials"),
        (
            "choices.xml",
            "6 diffuse, 2 null, 2 mask, 1 blend, 1 two-faced",
        ),
        ("coverage-m.xml", "5 bump-mapped materials"),
        ("coverage-n.xml", "materials    8 (7 principled, 1 diffuse)"),
        ("coverage-o.xml", "; 5 with anisotropic roughness"),
        ("coverage-q.xml", "; paths pass through 3 (a null BSDF)"),
        ("crop.xml", ", the crop 40x24 at (14, 10) of a 64x48 film"),
        ("coverage-r.xml", "; 3 scatter them (their BSDF)"),
        (
            "coverage-p.xml",
            "mesh attribute 'vertex_color', mesh attribute 'vertex_rough', mesh attribute 'vertex_w'), 0.72 MiB on the device",
        ),
    ] {
        let output = qtrace()
            .arg("inspect")
            .arg(common::repo("tests/fixtures/mitsuba").join(scene))
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(stdout.contains(want), "{scene}: {stdout}");
    }
}

#[test]
fn neural_render_reports_loss_and_training_passes() {
    let dir = scratch("neural");
    let json = dir.join("n.json");
    let output = qtrace()
        .arg("render")
        .arg(dir.join("cornell-box.toml"))
        .args([
            "--method",
            "neural",
            "--spp",
            "4",
            "--width",
            "16",
            "--height",
            "16",
            "--set",
            "neural.width=8",
            "--set",
            "neural.grid=[4, 4]",
            "--validation",
        ])
        // The Q-learning target too, where it is built.
        .args(match cfg!(feature = "experiments") {
            true => &["--set", "neural.target=max"][..],
            false => &[],
        })
        .arg("-o")
        .arg(dir.join("n.exr"))
        .arg("--stats")
        .arg(&json)
        .output()
        .unwrap();
    common::assert_success(&output);
    let stats = common::read_json(&json);
    assert_eq!(stats["method"], "neural");
    assert!(stats["guide_bytes"].as_u64().unwrap() > 0);
    assert!(stats["passes"][3]["loss"].as_f64().is_some());
    for pass in ["trace", "mlp training", "mlp Adam step", "mlp batch reset"] {
        assert!(stats["gpu_ms"][pass].as_f64().is_some(), "{pass}: {stats}");
    }
}

#[test]
fn bad_neural_options() {
    let dir = scratch("bad-neural");
    let scene = dir.join("cornell-box.toml");
    for (set, message) in [
        ("neural.width=100", "width"),
        ("neural.width=6", "width"),
        ("neural.learning_rate=0", "learning_rate"),
        ("neural.batch=0", "batch"),
        ("neural.epsilon=0", "epsilon"),
        ("neural.grid=[0, 4]", "grid"),
        ("neural.layers=0", "layers"),
        ("neural.layers=-1", "layers"),
        ("neural.encoding=fourier", "encoding"),
        ("neural.inference=everywhere", "inference"),
        ("neural.volumes=0", "volumes"),
        ("neural.prior_visits=-1", "prior_visits"),
        ("neural.prior_visits=nan", "prior_visits"),
        ("neural.widht=8", "unknown field"),
    ] {
        expect_error(
            &dir,
            &scene,
            &["--method", "neural", "--set", set],
            &[],
            &["[neural]", message],
        );
    }
    // The Cornell box's 32 vertices, encoded, overflow a 64-wide network's
    // workgroup memory; without the experiments, the encoding is refused.
    let vertices_error: &[&str] = if cfg!(feature = "experiments") {
        &[
            "encoding = \"vertices\"",
            "vertices give",
            "width = 28 would fit",
        ]
    } else {
        &["encoding = \"vertices\"", "--features experiments"]
    };
    expect_error(
        &dir,
        &scene,
        &[
            "--method",
            "neural",
            "--set",
            "neural.encoding=vertices",
            "--set",
            "neural.width=64",
        ],
        &[],
        vertices_error,
    );
    expect_error(
        &dir,
        &scene,
        &[
            "--method",
            "neural",
            "--spp",
            "8",
            "--set",
            "neural.reset_after=8",
        ],
        &[],
        &["[neural] reset_after"],
    );
    // A batch whose activations (512 MiB) exceed a storage buffer (128 MiB
    // on lavapipe; a GPU may allow 4 GiB, and then it renders).
    let devices = qtrace().arg("devices").output().unwrap();
    let largest = String::from_utf8_lossy(&devices.stdout)
        .split("max storage buffer: ")
        .skip(1)
        .filter_map(|rest| rest.split(" MiB").next()?.parse::<u64>().ok())
        .max()
        .expect("qtrace devices names each device's largest storage buffer");
    if largest >= 512 {
        eprintln!(
            "skipped the batch that overflows a storage buffer: a device allows {largest} MiB"
        );
    } else {
        expect_error(
            &dir,
            &scene,
            &[
                "--method",
                "neural",
                "--set",
                "neural.batch=262144",
                "--set",
                "neural.width=64",
                "--set",
                "neural.layers=8",
            ],
            &[],
            &["batch in [neural]", "MiB"],
        );
    }
    // Training on the volumes' means needs inference at the volumes.
    expect_error(
        &dir,
        &scene,
        &[
            "--method",
            "neural",
            "--set",
            "neural.training=volumes",
            "--set",
            "neural.inference=vertices",
        ],
        &[],
        &["[neural] training", "inference"],
    );
    // Tables at the volumes beyond a storage buffer.
    expect_error(
        &dir,
        &scene,
        &["--method", "neural", "--set", "neural.volumes=4194304"],
        &[],
        &["neural volumes", "sectors in [neural]", "MiB"],
    );
}

/// Guide settings come from the scene's table, then --guide-config, then
/// --set, key by key; the stats JSON gives back every key, and those
/// settings, as a config file, render the same guide again.
#[test]
fn guide_settings_layer_and_round_trip() {
    let dir = scratch("guide-config");
    let scene = dir.join("cornell-box.toml");
    let text = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(
        &scene,
        format!("{text}\n[sarsa]\nepsilon = 0.4\nvolumes = 64\nfreeze_after = 2\n"),
    )
    .unwrap();
    let config = dir.join("guides.toml");
    std::fs::write(
        &config,
        "[sarsa]\nepsilon = 0.3\ngrid = [6, 6]\n\n[neural]\nwidth = 8\n",
    )
    .unwrap();
    let render = |extra: &[&str], json: &Path| {
        let output = qtrace()
            .arg("render")
            .arg(&scene)
            .args([
                "--method", "sarsa", "--spp", "3", "--width", "16", "--height", "16",
            ])
            .args(extra)
            .arg("-o")
            .arg(dir.join("g.exr"))
            .arg("--stats")
            .arg(json)
            .output()
            .unwrap();
        common::assert_success(&output);
        let stats = common::read_json(json);
        stats["guide"]["sarsa"].clone()
    };
    let first = dir.join("first.json");
    let config_arg = config.to_str().unwrap();
    let g = render(
        &["--guide-config", config_arg, "--set", "sarsa.grid=[4, 5]"],
        &first,
    );
    assert_eq!(g["epsilon"], 0.3, "{g}");
    assert_eq!(g["grid"], serde_json::json!([4, 5]), "{g}");
    assert_eq!(g["volumes"], 64, "{g}");
    assert_eq!(g["freeze_after"], 2, "{g}");
    assert_eq!(g["atomics"], "auto", "{g}");

    // The reported settings as a config file give the same guide.
    let table: toml::Table = serde_json::from_value(g.clone()).unwrap();
    let mut file = toml::Table::new();
    file.insert("sarsa".into(), toml::Value::Table(table));
    let again = dir.join("again.toml");
    std::fs::write(&again, toml::to_string(&file).unwrap()).unwrap();
    let g2 = render(
        &["--guide-config", again.to_str().unwrap()],
        &dir.join("second.json"),
    );
    assert_eq!(g, g2);

    // A config table that is no guide, and a --set for another guide, are errors.
    std::fs::write(&config, "[sarsaa]\nepsilon = 0.3\n").unwrap();
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--guide-config", config_arg],
        &[],
        &["sarsaa", "not a guide table"],
    );
    expect_error(
        &dir,
        &scene,
        &["--method", "sarsa", "--set", "neural.width=8"],
        &[],
        &["neural", "method is sarsa"],
    );
    // A typo in the scene's own table fails whatever the method.
    std::fs::write(&scene, format!("{text}\n[neural]\nwidht = 8\n")).unwrap();
    expect_error(&dir, &scene, &[], &[], &["[neural]", "widht"]);
}

/// A truncated MTL colour line (`Kd 0.78 0.`) once panicked inside the OBJ
/// library; it is a one-line error naming the MTL file and its line.
#[test]
fn truncated_mtl_colour() {
    let dir = scratch("truncated-mtl");
    let mtl = dir.join("cornell-box.mtl");
    edit(&mtl, "Kd 0.725 0.71 0.68", "Kd 0.78 0.");
    expect_error(
        &dir,
        &dir.join("cornell-box.toml"),
        &[],
        &[],
        &[
            "cornell-box.mtl",
            "malformed MTL: line 4: Kd: a number is missing",
        ],
    );
    let output = qtrace()
        .arg("inspect")
        .arg(dir.join("cornell-box.toml"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
}

/// `--checkpoint` writes every output while the render runs; SIGINT or
/// SIGTERM ends it after the pass in flight with every output written,
/// `"interrupted": true`, the samples done, and exit status 130 or 143.
#[test]
fn checkpoints_and_signals_leave_complete_outputs() {
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let dir = scratch(&format!("signal{signal}"));
        let (exr, json) = (dir.join("s.exr"), dir.join("s.json"));
        let mut child = qtrace()
            .arg("render")
            .arg(dir.join("cornell-box.toml"))
            .args(["--width", "32", "--height", "32", "--spp", "1000000"])
            .args(["--checkpoint", "0.2", "-o"])
            .arg(&exr)
            .arg("--png")
            .arg(dir.join("s.png"))
            .arg("--stats")
            .arg(&json)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // The first checkpoint: every output, the render still running.
        let start = std::time::Instant::now();
        while !json.exists() {
            assert!(start.elapsed().as_secs() < 120, "no checkpoint written");
            // A render that ends early (no device, say) fails the test at
            // once rather than after the wait.
            if child.try_wait().unwrap().is_some() {
                let mut stderr = String::new();
                std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
                panic!("the render ended before its first checkpoint: {stderr}");
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        let stats = common::read_json(&json);
        assert_eq!(stats["interrupted"], false);
        assert!(stats["spp"].as_u64().unwrap() > 0);
        assert!(exr.exists() && dir.join("s.png").exists());
        let status = Command::new("kill")
            .arg(signal)
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(status.success());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{stderr}");
        assert!(stderr.contains("interrupted"), "{stderr}");
        let stats = common::read_json(&json);
        assert_eq!(stats["interrupted"], true);
        let spp = stats["spp"].as_u64().unwrap();
        assert!(spp > 0 && spp < 1_000_000, "{spp}");
        let part = qtrace::image::Part::read(&exr).unwrap();
        assert_eq!(part.provenance.spp as u64, spp);
        // No temporary file is left behind.
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .filter(|n| n.contains(".tmp."))
            .collect();
        assert!(names.is_empty(), "{names:?}");
    }
}

/// `--checkpoint` keeps the render's state beside -o; `--resume` goes on
/// from it to the new --spp, and refuses what it cannot go on from.
#[test]
fn resume_goes_on_from_the_state_beside_the_output() {
    let dir = scratch("resume-cli");
    let scene = dir.join("cornell-box.toml");
    let exr = dir.join("r.exr");
    let json = dir.join("r.json");
    let render = |extra: &[&str]| {
        let mut cmd = qtrace();
        cmd.arg("render")
            .arg(&scene)
            .args(["--width", "16", "--height", "16", "--nee"])
            .args(extra)
            .arg("-o")
            .arg(&exr)
            .arg("--stats")
            .arg(&json);
        cmd
    };
    expect_error(
        &dir,
        &scene,
        &["--resume"],
        &[],
        &["no render state to resume"],
    );
    let out = render(&["--spp", "4", "--checkpoint", "100"])
        .output()
        .unwrap();
    common::assert_success(&out);
    assert!(dir.join("r.exr.qtrace-state").exists());
    let out = render(&["--spp", "8", "--resume"]).output().unwrap();
    common::assert_success(&out);
    let stats = common::read_json(&json);
    assert_eq!(stats["spp"], 8);
    assert_eq!(stats["passes"].as_array().unwrap().len(), 8);
    assert_eq!(qtrace::image::Part::read(&exr).unwrap().provenance.spp, 8);
    let err = |extra: &[&str]| {
        let out = render(extra).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        stderr
    };
    assert!(err(&["--spp", "8", "--resume"]).contains("already holds 8"));
    assert!(err(&["--spp", "16", "--resume", "--method", "sarsa"]).contains("another render"));
}

/// A device allocation that fails, wherever it happens (scene, image,
/// guide, network, readback), ends the render with a one-line error and no
/// output file: each allocation in turn is made to fail.
#[test]
fn every_allocation_failure_is_an_error() {
    let dir = scratch("allocation-failures");
    for method in ["pt", "sarsa", "neural"] {
        let mut failed = 0;
        for n in 0..200 {
            let out = dir.join(format!("{method}-{n}.exr"));
            let output = qtrace()
                .arg("render")
                .arg(dir.join("cornell-box.toml"))
                .args([
                    "--method", method, "--spp", "2", "--width", "8", "--height", "8",
                ])
                .arg("-o")
                .arg(&out)
                .env("QTRACE_FAIL_ALLOCATION", n.to_string())
                .output()
                .unwrap();
            let stderr = String::from_utf8_lossy(&output.stderr);
            if output.status.success() {
                // Past the render's last allocation: nothing failed.
                assert!(out.exists());
                break;
            }
            failed += 1;
            assert_eq!(output.status.code(), Some(1), "{method} #{n}: {stderr}");
            assert!(!stderr.contains("panicked"), "{method} #{n}: {stderr}");
            assert_eq!(stderr.lines().count(), 1, "{method} #{n}: {stderr}");
            assert!(
                stderr.contains("allocation for buffer"),
                "{method} #{n}: {stderr}"
            );
            assert!(!out.exists(), "{method} #{n} left an output");
        }
        assert!(failed > 5, "{method}: only {failed} allocations");
    }
}

/// `--reads` or `QTRACE_READS` sets how the trace kernels read; the stats
/// JSON records it, and a value it does not know is a one-line error.
#[test]
fn reads_are_chosen_recorded_and_checked() {
    let dir = scratch("reads");
    let scene = dir.join("cornell-box.toml");
    let json = dir.join("a.json");
    for (args, env, want) in [
        (&["--reads", "storage"][..], "texel", "storage"),
        (&[][..], "texel", "texel"),
        (&[][..], "storage", "storage"),
    ] {
        let output = qtrace()
            .arg("render")
            .arg(&scene)
            .args(["--spp", "2", "--width", "16", "--height", "16"])
            .args(args)
            .env("QTRACE_READS", env)
            .arg("-o")
            .arg(dir.join("a.exr"))
            .arg("--stats")
            .arg(&json)
            .output()
            .unwrap();
        common::assert_success(&output);
        assert_eq!(common::read_json(&json)["reads"], want, "{args:?} {env}");
    }
    expect_error(
        &dir,
        &scene,
        &[],
        &[("QTRACE_READS", "gather")],
        &["gather"],
    );
}

/// Output into a pipe whose reader has gone (`qtrace devices | head -1`)
/// ends the process quietly, without a panic.
#[test]
fn a_closed_pipe_ends_quietly() {
    let mut child = qtrace()
        .arg("devices")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Closed before the device list (after Vulkan's start-up) is written.
    drop(child.stdout.take());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        matches!(output.status.code(), Some(0 | 141)),
        "{:?}: {stderr}",
        output.status
    );
}
