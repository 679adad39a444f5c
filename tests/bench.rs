//! `qtrace bench --quick` writes the whole report: images, pictures of what
//! was learned, charts, CSV/JSON with the right columns and sane values, HTML.

mod common;

use std::path::Path;

fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(String::from)
        .collect::<Vec<_>>();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column '{name}' in {header:?}"))
}

fn number(row: &[String], i: usize) -> f64 {
    row[i]
        .parse::<f64>()
        .unwrap_or_else(|_| panic!("'{}' is not a number in {row:?}", row[i]))
}

#[test]
fn quick_bench_writes_the_report() {
    let dir = common::scratch("bench-report");
    let out = dir.join("report");
    let cache = dir.join("cache");
    let run = || {
        common::qtrace()
            .args([
                "bench",
                "scenes/cornell-box.toml",
                "--quick",
                "--methods",
                "pt,sarsa,neural",
                "--out",
            ])
            .arg(&out)
            .env("QTRACE_CACHE", &cache)
            .current_dir(common::repo("."))
            .output()
            .unwrap()
    };
    let output = run();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "bench failed: {stderr}");
    // At --quick sizes a guide is still learning at `pt`'s time for 32 spp
    // (it costs more per pass than `pt`), and the bench says so.
    let stdout = String::from_utf8_lossy(&output.stdout);
    for guide in ["sarsa", "neural"] {
        assert!(
            stdout.contains(&format!("{guide} had rendered about"))
                && stdout.contains("measures its guide's start-up"),
            "{stdout}"
        );
    }

    for f in [
        "index.html",
        "results.json",
        "summary.csv",
        "checkpoints.csv",
        "passes.csv",
        "equal_time.csv",
        "gpu_passes.csv",
        "cornell-box/reference.exr",
        "cornell-box/error-vs-spp.png",
        "cornell-box/error-vs-time.png",
        "cornell-box/zero-vs-pass.png",
        "cornell-box/length-vs-pass.png",
        "cornell-box/loss-vs-pass.png",
        "cornell-box/pt/spp-0001.exr",
        "cornell-box/pt/spp-0032.png",
        "cornell-box/sarsa/spp-0016.png",
        "cornell-box/sarsa/voronoi.png",
        "cornell-box/sarsa/hemispheres.png",
        "cornell-box/neural/spp-0032.png",
        "cornell-box/neural/hemispheres.png",
        "cornell-box/neural/voronoi.png",
    ] {
        let p = out.join(f);
        assert!(
            p.is_file() && std::fs::metadata(&p).unwrap().len() > 0,
            "missing {}",
            p.display()
        );
    }

    // Checkpoints: 1, 2, 4, 8, 16, 32 spp for each method, errors finite and falling.
    let (h, rows) = csv(&out.join("checkpoints.csv"));
    let (spp, rel, zero, secs) = (
        column(&h, "spp"),
        column(&h, "rel_mse"),
        column(&h, "zero_contribution_fraction"),
        column(&h, "seconds"),
    );
    for name in ["mse", "mape", "scene", "config"] {
        column(&h, name);
    }
    assert_eq!(rows.len(), 18, "{rows:?}");
    for r in &rows {
        assert!(number(r, rel).is_finite() && number(r, rel) >= 0.0);
        assert!((0.0..=1.0).contains(&number(r, zero)));
        assert!(number(r, secs) > 0.0);
    }
    for method in ["pt", "sarsa", "neural"] {
        let mine: Vec<&Vec<String>> = rows.iter().filter(|r| r[1] == method).collect();
        let (first, last) = (mine.first().unwrap(), mine.last().unwrap());
        assert_eq!((number(first, spp), number(last, spp)), (1.0, 32.0));
        assert!(
            number(last, rel) < number(first, rel),
            "{method}: error did not fall with samples"
        );
    }

    // Per pass: 32 passes per method, loss only for the learned ones.
    let (h, rows) = csv(&out.join("passes.csv"));
    let (cfg, loss, len) = (
        column(&h, "config"),
        column(&h, "loss"),
        column(&h, "mean_path_length"),
    );
    assert_eq!(rows.len(), 96);
    for r in &rows {
        assert!(number(r, len) >= 1.0);
        assert_eq!(r[cfg] != "pt", !r[loss].is_empty(), "{r:?}");
    }

    let (h, rows) = csv(&out.join("summary.csv"));
    for name in [
        "samples_per_second",
        "rays_per_second",
        "zero_contribution_fraction",
        "equal_time_rel_mse",
        "guide_bytes",
    ] {
        let i = column(&h, name);
        assert!(rows.iter().all(|r| number(r, i) >= 0.0));
    }
    // Each guide against `pt` at `pt`'s time; none for `pt` itself.
    let (cfg, over) = (column(&h, "config"), column(&h, "over_plain"));
    for r in &rows {
        assert_eq!(r[cfg] == "pt", r[over].is_empty(), "{r:?}");
        assert!(r[over].is_empty() || number(r, over) > 0.0, "{r:?}");
    }
    assert!(stdout.contains("vs plain"), "{stdout}");
    let json = common::read_json(out.join("results.json"));
    let summary = &json["scenes"][0]["summary"];
    for key in [
        "fewest_zero_contribution",
        "lowest_error_equal_spp",
        "lowest_error_equal_time",
    ] {
        let v = summary[key].as_str().unwrap();
        assert!(["pt", "sarsa", "neural"].contains(&v), "{key}: {v}");
    }
    // The reference's own error, from its variance: refined until it is under
    // a tenth of the smallest error measured against it, or 8x its samples
    // (more while a doubling is quick).
    let scene = &json["scenes"][0];
    let floor = scene["reference_rel_mse"].as_f64().unwrap();
    let smallest = scene["smallest_rel_mse"].as_f64().unwrap();
    let spp = scene["reference_spp"].as_u64().unwrap();
    assert!(floor > 0.0, "{floor}");
    assert!(
        floor <= 0.1 * smallest || spp >= 8 * 256,
        "reference at {spp} spp: {floor} against {smallest}"
    );
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    for needle in [
        "Its own relMSE",
        "Summary",
        "cornell-box/sarsa/voronoi.png",
        "cornell-box/neural/hemispheres.png",
        "cornell-box/error-vs-time.png",
        "relMSE at equal time",
    ] {
        assert!(html.contains(needle), "index.html lacks {needle}");
    }

    // A second run reuses the cached reference (and its error) rather than
    // rendering it again.
    let cached: Vec<_> = std::fs::read_dir(&cache).unwrap().collect();
    assert_eq!(cached.len(), 2);
    let again = run();
    assert!(again.status.success());
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 2);
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(
        stdout.contains("the reference's own relMSE is about"),
        "{stdout}"
    );
}

