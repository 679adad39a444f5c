//! A peer renderer timed on the same scene for the speed table: Mitsuba 3's
//! LLVM backend, run by `scripts/mitsuba_speed.py`. Benchmarks only; no test
//! needs Python or Mitsuba.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Exit status of the script when Mitsuba or its LLVM library is missing.
const EXIT_NOT_SET_UP: i32 = 3;

/// One peer measurement, beside the speed table's rows for the same scene.
#[derive(Clone, Debug, Serialize)]
pub struct PeerRow {
    pub scene: PathBuf,
    pub renderer: String,
    pub version: String,
    pub variant: String,
    pub spp: u32,
    pub width: u32,
    pub height: u32,
    /// Best batch, its JIT-compiling first batch left out.
    pub samples_per_second: f64,
    pub samples_per_second_median: f64,
    /// Our `pt+nee` samples/s over the peer's (both estimate the same image:
    /// path tracing with NEE and MIS, same path-length rule), if measured.
    pub pt_nee_ratio: Option<f64>,
}

#[derive(Deserialize)]
struct ScriptLine {
    version: String,
    variant: String,
    samples_per_second: f64,
    samples_per_second_median: f64,
}

/// Why the peer was not measured.
#[derive(Debug, thiserror::Error)]
pub enum PeerError {
    /// Mitsuba or its LLVM library is not installed: the line says how to set up.
    #[error("{0}")]
    NotSetUp(String),
    #[error("{0}")]
    Failed(String),
}

/// The interpreter (`QTRACE_PEER_PYTHON`, default `python3`) and the script
/// (`QTRACE_PEER_SCRIPT`; else the one in the source tree the binary was
/// built from, if it is still there; else `scripts/` of the current
/// directory, for a binary built elsewhere and run from a checkout).
fn command() -> (String, PathBuf) {
    let python = std::env::var("QTRACE_PEER_PYTHON").unwrap_or_else(|_| "python3".into());
    const SCRIPT: &str = "scripts/mitsuba_speed.py";
    let script = std::env::var_os("QTRACE_PEER_SCRIPT")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            let built = Path::new(env!("CARGO_MANIFEST_DIR")).join(SCRIPT);
            if built.is_file() {
                built
            } else {
                PathBuf::from(SCRIPT)
            }
        });
    (python, script)
}

/// Renders `scene` (with an XML scene's `defines`) with Mitsuba 3
/// `llvm_ad_rgb` at our settings.
pub fn mitsuba(
    scene: &Path,
    defines: &[(String, String)],
    width: u32,
    height: u32,
    spp: u32,
    max_depth: u32,
) -> Result<PeerRow, PeerError> {
    let (python, script) = command();
    if !script.is_file() {
        return Err(PeerError::NotSetUp(format!(
            "peer script {} not found (set QTRACE_PEER_SCRIPT)",
            script.display()
        )));
    }
    let output = Command::new(&python)
        .arg(&script)
        .arg(scene)
        .args([
            "--width",
            &width.to_string(),
            "--height",
            &height.to_string(),
        ])
        .args([
            "--spp",
            &spp.to_string(),
            "--max-depth",
            &max_depth.to_string(),
        ])
        .args(
            defines
                .iter()
                .flat_map(|(k, v)| ["-D".to_string(), format!("{k}={v}")]),
        )
        .output()
        .map_err(|e| {
            PeerError::NotSetUp(format!(
                "cannot run {python} ({e}); install Python 3.11+ or set QTRACE_PEER_PYTHON"
            ))
        })?;
    let stderr = String::from_utf8_lossy(&output.stderr);
    let last_line = |text: &str| text.lines().last().unwrap_or("").trim().to_string();
    match output.status.code() {
        Some(0) => {}
        Some(EXIT_NOT_SET_UP) => return Err(PeerError::NotSetUp(last_line(&stderr))),
        _ => {
            return Err(PeerError::Failed(format!(
                "{} failed ({}): {}",
                script.display(),
                output.status,
                last_line(&stderr)
            )))
        }
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line: ScriptLine = serde_json::from_str(&last_line(&stdout))
        .map_err(|e| PeerError::Failed(format!("{}: unreadable output ({e})", script.display())))?;
    Ok(PeerRow {
        scene: scene.to_path_buf(),
        renderer: "mitsuba".into(),
        version: line.version,
        variant: line.variant,
        spp,
        width,
        height,
        samples_per_second: line.samples_per_second,
        samples_per_second_median: line.samples_per_second_median,
        pt_nee_ratio: None,
    })
}
