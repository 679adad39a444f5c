//! Renders split by seed and merged (`qtrace merge`): the merge is the
//! sample-weighted mean of its parts, equals statistically one render of all
//! the samples, refuses parts that do not belong together, and the Slurm
//! job-array script drives it (through a stand-in `sbatch`).

mod common;

use qtrace::image::{self, Image, Part, Provenance};
use qtrace::render::{Method, Overrides};
use qtrace::RenderOutput;
use std::path::{Path, PathBuf};
use std::process::Command;

fn qtrace() -> Command {
    let mut c = common::qtrace();
    c.current_dir(common::repo("."));
    c
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{cmd:?}: {stderr}");
    stderr
}

fn fail(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{cmd:?}: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    stderr
}

fn render_part(dir: &Path, scene: &str, seed: u32, spp: u32, extra: &[&str]) -> PathBuf {
    let out = dir.join(format!("{}-{seed}.exr", scene.replace('/', "-")));
    run(qtrace()
        .args(["render", scene, "--width", "16", "--height", "16"])
        .args(["--spp", &spp.to_string(), "--seed", &seed.to_string()])
        .args(extra)
        .arg("-o")
        .arg(&out));
    out
}

#[test]
fn merge_is_the_weighted_mean_of_its_parts_and_refuses_strangers() {
    let dir = common::scratch("merge-cli");
    let scene = "scenes/cornell-box.toml";
    let a = render_part(&dir, scene, 1, 4, &[]);
    let b = render_part(&dir, scene, 2, 12, &[]);
    let merged = dir.join("merged.exr");
    let json = dir.join("merged.json");
    run(qtrace()
        .arg("merge")
        .arg(&a)
        .arg(&b)
        .arg("-o")
        .arg(&merged)
        .arg("--stats")
        .arg(&json));
    let (pa, pb, m) = (
        Part::read(&a).unwrap(),
        Part::read(&b).unwrap(),
        Part::read(&merged).unwrap(),
    );
    assert_eq!(m.provenance.spp, 16);
    assert_eq!(m.provenance.seeds, vec![1, 2]);
    assert_eq!(m.provenance.method, "pt");
    assert!(
        m.provenance.scene.starts_with("cornell-box.toml "),
        "{:?}",
        m.provenance
    );
    for i in 0..m.image.pixels.len() {
        for c in 0..3 {
            let want = 0.25 * pa.image.pixels[i][c] + 0.75 * pb.image.pixels[i][c];
            assert!((m.image.pixels[i][c] - want).abs() <= 1e-6 * want.abs().max(1.0));
        }
    }
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(stats["spp"], 16);
    assert_eq!(stats["parts"].as_array().unwrap().len(), 2);

    // A merged image merges again, with a part of another seed.
    let c = render_part(&dir, scene, 3, 4, &[]);
    run(qtrace()
        .arg("merge")
        .arg(&merged)
        .arg(&c)
        .arg("-o")
        .arg(dir.join("again.exr")));
    assert_eq!(
        Part::read(&dir.join("again.exr")).unwrap().provenance.spp,
        20
    );

    let out = dir.join("bad.exr");
    let merge = |x: &Path, y: &Path| {
        let mut cmd = qtrace();
        cmd.arg("merge").arg(x).arg(y).arg("-o").arg(&out);
        cmd
    };
    assert!(fail(&mut merge(&a, &a)).contains("both hold seed 1"));
    assert!(fail(&mut merge(&merged, &a)).contains("seed 1"));
    let nee = render_part(&dir, scene, 4, 4, &["--nee"]);
    assert!(fail(&mut merge(&a, &nee)).contains("pt+nee"));
    let room = render_part(&dir, "scenes/indirect-room.toml", 5, 4, &[]);
    assert!(fail(&mut merge(&a, &room)).contains("indirect-room.toml"));
    let small = dir.join("small.exr");
    run(qtrace()
        .args([
            "render", scene, "--width", "8", "--height", "8", "--spp", "1", "--seed", "6", "-o",
        ])
        .arg(&small));
    assert!(fail(&mut merge(&a, &small)).contains("8x8"));
    let plain = dir.join("plain.exr");
    Image::new(16, 16).write_exr(&plain).unwrap();
    assert!(fail(&mut merge(&a, &plain)).contains("not a qtrace render"));
    assert!(!out.exists(), "a failed merge wrote its output");
}