/// `--seconds`: each method renders for that long, its last image is one
/// more checkpoint, and errors are compared there.
#[test]
fn a_bench_by_seconds_compares_at_that_time() {
    let dir = common::scratch("bench-seconds");
    let out = dir.join("report");
    let output = common::qtrace()
        .args([
            "bench",
            "scenes/cornell-box.toml",
            "--quick",
            "--seconds",
            "0.5",
        ])
        .args(["--methods", "pt,sarsa", "--out"])
        .arg(&out)
        .env("QTRACE_CACHE", dir.join("cache"))
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "bench failed: {stderr}");
    let results = common::read_json(out.join("results.json"));
    let scene = &results["scenes"][0];
    let equal = scene["equal_time_seconds"].as_f64().unwrap();
    assert!((0.5..0.75).contains(&equal), "equal time {equal}");
    for run in scene["runs"].as_array().unwrap() {
        let rows = run["checkpoints"].as_array().unwrap();
        let last = rows.last().unwrap();
        let (spp, seconds) = (
            last["spp"].as_u64().unwrap(),
            last["seconds"].as_f64().unwrap(),
        );
        // Past the last power of two: the render's own end.
        assert!(!spp.is_power_of_two() && seconds >= 0.5, "{run}");
        assert!(out.join(last["png"].as_str().unwrap()).exists(), "{last}");
        let at_time = run["error_at_equal_time"]["rel_mse"].as_f64().unwrap();
        assert!(
            at_time > 0.0 && !run["equal_time_extrapolated"].as_bool().unwrap(),
            "{run}"
        );
    }
    for bad in ["0", "-1", "nan"] {
        let output = common::qtrace()
            .args([
                "bench",
                "scenes/cornell-box.toml",
                "--quick",
                &format!("--seconds={bad}"),
            ])
            .arg("--out")
            .arg(dir.join("bad"))
            .current_dir(common::repo("."))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            !output.status.success() && stderr.contains("--seconds"),
            "{bad}: {stderr}"
        );
    }
}

