//! Render settings: the scene's defaults overridden by the command line, validated.

pub use crate::bsdf::Sampling;
use crate::guide::GuideSettings;
use crate::scene::Scene;
use serde::Serialize;

/// Path-tracing method: plain path tracing, or a guide's name (see
/// `guide::GUIDES`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Method(&'static str);

impl Method {
    /// Forward path tracing with BSDF sampling.
    pub const PT: Method = Method("pt");

    /// The method of a guide, by the name in its `GuideEntry`.
    pub(crate) const fn guided(name: &'static str) -> Method {
        Method(name)
    }

    /// The method of guide `name`, if there is one (or `pt`).
    pub fn named(name: &str) -> Option<Method> {
        if name == Self::PT.0 {
            return Some(Self::PT);
        }
        crate::guide::guide_named(name).map(|g| Method(g.name))
    }

    pub fn name(self) -> &'static str {
        self.0
    }

    /// The method's name, `+nee` added with NEE (`sarsa+nee`).
    pub fn label(self, nee: bool) -> String {
        label(self.name(), nee)
    }

    /// Whether the method learns a guide (its settings: the table of its name).
    pub fn is_guided(self) -> bool {
        self != Method::PT
    }
}

impl Serialize for Method {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.0)
    }
}

/// `--method`'s values: `pt`, then every guide.
impl clap::ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        static ALL: std::sync::LazyLock<Vec<Method>> = std::sync::LazyLock::new(|| {
            std::iter::once(Method::PT)
                .chain(crate::guide::GUIDES.iter().map(|g| Method(g.name)))
                .collect()
        });
        &ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let about = match crate::guide::guide_named(self.0) {
            Some(g) => g.about,
            None => "Forward path tracing with BSDF sampling",
        };
        Some(clap::builder::PossibleValue::new(self.0).help(about))
    }
}

/// What the user asked for; `None` means "the scene's default, else ours".
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    pub method: Option<Method>,
    pub spp: Option<u32>,
    pub time: Option<f64>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub max_depth: Option<u32>,
    pub nee: bool,
    pub seed: Option<u32>,
    pub sampling: Option<Sampling>,
    /// The guide's settings; None: the scene's table for the method, else
    /// the defaults. Given with no method, they choose it.
    pub guide: Option<GuideSettings>,
}

/// A method's name with `+nee` added when it uses NEE, as bench, merge and
/// render states name configurations.
pub fn label(method: &str, nee: bool) -> String {
    format!("{method}{}", if nee { "+nee" } else { "" })
}

/// When a render stops.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Budget {
    Samples(u32),
    Seconds(f64),
}

#[derive(Clone, Debug, Serialize)]
pub struct RenderSettings {
    pub method: Method,
    pub budget: Budget,
    pub width: u32,
    pub height: u32,
    pub max_depth: u32,
    pub nee: bool,
    pub seed: u32,
    pub sampling: Sampling,
    /// The guided methods' guide.
    pub guide: Option<GuideSettings>,
}

impl RenderSettings {
    /// Whether the method's guide learns in pass `index`.
    pub fn learns_in_pass(&self, index: u32) -> bool {
        self.guide.as_ref().is_some_and(|g| g.learns_in_pass(index))
    }

    /// The pass before which the image restarts, if the method's guide is
    /// trained by earlier passes only.
    pub fn reset_after(&self) -> Option<u32> {
        self.guide.as_ref().and_then(|g| g.common().reset_after)
    }
}

pub const MAX_RESOLUTION: u32 = 16384;
pub const MAX_SPP: u32 = 1 << 20;
pub const MAX_DEPTH: u32 = 1024;
// A path sample packs its surface hits and rays (at most two per hit, and
// the camera ray) into 16 and 15 bits (glsl/shared.h, PathSample).
const _: () = assert!(2 * (MAX_DEPTH + 1) + 1 < 1 << 15);
pub const MAX_SECONDS: f64 = 7.0 * 24.0 * 3600.0;

#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SettingsError(pub String);

impl RenderSettings {
    pub fn resolve(scene: &Scene, o: &Overrides) -> Result<Self, SettingsError> {
        let d = &scene.defaults;
        let width = o.width.or(d.width).unwrap_or(256);
        let height = o.height.or(d.height).unwrap_or(256);
        let max_depth = o.max_depth.or(d.max_depth).unwrap_or(64);
        let bad = |m: String| Err(SettingsError(m));
        if width == 0 || height == 0 {
            return bad(format!("image size {width}x{height} must be at least 1x1"));
        }
        if width > MAX_RESOLUTION || height > MAX_RESOLUTION {
            return bad(format!(
                "image size {width}x{height} exceeds the {MAX_RESOLUTION}x{MAX_RESOLUTION} limit"
            ));
        }
        if max_depth > MAX_DEPTH {
            return bad(format!(
                "max depth {max_depth} exceeds the limit of {MAX_DEPTH}"
            ));
        }
        let budget = match (o.spp, o.time) {
            (Some(_), Some(_)) => return bad("give either --spp or --time, not both".into()),
            (_, Some(t)) if !(t.is_finite() && t > 0.0 && t <= MAX_SECONDS) => {
                return bad(format!(
                    "time {t} s must be positive and at most {MAX_SECONDS} s"
                ))
            }
            (_, Some(t)) => Budget::Seconds(t),
            (spp, None) => {
                let spp = spp.or(d.spp).unwrap_or(64);
                if spp == 0 || spp > MAX_SPP {
                    return bad(format!("spp {spp} must lie in 1..={MAX_SPP}"));
                }
                Budget::Samples(spp)
            }
        };
        let given = o.guide.as_ref().map(|g| g.name());
        let method = match (o.method, given) {
            (Some(m), Some(g)) if m.name() != g => {
                return bad(format!(
                    "[{g}] settings were given for --method {}",
                    m.name()
                ))
            }
            (Some(m), _) => m,
            (None, Some(g)) => Method::named(g).unwrap_or(Method::PT),
            (None, None) => Method::PT,
        };
        // Both tables are checked, so a typo fails whatever the method.
        for (name, table) in &scene.guide_tables {
            GuideSettings::from_table(name, table)
                .map_err(|e| SettingsError(format!("{}: {e}", scene.path.display())))?;
        }
        let guide = match (&o.guide, method.is_guided()) {
            (_, false) => None,
            (Some(g), true) => Some(g.clone()),
            (None, true) => Some(
                GuideSettings::from_table(method.name(), scene.guide_table(method.name()))
                    .map_err(|e| SettingsError(format!("{}: {e}", scene.path.display())))?,
            ),
        };
        if let Some(g) = &guide {
            g.validate(scene).map_err(SettingsError)?;
            if let (Some(k), Budget::Samples(n)) = (g.common().reset_after, budget) {
                if k >= n {
                    return bad(format!(
                        "[{}] reset_after = {k} leaves none of the {n} passes in the image",
                        g.name()
                    ));
                }
            }
        }
        Ok(Self {
            method,
            budget,
            width,
            height,
            max_depth,
            nee: o.nee,
            seed: o.seed.unwrap_or(0),
            sampling: o.sampling.unwrap_or_default(),
            guide: guide.map(|g| g.for_image(width, height)),
        })
    }
}
