//! Mitsuba's `sunsky`: the Hošek–Wilkie sky and sun, as Mitsuba 3's RGB
//! variants evaluate them (from the tables Mitsuba ships, in
//! data/sunsky/). The renderer evaluates the model where a ray leaves the
//! scene (its words, [`Sunsky::words`], read by glsl/environment.glsl);
//! NEE draws its directions from a latitude-longitude map baked from the
//! model ([`Sunsky::bake`]), each texel its tent-weighted mean of the
//! radiance, so that the map's cells weigh the sun and the sky by their
//! power. Looking the sky up in the map instead would smooth it by a few
//! parts in 10⁴ and widen the sun's edge to two texels.

use super::cie;
use super::xml::{CIE_Y_NORMALIZATION, XYZ_TO_SRGB};
use glam::{DVec3, Mat3, Vec3};
use std::f64::consts::PI;

/// The tables, little-endian f32, written by scripts/sunsky_tables.py.
const TABLES: &[u8] = include_bytes!("../../../data/sunsky/hosek_wilkie_rgb.bin");
/// Where each table begins, in floats: the sky's 9 parameters and its
/// radiance (turbidity 10, albedo 2, control point 6, channel 3), the
/// sun's spectral irradiance (turbidity 10, elevation 30, 11 wavelengths
/// 320-720 nm), the limb-darkened sun (turbidity 10, segment 45, channel
/// 3, power 4, limb 6).
const SKY_PARAMS: usize = 0;
const SKY_RADIANCE: usize = SKY_PARAMS + 10 * 2 * 6 * 3 * 9;
const SUN_IRRADIANCE: usize = SKY_RADIANCE + 10 * 2 * 6 * 3;
const SUN_RADIANCE: usize = SUN_IRRADIANCE + 10 * 30 * 11;
const TABLE_FLOATS: usize = SUN_RADIANCE + 10 * 45 * 3 * 4 * 6;
const _: () = assert!(TABLES.len() == 4 * TABLE_FLOATS);

fn table(i: usize) -> f64 {
    f32::from_le_bytes(TABLES[4 * i..4 * i + 4].try_into().unwrap()) as f64
}

/// The sun's half aperture the model's irradiance is for (degrees 0.5358).
const SUN_HALF_APERTURE: f64 = PI * (0.5 * 0.5358) / 180.0;
/// Mitsuba's scale from the sun's spectral radiance to RGB.
const SUN_RADIANCE_TO_RGB: f64 = 467.069_280_386;
/// Columns of the baked map (rows: half as many, plus one).
pub const BAKED_WIDTH: usize = 1024;

/// What a `sunsky` element says.
#[derive(Clone, Debug)]
pub struct Settings {
    /// The sun's direction in the emitter's frame (z up), unit.
    pub sun: DVec3,
    pub turbidity: f64,
    pub albedo: [f64; 3],
    pub sun_scale: f64,
    pub sky_scale: f64,
    /// Degrees across.
    pub sun_aperture: f32,
    /// Limb darkening: the sun's radiance falls toward its edge.
    pub complex_sun: bool,
}

/// A place and a moment (local time), for the sun's position.
#[derive(Clone, Debug)]
pub struct When {
    pub latitude: f64,
    pub longitude: f64,
    pub timezone: f32,
    pub year: i64,
    pub month: i64,
    pub day: i64,
    pub hour: f32,
    pub minute: f32,
    pub second: f32,
}

impl Default for When {
    /// Mitsuba's defaults: Tokyo, 10 July 2010, 15:00.
    fn default() -> Self {
        Self {
            latitude: 35.6894,
            longitude: 139.6917,
            timezone: 9.0,
            year: 2010,
            month: 7,
            day: 10,
            hour: 15.0,
            minute: 0.0,
            second: 0.0,
        }
    }
}