#[test]
fn bench_rejects_a_reference_for_several_scenes() {
    let output = common::qtrace()
        .args([
            "bench",
            "scenes/cornell-box.toml",
            "scenes/furnace.toml",
            "--reference",
            "x.exr",
            "--out",
        ])
        .arg(common::scratch("bench-bad").join("out"))
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(stderr.contains("--reference"), "{stderr}");
}

#[test]
fn speed_table_reports_every_pass_and_cost() {
    let json = common::scratch("bench-speed").join("speed.json");
    let output = common::qtrace()
        .args([
            "bench",
            "--speed",
            "scenes/cornell-box.toml",
            "--methods",
            "pt,sarsa+nee",
            "--width",
            "32",
            "--height",
            "32",
            "--spp",
            "4",
            "--repeats",
            "1",
            "--peer",
            "none",
            "--json",
        ])
        .arg(&json)
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "bench --speed failed: {stdout}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        stdout.contains("cost/hit"),
        "no per-hit cost column: {stdout}"
    );
    let report = common::read_json(&json);
    assert_eq!(report["peers"].as_array().map(Vec::len), Some(0));
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    let field =
        |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
    for r in rows {
        for k in [
            "samples_per_second",
            "rays_per_second",
            "pass_ms",
            "mean_path_length",
        ] {
            assert!(field(r, k) > 0.0, "{k} = {} in {r}", field(r, k));
        }
        let names: Vec<&str> = r["pass_breakdown_ms"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p[0].as_str().unwrap())
            .collect();
        let want: &[&str] = if r["config"] == "pt" {
            &["trace", "accumulate"]
        } else {
            &["trace", "guide update", "accumulate"]
        };
        assert_eq!(names, want, "passes of {}", r["config"]);
    }
    assert_eq!(field(&rows[0], "pass_cost_ratio"), 1.0);
    let (pass, vertex) = (
        field(&rows[1], "pass_cost_ratio"),
        field(&rows[1], "vertex_cost_ratio"),
    );
    let lengths = field(&rows[1], "mean_path_length") / field(&rows[0], "mean_path_length");
    assert!(
        (pass - vertex * lengths).abs() < 1e-9 * pass,
        "per-hit cost {vertex} does not account for path lengths ({lengths}) in {pass}"
    );
}

/// `bench --speed` with a stand-in peer script (no Python, no Mitsuba): the
/// JSON line it prints becomes a peer row with the pt+nee ratio, and a
/// script that says it is not set up gives one line on how to set it up.
#[test]
fn speed_table_shows_the_peer_or_how_to_set_it_up() {
    let dir = common::scratch("bench-peer");
    let measured = dir.join("measured.sh");
    std::fs::write(
        &measured,
        "echo '{\"renderer\": \"mitsuba\", \"version\": \"9.9\", \"variant\": \"llvm_ad_rgb\", \
         \"samples_per_second\": 1000.0, \"samples_per_second_median\": 900.0}'\n",
    )
    .unwrap();
    let missing = dir.join("missing.sh");
    std::fs::write(
        &missing,
        "echo 'mitsuba_speed: install it like so' >&2\nexit 3\n",
    )
    .unwrap();
    let run = |script: &std::path::Path, json: &std::path::Path| {
        let output = common::qtrace()
            .args([
                "bench",
                "--speed",
                "scenes/cornell-box.toml",
                "--methods",
                "pt,pt+nee",
            ])
            .args([
                "--width",
                "16",
                "--height",
                "16",
                "--spp",
                "2",
                "--repeats",
                "1",
            ])
            .arg("--json")
            .arg(json)
            .env("QTRACE_PEER_PYTHON", "sh")
            .env("QTRACE_PEER_SCRIPT", script)
            .current_dir(common::repo("."))
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout).to_string();
        assert!(
            output.status.success(),
            "{stdout}{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let report = common::read_json(json);
        (stdout, report)
    };

    let (stdout, report) = run(&measured, &dir.join("measured.json"));
    assert!(stdout.contains("mitsuba 9.9 llvm_ad_rgb"), "{stdout}");
    let peer = &report["peers"][0];
    assert_eq!(peer["samples_per_second"].as_f64(), Some(1000.0));
    let ours = report["rows"][1]["samples_per_second"].as_f64().unwrap();
    let ratio = peer["pt_nee_ratio"].as_f64().unwrap();
    assert!((ratio - ours / 1000.0).abs() < 1e-9 * ratio, "{report}");

    let (stdout, report) = run(&missing, &dir.join("missing.json"));
    assert!(
        stdout.contains("mitsuba not measured: mitsuba_speed: install it like so"),
        "{stdout}"
    );
    assert_eq!(report["peers"].as_array().map(Vec::len), Some(0));
    assert!(report["peer_missing"].as_str().unwrap().contains("install"));
}

