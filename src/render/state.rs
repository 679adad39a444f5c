//! A render's state on disk, so that a render stopped (or finished) can go
//! on: what it has accumulated, how far its sample streams went (sample s
//! of a pixel always uses stream s, so the pass count is the position),
//! and its guide's state. One file: a line of magic, a JSON header, then
//! the header's blobs back to back.

use super::{RenderError, RenderSettings, Renderer, SettingsError, Tally};
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::Path;

const MAGIC: &[u8] = b"QTRACE-STATE 1\n";

/// What a state must match to resume a render: scene (name and content
/// fingerprint), size, method, seed, path length and sampling rules, and
/// every guide setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Identity {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub method: String,
    pub seed: u32,
    pub max_depth: u32,
    pub sampling: String,
    pub guide: serde_json::Value,
}

impl Identity {
    pub fn of(scene: &Scene, s: &RenderSettings) -> Self {
        Self {
            scene: scene.id(),
            width: s.width,
            height: s.height,
            method: s.method.label(s.nee),
            seed: s.seed,
            max_depth: s.max_depth,
            sampling: format!("{:?}", s.sampling).to_lowercase(),
            guide: s
                .guide
                .as_ref()
                .map_or(serde_json::Value::Null, |g| g.state_value()),
        }
    }

    /// The first way `other` differs from this, in words.
    fn difference(&self, other: &Self) -> Option<String> {
        let fields: [(&str, String, String); 8] = [
            ("scene", self.scene.clone(), other.scene.clone()),
            ("method", self.method.clone(), other.method.clone()),
            ("width", self.width.to_string(), other.width.to_string()),
            ("height", self.height.to_string(), other.height.to_string()),
            ("seed", self.seed.to_string(), other.seed.to_string()),
            (
                "max_depth",
                self.max_depth.to_string(),
                other.max_depth.to_string(),
            ),
            ("sampling", self.sampling.clone(), other.sampling.clone()),
            (
                "guide settings",
                self.guide.to_string(),
                other.guide.to_string(),
            ),
        ];
        fields
            .into_iter()
            .find(|(_, a, b)| a != b)
            .map(|(k, a, b)| format!("its {k} is {a}, this render's {b}"))
    }
}

#[derive(Serialize, Deserialize)]
struct Header {
    identity: Identity,
    tally: Tally,
    trace_dispatches: u32,
    /// Name and length of each blob that follows, in order.
    blobs: Vec<(String, u64)>,
}

fn read_error(path: &Path, message: impl std::fmt::Display) -> RenderError {
    SettingsError(format!("{}: cannot resume: {message}", path.display())).into()
}

impl Renderer {
    /// Writes the render's state to `path` (atomically).
    pub(crate) fn save_state(
        &self,
        path: &Path,
        tally: &Tally,
        seconds: f64,
    ) -> Result<(), RenderError> {
        let mut blobs: Vec<(String, Vec<u8>)> =
            vec![("accumulation".into(), self.accum.download::<u8>()?)];
        if let Some(g) = &self.guide {
            blobs.extend(g.save()?.into_iter().map(|(n, b)| (n.to_string(), b)));
        }
        let mut tally = tally.clone();
        tally.seconds_before += seconds;
        let header = Header {
            identity: self.identity.clone(),
            tally,
            trace_dispatches: self.trace_dispatches,
            blobs: blobs
                .iter()
                .map(|(n, b)| (n.clone(), b.len() as u64))
                .collect(),
        };
        let json = serde_json::to_vec(&header).map_err(|e| read_error(path, e))?;
        crate::image::write_atomically(path, |tmp| {
            use std::io::Write;
            let mut f =
                std::io::BufWriter::new(std::fs::File::create(tmp).map_err(|e| e.to_string())?);
            f.write_all(MAGIC)
                .and_then(|()| f.write_all(&json))
                .and_then(|()| f.write_all(b"\n"))
                .map_err(|e| e.to_string())?;
            for (_, b) in &blobs {
                f.write_all(b).map_err(|e| e.to_string())?;
            }
            f.flush().map_err(|e| e.to_string())
        })?;
        Ok(())
    }

    /// Loads the state at `path` into this renderer, which must be set up
    /// for the same render; the next run goes on from it. Returns the
    /// samples per pixel it holds.
    pub fn resume(&mut self, path: &Path) -> Result<u32, RenderError> {
        let bytes = std::fs::read(path).map_err(|e| read_error(path, e))?;
        let rest = bytes
            .strip_prefix(MAGIC)
            .ok_or_else(|| read_error(path, "not a qtrace render state"))?;
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| read_error(path, "its header is cut short"))?;
        let header: Header =
            serde_json::from_slice(&rest[..end]).map_err(|e| read_error(path, e))?;
        if let Some(d) = header.identity.difference(&self.identity) {
            return Err(read_error(
                path,
                format!("it is the state of another render: {d}"),
            ));
        }
        let mut data = &rest[end + 1..];
        let mut blobs = Vec::new();
        for (name, len) in &header.blobs {
            let len = usize::try_from(*len).unwrap_or(usize::MAX);
            if data.len() < len {
                return Err(read_error(path, "it is cut short"));
            }
            let (blob, tail) = data.split_at(len);
            blobs.push((name.clone(), blob.to_vec()));
            data = tail;
        }
        let accum = blobs
            .iter()
            .find(|(n, _)| n == "accumulation")
            .filter(|(_, b)| b.len() as u64 == self.accum.size())
            .ok_or_else(|| read_error(path, "its accumulation does not fit this image"))?;
        self.accum.overwrite(&accum.1)?;
        if let Some(g) = &mut self.guide {
            g.restore(&self.ctx, &blobs, self.settings.nee)
                .map_err(|e| read_error(path, e))?;
        }
        self.trace_dispatches = header.trace_dispatches;
        let done = header.tally.done;
        self.resumed = Some(header.tally);
        Ok(done)
    }
}