impl When {
    /// The sun's direction (z up, x toward azimuth 0 as Mitsuba places it),
    /// by Blanco-Muriel et al., "Computing the solar vector" (2001), with
    /// the Julian date in single precision as Mitsuba computes it (which
    /// moves the sun by up to a quarter of a degree).
    pub fn sun(&self) -> DVec3 {
        let dec_hours = self.hour - self.timezone + (self.minute + self.second / 60.0) / 60.0;
        // Integer division truncates, as in C.
        let (y, m, d) = (self.year, self.month, self.day);
        let a1 = (m - 14) / 12;
        let a2 = (1461 * (y + 4800 + a1)) / 4 + (367 * (m - 2 - 12 * a1)) / 12
            - (3 * ((y + 4900 + a1) / 100)) / 4
            + d
            - 32075;
        let julian = (a2 as f32 - 0.5) + dec_hours / 24.0;
        let n = (julian - 2_451_545.0) as f64;
        let dec_hours = dec_hours as f64;

        let omega = 2.1429 - 0.001_039_459_4 * n;
        let mean_longitude = 4.895_063 + 0.017_202_791_698 * n;
        let anomaly = 6.240_06 + 0.017_201_969_9 * n;
        let ecliptic_longitude =
            mean_longitude + 0.033_416_07 * anomaly.sin() + 0.000_348_94 * (2.0 * anomaly).sin()
                - 0.000_113_4
                - 0.000_020_3 * omega.sin();
        let obliquity = 0.409_092_8 - 6.214e-9 * n + 0.000_039_6 * omega.cos();

        let s = ecliptic_longitude.sin();
        let mut right_ascension = (obliquity.cos() * s).atan2(ecliptic_longitude.cos());
        if right_ascension < 0.0 {
            right_ascension += 2.0 * PI;
        }
        let declination = (obliquity.sin() * s).asin();

        let sidereal = 6.697_424_324_2 + 0.065_709_828_3 * n + dec_hours;
        let local_sidereal = (sidereal * 15.0 + self.longitude).to_radians();
        let latitude = self.latitude.to_radians();
        let hour_angle = local_sidereal - right_ascension;
        let mut zenith = (latitude.cos() * hour_angle.cos() * declination.cos()
            + declination.sin() * latitude.sin())
        .clamp(-1.0, 1.0)
        .acos();
        let mut azimuth = (-hour_angle.sin())
            .atan2(declination.tan() * latitude.cos() - latitude.sin() * hour_angle.cos());
        if azimuth < 0.0 {
            azimuth += 2.0 * PI;
        }
        // Parallax: the Earth's mean radius over the astronomical unit.
        zenith += 6371.01 / 149_597_890.0 * zenith.sin();
        let phi = azimuth - PI;
        DVec3::new(
            zenith.sin() * phi.cos(),
            zenith.sin() * phi.sin(),
            zenith.cos(),
        )
    }
}

/// The model for one sun position, turbidity and albedo.
pub struct Sunsky {
    sun: DVec3,
    sky_params: [[f64; 9]; 3],
    sky_radiance: [f64; 3],
    sun_radiance: SunRadiance,
    cos_half: f64,
    sin_half: f64,
    sun_scale: f64,
    sky_scale: f64,
}

enum SunRadiance {
    /// Irradiance over the disk's solid angle, the same everywhere on it.
    Uniform(DVec3),
    /// Per elevation segment, 3 channels x 4 powers of the elevation x 6 of
    /// the limb's cosine.
    Limb(Vec<[f64; 72]>),
}

/// `1 - cos(x)` as Mitsuba computes it, in single precision: for the sun's
/// small angle it is 0.2% off, and Mitsuba's sun is that much brighter.
fn one_minus_cos_f32(x: f32) -> f64 {
    (1.0 - ((x as f64).cos() as f32)) as f64
}

