//! Fuzzes the scene loaders (TOML, OBJ, MTL; Mitsuba XML, PLY, serialized)
//! with mutants of the shipped scenes and the Mitsuba test scenes:
//! `cargo run --release --example fuzz_scenes -- [INPUTS] [SEED] [xml]`
//! (default 1,000,000 inputs, seed 1; `xml`: the Mitsuba scenes alone). Fails on any panic, on an input that
//! takes over 2 s, or on one that takes the process's peak memory over
//! 1 GiB; each such input is written to fuzz-findings/.

use qtrace::fuzz::{self, Outcome};
use std::time::{Duration, Instant};

/// Peak resident memory since the last reset, in bytes (Linux).
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

const PEAK_LIMIT: u64 = 1 << 30;

fn main() {
    let mut args = std::env::args().skip(1);
    let inputs: usize = args
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or(1_000_000);
    let seed: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    let xml_only = args.next().as_deref() == Some("xml");
    let mut corpus = if xml_only {
        Vec::new()
    } else {
        fuzz::shipped(std::path::Path::new("scenes")).expect("run from the repository root")
    };
    corpus.extend(fuzz::mitsuba(&fuzz::mitsuba_scenes()).expect("run from the repository root"));
    let start = Instant::now();
    reset_peak_rss();
    let mut peak_seen = 0u64;
    let report = fuzz::run(
        &corpus,
        seed,
        inputs,
        fuzz::MAX_TRIANGLES,
        Duration::from_secs(2),
        &mut |i, _outcome: &Outcome| {
            if i % 50_000 == 0 {
                eprintln!("{i} inputs, {:.0} s", start.elapsed().as_secs_f64());
            }
            let peak = peak_rss()?;
            peak_seen = peak_seen.max(peak);
            reset_peak_rss();
            (peak > PEAK_LIMIT).then(|| format!("peak memory {} MiB", peak >> 20))
        },
    );
    println!(
        "{} inputs in {:.0} s: {} loaded, {} refused with an error ({} of them not one line), {} findings; slowest {:.3} s; peak memory {} MiB",
        report.inputs,
        start.elapsed().as_secs_f64(),
        report.loaded,
        report.refused,
        report.multiline,
        report.findings.len(),
        report.slowest.as_secs_f64(),
        peak_seen >> 20
    );
    if let Some(e) = &report.multiline_example {
        println!("an error of more than one line: {e:?}");
    }
    if report.findings.is_empty() && report.multiline == 0 {
        return;
    }
    std::fs::create_dir_all("fuzz-findings").expect("fuzz-findings/");
    for f in &report.findings {
        let dir = format!("fuzz-findings/{}", f.input);
        std::fs::create_dir_all(&dir).expect("a findings folder");
        std::fs::write(format!("{dir}/{}", f.main_name), &f.main).expect("write");
        for (name, bytes) in &f.files {
            std::fs::write(format!("{dir}/{name}"), bytes).expect("write");
        }
        println!("input {}: {} (files in {dir})", f.input, f.what);
    }
    std::process::exit(1);
}