/// Guide settings reach the bench too, checked before any GPU work.
#[test]
fn bench_checks_guide_settings_first() {
    for args in [
        &["--quick", "--methods", "sarsa", "--set", "sarsa.epsilonx=2"][..],
        &["--speed", "--methods", "neural", "--set", "neural.width=6"][..],
        &[
            "--quick",
            "--methods",
            "pt,pt+nee",
            "--set",
            "sarsa.epsilon=0.3",
        ][..],
    ] {
        let output = common::qtrace()
            .args(["bench", "scenes/cornell-box.toml", "--out"])
            .arg(common::scratch("bench-guide").join("out"))
            .args(args)
            .current_dir(common::repo("."))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{args:?}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(
            stderr.contains("[sarsa] unknown field `epsilonx`")
                || stderr.contains("[neural] width = 6")
                || stderr.contains("sets the sarsa guide, but the method is pt, pt"),
            "{stderr}"
        );
    }
}

/// A font the charts cannot use fails the bench at once, in one line,
/// before it renders anything (no reference in its cache).
#[test]
fn bench_checks_its_font_first() {
    let dir = common::scratch("bench-font");
    let output = common::qtrace()
        .args(["bench", "scenes/cornell-box.toml", "--quick", "--out"])
        .arg(dir.join("out"))
        .env("QTRACE_CACHE", dir.join("cache"))
        .env("QTRACE_FONT", dir.join("no-such-font.ttf"))
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("QTRACE_FONT=") && stderr.contains("not a TrueType font"),
        "{stderr}"
    );
    assert!(!dir.join("cache").exists(), "it rendered before checking");
}

/// With several lights the report pictures which light NEE picks where
/// (for both guides: Neural-Q's tables learn it too), with a legend naming
/// each light's colour; without, it has no such picture.
#[test]
fn quick_bench_pictures_the_learned_choice_of_light() {
    let dir = common::scratch("bench-lights");
    let out = dir.join("report");
    let output = common::qtrace()
        .args([
            "bench",
            "scenes/several-lights.toml",
            "scenes/cornell-box.toml",
            "--quick",
            "--methods",
            "sarsa+nee,neural+nee",
            "--out",
        ])
        .arg(&out)
        .env("QTRACE_CACHE", dir.join("cache"))
        .current_dir(common::repo("."))
        .output()
        .unwrap();
    common::assert_success(&output);
    for method in ["sarsa+nee", "neural+nee"] {
        let picture = out.join(format!("several-lights/{method}/light-choice.png"));
        assert!(
            picture.is_file() && std::fs::metadata(&picture).unwrap().len() > 0,
            "missing {}",
            picture.display()
        );
    }
    assert!(!out.join("cornell-box/sarsa+nee/light-choice.png").exists());
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        html.contains("red: light_warm, green: light_blue, blue: light_ceiling"),
        "no legend in the report"
    );
}