impl Sunsky {
    pub fn new(s: &Settings) -> Self {
        let eta = (0.5 * PI - s.sun.z.clamp(-1.0, 1.0).acos()).max(0.0);
        // Turbidity's levels 1-10 and its weight between two of them.
        let level = |t: f64, levels: usize| {
            let i = (t.floor().max(0.0) as usize).min(levels - 1);
            (i, (i + 1).min(levels - 1), t - i as f64)
        };
        let (t0, t1, tf) = level(s.turbidity - 1.0, 10);
        // The quintic Bézier over the sun's elevation the model fits.
        let x = (2.0 / PI * eta).cbrt().min(1.0 - f32::EPSILON as f64 / 2.0);
        let weights: Vec<f64> = (0..6)
            .map(|k| {
                const BINOMIAL: [f64; 6] = [1.0, 5.0, 10.0, 10.0, 5.0, 1.0];
                BINOMIAL[k] * x.powi(k as i32) * (1.0 - x).powi(5 - k as i32)
            })
            .collect();
        // Table value at (turbidity, albedo, control point, channel, p),
        // turbidity and albedo interpolated.
        let sky = |base: usize, params: usize, c: usize, p: usize| -> f64 {
            let at = |t: usize, a: usize, k: usize| {
                table(base + (((t * 2 + a) * 6 + k) * 3 + c) * params + p)
            };
            let albedo = s.albedo[c];
            (0..6)
                .map(|k| {
                    let by_albedo = |t| at(t, 0, k) * (1.0 - albedo) + at(t, 1, k) * albedo;
                    weights[k] * (by_albedo(t0) * (1.0 - tf) + by_albedo(t1) * tf)
                })
                .sum()
        };
        let sky_params = [0, 1, 2].map(|c| std::array::from_fn(|p| sky(SKY_PARAMS, 9, c, p)));
        let sky_radiance = [0, 1, 2].map(|c| sky(SKY_RADIANCE, 1, c, 0));

        let half = (std::f32::consts::PI / 180.0) * (0.5 * s.sun_aperture);
        // Keeps the sun's irradiance whatever its aperture.
        let area_ratio = one_minus_cos_f32(SUN_HALF_APERTURE as f32) / one_minus_cos_f32(half);
        let sun_radiance = if s.complex_sun {
            let scale = area_ratio * SUN_RADIANCE_TO_RGB * CIE_Y_NORMALIZATION;
            SunRadiance::Limb(
                (0..45)
                    .map(|segment| {
                        std::array::from_fn(|i| {
                            let at = |t: usize| table(SUN_RADIANCE + (t * 45 + segment) * 72 + i);
                            scale * (at(t0) * (1.0 - tf) + at(t1) * tf)
                        })
                    })
                    .collect(),
            )
        } else {
            // The sun's irradiance by its elevation (steps of 3 degrees from
            // 2), as XYZ over the model's 11 wavelengths, then sRGB.
            let (e0, e1, ef) = level(((eta.to_degrees() - 2.0) / 3.0).clamp(0.0, 29.0), 30);
            let mut xyz = DVec3::ZERO;
            for w in 0..11 {
                let at = |t: usize, e: usize| table(SUN_IRRADIANCE + (t * 30 + e) * 11 + w);
                let by_turbidity = |e| at(t0, e) * (1.0 - tf) + at(t1, e) * tf;
                let irradiance = by_turbidity(e0) * (1.0 - ef) + by_turbidity(e1) * ef;
                let nm = 320 + 40 * w;
                if nm >= cie::FIRST_NM as usize {
                    let [x, y, z, _] = cie::TABLE[nm - cie::FIRST_NM as usize];
                    xyz += DVec3::new(x as f64, y as f64, z as f64) * irradiance;
                }
            }
            let rgb = XYZ_TO_SRGB * (xyz / 11.0);
            // Mitsuba divides by the solid angle of its reference aperture
            // and multiplies by the area ratio: together, by this one's.
            SunRadiance::Uniform(
                rgb / (2.0 * PI * one_minus_cos_f32(half))
                    * SUN_RADIANCE_TO_RGB
                    * CIE_Y_NORMALIZATION,
            )
        };
        Self {
            sun: s.sun,
            sky_params,
            sky_radiance,
            sun_radiance,
            // The disk's edge where Mitsuba tests it, in single precision:
            // its solid angle times the radiance is then the irradiance.
            cos_half: 1.0 - one_minus_cos_f32(half),
            sin_half: (half as f64).sin(),
            sun_scale: s.sun_scale,
            sky_scale: s.sky_scale,
        }
    }