/// Four renders with seeds 1-4 of 32 spp each, merged, against one render of
/// 128 spp with seed 9: per-pixel z-scores (binned 4 x 4) follow N(0, 1).
#[test]
fn merged_parts_equal_one_render_of_all_their_samples() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let render = |seed: u32, spp: u32| {
        common::render_with(
            &ctx,
            &scene,
            Overrides {
                method: Some(Method::PT),
                nee: true,
                spp: Some(spp),
                seed: Some(seed),
                width: Some(32),
                height: Some(32),
                ..Default::default()
            },
        )
    };
    let parts: Vec<Part> = (1..=4)
        .map(|seed| Part {
            path: PathBuf::from(format!("part-{seed}")),
            image: render(seed, 32).image,
            provenance: Provenance {
                spp: 32,
                method: "pt+nee".into(),
                scene: "cornell-box".into(),
                seeds: vec![seed],
            },
        })
        .collect();
    let (merged, provenance) = image::merge(&parts).unwrap();
    assert_eq!(provenance.spp, 128);
    let single = render(9, 128);
    // The merge's per-sample variance is the single render's: same estimator.
    let merged = RenderOutput {
        image: merged,
        variance: single.variance.clone(),
        stats: single.stats.clone(),
    };
    common::assert_same_expectation("merge", &merged, &single);
}

/// scripts/slurm_render.sh submits a job array (one seed per task) and a
/// merge after it; here `sbatch` is scripts/sbatch_local.sh, which runs the
/// same jobs on this machine. The merged image holds every task's samples.
#[test]
fn slurm_script_renders_a_job_array_and_merges_it() {
    let dir = common::scratch("slurm");
    let out = dir.join("cornell.exr");
    let status = Command::new("bash")
        .arg(common::repo("scripts/slurm_render.sh"))
        .args(["scenes/cornell-box.toml", "3", "4"])
        .arg(&out)
        .args(["--width", "16", "--height", "16", "--nee"])
        .env("QTRACE", env!("CARGO_BIN_EXE_qtrace"))
        .env("QTRACE_VALIDATION", "1")
        .env("SBATCH", common::repo("scripts/sbatch_local.sh"))
        .env("SBATCH_LOCAL_STATE", dir.join("state"))
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&status.stdout);
    assert!(
        status.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&status.stderr)
    );
    assert!(stdout.contains("3 tasks"), "{stdout}");
    let merged = Part::read(&out).unwrap_or_else(|e| {
        let log = std::fs::read_to_string(dir.join("cornell.parts/merge.log")).unwrap_or_default();
        panic!("{e}: {log}")
    });
    assert_eq!(merged.provenance.spp, 12);
    assert_eq!(merged.provenance.seeds, vec![1, 2, 3]);
    assert_eq!(merged.provenance.method, "pt+nee");
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("cornell.json")).unwrap()).unwrap();
    assert_eq!(stats["parts"].as_array().unwrap().len(), 3);
}

/// The same script on a real Slurm, when one answers on this machine (CI
/// starts a single node with scripts/slurm_single_node.sh and sets
/// QTRACE_SLURM=1, which makes its absence a failure here).
#[test]
fn slurm_script_runs_on_a_real_single_node_slurm() {
    let up = Command::new("sinfo")
        .args(["-h", "-o", "%T"])
        .output()
        .is_ok_and(|o| {
            let s = String::from_utf8_lossy(&o.stdout);
            o.status.success() && ["idle", "mix", "alloc"].iter().any(|t| s.contains(t))
        });
    if !up {
        assert_ne!(
            std::env::var("QTRACE_SLURM").as_deref(),
            Ok("1"),
            "QTRACE_SLURM=1 but no Slurm node answers sinfo"
        );
        eprintln!("skipped: no Slurm node answers sinfo (scripts/slurm_single_node.sh starts one)");
        return;
    }
    let dir = common::scratch("slurm-real");
    let out = dir.join("room.exr");
    let submit = Command::new("bash")
        .arg(common::repo("scripts/slurm_render.sh"))
        .args(["scenes/indirect-room.toml", "2", "3"])
        .arg(&out)
        .args(["--width", "16", "--height", "16"])
        .env("QTRACE", env!("CARGO_BIN_EXE_qtrace"))
        .env("QTRACE_VALIDATION", "1")
        .env_remove("SBATCH")
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&submit.stdout);
    assert!(
        submit.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&submit.stderr)
    );
    let json = dir.join("room.json");
    let start = std::time::Instant::now();
    while !json.exists() {
        if start.elapsed().as_secs() > 300 {
            let log = std::fs::read_to_string(dir.join("room.parts/merge.log")).unwrap_or_default();
            panic!("the merge job wrote nothing in 300 s: {stdout} {log}");
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    // The merge renames its EXR into place before its stats.
    let merged = Part::read(&out).unwrap();
    assert_eq!(merged.provenance.spp, 6);
    assert_eq!(merged.provenance.seeds, vec![1, 2]);
}