    /// Whether the sun is above the horizon (Mitsuba's sky is black when not).
    pub fn is_day(&self) -> bool {
        self.sun.z >= 0.0
    }

    /// The sky's radiance from direction `d` (unit, z up), the sun left out.
    pub fn sky(&self, d: DVec3) -> DVec3 {
        if d.z < 0.0 || !self.is_day() || self.sky_scale == 0.0 {
            return DVec3::ZERO;
        }
        let cos_gamma = d.dot(self.sun).clamp(-1.0, 1.0);
        let gamma = cos_gamma.acos();
        let rgb: [f64; 3] = std::array::from_fn(|c| {
            let p = &self.sky_params[c];
            let c1 = 1.0 + p[0] * (p[1] / (d.z + 0.01)).exp();
            let chi = (1.0 + cos_gamma * cos_gamma)
                / (1.0 + p[8] * p[8] - 2.0 * p[8] * cos_gamma).powf(1.5);
            let c2 = p[2]
                + p[3] * (p[4] * gamma).exp()
                + p[5] * cos_gamma * cos_gamma
                + p[6] * chi
                + p[7] * d.z.max(0.0).sqrt();
            c1 * c2 * self.sky_radiance[c]
        });
        DVec3::from(rgb) * (self.sky_scale * CIE_Y_NORMALIZATION)
    }

    /// The sun's radiance from direction `d` (unit, z up): zero off its disk.
    pub fn sun(&self, d: DVec3) -> DVec3 {
        let cos_gamma = d.dot(self.sun);
        if d.z < 0.0 || !self.is_day() || cos_gamma < self.cos_half || self.sun_scale == 0.0 {
            return DVec3::ZERO;
        }
        let rgb = match &self.sun_radiance {
            SunRadiance::Uniform(rgb) => *rgb,
            SunRadiance::Limb(segments) => {
                let elevation = 0.5 * PI - d.z.clamp(-1.0, 1.0).acos();
                let segment =
                    (((2.0 * elevation / PI).cbrt() * 45.0).floor().max(0.0) as usize).min(44);
                let x = elevation - 0.5 * PI * (segment as f64 / 45.0).powi(3);
                let sin_gamma2 = 1.0 - cos_gamma * cos_gamma;
                let cos_psi = (1.0 - sin_gamma2 / (self.sin_half * self.sin_half))
                    .max(0.0)
                    .sqrt();
                let data = &segments[segment];
                DVec3::from(std::array::from_fn(|c| {
                    let mut sum = 0.0;
                    for k in 0..4 {
                        for j in 0..6 {
                            sum += x.powi(k as i32)
                                * cos_psi.powi(j as i32)
                                * data[(c * 4 + k) * 6 + j];
                        }
                    }
                    sum
                }))
            }
        };
        rgb * self.sun_scale
    }

    /// The words of glsl/environment.glsl's sky_model (its CPU twin,
    /// `environment::sky_model`, says what each holds), in the envmap's
    /// frame (y up).
    pub fn words(&self) -> Vec<[f32; 4]> {
        let sun = [self.sun.x, self.sun.z, -self.sun.y].map(|v| v as f32);
        let limb = matches!(self.sun_radiance, SunRadiance::Limb(_));
        let mut words = vec![
            // The disk's radius as a sine: near the sun a sine (from a
            // cross product) holds its digits where a cosine has lost
            // them (an ulp of a cosine there moves the disk's area 1%).
            [
                sun[0],
                sun[1],
                sun[2],
                (1.0 - self.cos_half * self.cos_half).sqrt() as f32,
            ],
            [self.sin_half as f32, if limb { 1.0 } else { 0.0 }, 0.0, 0.0],
        ];
        let sky = self.sky_scale * CIE_Y_NORMALIZATION;
        for c in 0..3 {
            let p = self.sky_params[c].map(|v| v as f32);
            words.push([p[0], p[1], p[2], p[3]]);
            words.push([p[4], p[5], p[6], p[7]]);
            words.push([p[8], (self.sky_radiance[c] * sky) as f32, 0.0, 0.0]);
        }
        match &self.sun_radiance {
            SunRadiance::Uniform(rgb) => {
                let rgb = (*rgb * self.sun_scale).as_vec3();
                words.push([rgb.x, rgb.y, rgb.z, 0.0]);
            }
            SunRadiance::Limb(segments) => {
                words.push([0.0; 4]);
                let floats: Vec<f32> = segments
                    .iter()
                    .flatten()
                    .map(|v| (v * self.sun_scale) as f32)
                    .collect();
                words.extend(floats.chunks_exact(4).map(|w| [w[0], w[1], w[2], w[3]]));
            }
        }
        words
    }

    /// The sky and the sun baked into a latitude-longitude map in Mitsuba's
    /// `envmap` convention (y up): its width, height and texels. Each texel
    /// is the mean of the radiance weighted by its bilinear tent over the
    /// sphere: the sky from 2 x 2 points in each cell between texels, the
    /// sun from 1,024 points on its disk.
    pub fn bake(&self, width: usize) -> (usize, usize, Vec<Vec3>) {
        let height = width / 2 + 1;
        let rows = (height - 1) as f64;
        // The envmap's frame (y up) in the sky's (z up).
        let direction = |x: f64, y: f64| {
            let phi = 2.0 * PI * (x + 0.5) / width as f64;
            let theta = PI * y / rows;
            let (e_x, e_y, e_z) = (
                phi.sin() * theta.sin(),
                theta.cos(),
                -phi.cos() * theta.sin(),
            );
            DVec3::new(e_x, -e_z, e_y)
        };
        let mut sum = vec![DVec3::ZERO; width * height];
        let mut weight = vec![0.0f64; width * height];
        // The four texels around data point (x, y) and their tent weights.
        let corners = |x: f64, y: f64| {
            let (i, j) = (x.floor(), (y.floor().max(0.0) as usize).min(height - 2));
            let (fx, fy) = (x - i, y - j as f64);
            let i0 = (i as i64).rem_euclid(width as i64) as usize;
            let i1 = (i0 + 1) % width;
            [
                (j * width + i0, (1.0 - fx) * (1.0 - fy)),
                (j * width + i1, fx * (1.0 - fy)),
                ((j + 1) * width + i0, (1.0 - fx) * fy),
                ((j + 1) * width + i1, fx * fy),
            ]
        };
        const SUB: usize = 2;
        for cj in 0..height - 1 {
            for b in 0..SUB {
                let y = cj as f64 + (b as f64 + 0.5) / SUB as f64;
                let sin_theta = (PI * y / rows).sin();
                for ci in 0..width {
                    for a in 0..SUB {
                        let x = ci as f64 + (a as f64 + 0.5) / SUB as f64;
                        let radiance = self.sky(direction(x, y));
                        for (t, w) in corners(x, y) {
                            sum[t] += radiance * (w * sin_theta);
                            weight[t] += w * sin_theta;
                        }
                    }
                }
            }
        }
        if self.is_day() && self.sun_scale > 0.0 {
            // Each point on the disk carries its share of the disk's solid
            // angle; a texel's weight above is its tent's solid angle over
            // that of one sub-cell.
            let sub_cell = 2.0 * PI / width as f64 * PI / rows / (SUB * SUB) as f64;
            let (n_rings, n_angles) = (32, 32);
            let solid_angle = 2.0 * PI * (1.0 - self.cos_half);
            let (t, b) = orthonormal(self.sun);
            for r in 0..n_rings {
                let cos_a = 1.0 - (r as f64 + 0.5) / n_rings as f64 * (1.0 - self.cos_half);
                let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
                for k in 0..n_angles {
                    let angle = 2.0 * PI * (k as f64 + 0.5) / n_angles as f64;
                    let d = self.sun * cos_a + (t * angle.cos() + b * angle.sin()) * sin_a;
                    let radiance = self.sun(d) * (solid_angle / (n_rings * n_angles) as f64);
                    if radiance == DVec3::ZERO {
                        continue;
                    }
                    // The data point of d: the inverse of `direction`.
                    let (e_x, e_y, e_z) = (d.x, d.z, -d.y);
                    let phi = e_x.atan2(-e_z).rem_euclid(2.0 * PI);
                    let theta = e_y.clamp(-1.0, 1.0).acos();
                    let x = phi / (2.0 * PI) * width as f64 - 0.5;
                    let y = theta / PI * rows;
                    for (t, w) in corners(x, y) {
                        sum[t] += radiance * (w / sub_cell);
                    }
                }
            }
        }
        let texels = sum
            .iter()
            .zip(&weight)
            .map(|(s, w)| {
                if *w > 0.0 {
                    (*s / *w).as_vec3()
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        (width, height, texels)
    }
}

/// Two unit vectors completing `n` to an orthonormal frame.
fn orthonormal(n: DVec3) -> (DVec3, DVec3) {
    let t = if n.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    let t = (t - n * n.dot(t)).normalize();
    (t, n.cross(t))
}

/// The envmap's frame (y up) in the sky's (z up), as a rotation: what the
/// baked map's to_world is composed with.
pub fn envmap_frame() -> Mat3 {
    Mat3::from_cols(Vec3::X, Vec3::Z, -Vec3::Y)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(sun: DVec3) -> Settings {
        Settings {
            sun: sun.normalize(),
            turbidity: 3.0,
            albedo: [0.3; 3],
            sun_scale: 1.0,
            sky_scale: 1.0,
            sun_aperture: 0.5358,
            complex_sun: false,
        }
    }

    fn close(a: DVec3, b: [f64; 3], tolerance: f64) {
        for c in 0..3 {
            let rel = (a[c] - b[c]).abs() / b[c].abs().max(1e-9);
            assert!(rel < tolerance, "{a} against Mitsuba's {b:?}");
        }
    }

    /// Radiance Mitsuba 3.9.1's `sunsky` (scalar_rgb) gives, through
    /// `emitter.eval` with `sun_direction` (0.3, 0.2, 0.8).
    #[test]
    fn the_model_gives_mitsubas_radiance() {
        let m = Sunsky::new(&settings(DVec3::new(0.3, 0.2, 0.8)));
        let sun = DVec3::new(0.3, 0.2, 0.8).normalize();
        close(
            m.sun(sun),
            [21987.14257812, 18490.32617188, 14381.53027344],
            1e-5,
        );
        // Sky only: Mitsuba's eval with sun_scale 0 there.
        let zenith = m.sky(DVec3::Z);
        close(zenith, [0.04735186, 0.06818668, 0.11931507], 1e-5);
        assert_eq!(m.sky(DVec3::new(1.0, 0.0, -0.1).normalize()), DVec3::ZERO);
    }

    /// The sun's limb-darkened radiance, from Mitsuba's eval with
    /// complex_sun, at its centre and 0.9 of its radius toward the zenith.
    #[test]
    fn the_limb_darkens_as_in_mitsuba() {
        let s = Settings {
            complex_sun: true,
            ..settings(DVec3::new(0.3, 0.2, 0.8))
        };
        let m = Sunsky::new(&s);
        let sun = s.sun;
        close(
            m.sun(sun),
            [26504.484375, 23129.56054688, 19032.484375],
            1e-5,
        );
        let half = (0.5 * 0.5358f64).to_radians();
        let t = sun.cross(DVec3::Z).normalize();
        let d = sun * (0.9 * half).cos() + t * (0.9 * half).sin();
        close(
            m.sun(d),
            [18845.98242188, 15271.56054688, 11152.921875],
            1e-4,
        );
    }

    /// The sun's direction for a place and time, as Mitsuba's
    /// `sun_direction` (read back through `mi.traverse`) gives it.
    #[test]
    fn the_sun_stands_where_mitsuba_puts_it() {
        let vienna = When {
            latitude: 48.2,
            longitude: 16.37,
            timezone: 1.0,
            year: 2024,
            month: 3,
            day: 21,
            hour: 9.5,
            ..When::default()
        };
        let sydney = When {
            latitude: -33.9,
            longitude: 151.2,
            timezone: 10.0,
            year: 2026,
            month: 12,
            day: 1,
            hour: 17.25,
            minute: 30.0,
            ..When::default()
        };
        for (when, want) in [
            (When::default(), [0.0513854, 0.691748, 0.720308]),
            (vienna, [0.58304, -0.61433, 0.531661]),
            (sydney, [0.310265, 0.928471, 0.204148]),
        ] {
            let got = when.sun();
            assert!(
                (got - DVec3::from(want)).length() < 1e-4,
                "{got} against Mitsuba's {want:?}"
            );
        }
    }

    /// The words the GPU reads give the model's radiance (single precision
    /// against double), on the sky and on the sun.
    #[test]
    fn the_words_evaluate_as_the_model() {
        for complex_sun in [false, true] {
            let s = Settings {
                complex_sun,
                turbidity: 6.5,
                albedo: [0.1, 0.5, 0.9],
                sky_scale: 1.5,
                sun_scale: 0.5,
                ..settings(DVec3::new(-0.5, 0.4, 0.3))
            };
            let m = Sunsky::new(&s);
            let words = m.words();
            // From the sky's frame (z up) to the envmap's (y up).
            let eval = |d: DVec3| {
                crate::scene::environment::sky_model(
                    &words,
                    Vec3::new(d.x as f32, d.z as f32, -d.y as f32),
                )
            };
            let mut rng = crate::fuzz::Rng::new(3);
            let mut u = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
            for i in 0..2000 {
                let d = if i % 2 == 0 {
                    let z = 2.0 * u() - 1.0;
                    let a = 2.0 * PI * u();
                    let r = (1.0 - z * z).sqrt();
                    DVec3::new(r * a.cos(), r * a.sin(), z)
                } else {
                    // On the sun, away from its edge.
                    let (t, b) = orthonormal(s.sun);
                    let (r, a) = (0.9 * u().sqrt() * m.sin_half, 2.0 * PI * u());
                    (s.sun + t * (r * a.cos()) + b * (r * a.sin())).normalize()
                };
                let want = m.sky(d) + m.sun(d);
                let got = eval(d).as_dvec3();
                assert!(
                    (got - want).abs().max_element() <= 2e-5 * want.max_element().max(1e-3),
                    "limb {complex_sun}, {d}: {got} against {want}"
                );
            }
        }
    }

    /// The baked map holds the sky's and the sun's power: its integral
    /// (bilinear, as the lookup reads it) against the model's, by a fine
    /// quadrature of the sky and the sun's irradiance.
    #[test]
    fn the_baked_map_keeps_the_power() {
        let s = Settings {
            sun_aperture: 1.2,
            ..settings(DVec3::new(0.2, -0.6, 0.35))
        };
        let m = Sunsky::new(&s);
        let (w, h, texels) = m.bake(256);
        let env = crate::scene::environment::Environment::new(
            "baked".into(),
            w,
            h,
            texels,
            Mat3::IDENTITY,
        );
        let baked = env.power as f64;
        // The model: the sky by 2,048 x 1,024 midpoints, the sun's disk by
        // its radiance times its solid angle.
        let lum = |c: DVec3| crate::bsdf::luminance(c.as_vec3()) as f64;
        let (nx, ny) = (2048, 1024);
        let mut sky = 0.0;
        for j in 0..ny {
            let theta = PI * (j as f64 + 0.5) / ny as f64;
            for i in 0..nx {
                let phi = 2.0 * PI * (i as f64 + 0.5) / nx as f64;
                let d = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                sky += lum(m.sky(d)) * theta.sin();
            }
        }
        sky *= 2.0 * PI / nx as f64 * PI / ny as f64;
        let sun = lum(m.sun(s.sun)) * 2.0 * PI * (1.0 - m.cos_half);
        let want = sky + sun;
        assert!(sun > sky, "a bright sun: {sun} against the sky's {sky}");
        assert!(
            (baked / want - 1.0).abs() < 2e-3,
            "baked {baked} against the model's {want} (sky {sky}, sun {sun})"
        );
    }
}
