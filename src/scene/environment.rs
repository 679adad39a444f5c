//! Light from the sky: Mitsuba's `envmap` (a latitude-longitude image) and
//! `constant` (one radiance, held as a 1 x 2 image), as Mitsuba evaluates
//! them, with the distribution NEE samples them by. The CPU twin of
//! glsl/environment.glsl, and the packing of its buffer.

use crate::bsdf::luminance;
use crate::shaders;
use glam::{Mat3, Vec2, Vec3};
use std::f32::consts::PI;

/// A latitude-longitude map of radiance around the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    /// What errors and `inspect` call it.
    pub name: String,
    pub width: usize,
    /// At least 2: rows lie at v = j / (height - 1), from the map's +y
    /// pole to its -y pole.
    pub height: usize,
    /// Radiance (scale applied), in rows.
    pub texels: Vec<Vec3>,
    /// From world directions to the map's frame (its to_world undone).
    pub to_local: Mat3,
    /// NEE's cells: blocks of `block` (columns, rows) of the cells between
    /// texels (all of them up to MAX_SKY_CELLS wide and half as high).
    pub block: (usize, usize),
    pub grid: (usize, usize),
    /// Per cell: the probability NEE draws it over its solid angle (the
    /// density of its directions, where NEE picks the parts by power), and
    /// its part (0 the sky, 1 its brightest cells; see [`BRIGHT`]).
    pub density: Vec<f32>,
    pub part: Vec<u8>,
    /// Per part: its share of the power, and its alias table (threshold,
    /// alias slot, cell) over its cells; part 1 has none where the sky is
    /// not split.
    pub shares: [f32; 2],
    pub tables: [Vec<(f32, u32, u32)>; 2],
    /// ∫ luminance dω over the sphere (by cells): NEE's weight of the sky.
    pub power: f32,
    /// An analytic sky (Mitsuba's `sunsky`) that `eval` computes, as
    /// [`sky_model`] words; the texels then only shape NEE's cells.
    pub model: Option<Vec<[f32; 4]>>,
}

/// The most columns of NEE's cells; rows at most half as many.
const MAX_SKY_CELLS: usize = shaders::MAX_SKY_CELLS as usize;

/// A sky whose brightest cells, each at least `BRIGHT` times its mean
/// radiance, hold at least a twentieth of its power in at most a fiftieth
/// of the sphere (a sun, a studio's lamps) is two of NEE's lights: those
/// cells and the rest. Drawn by power, the two are the one distribution;
/// apart, the guides learn where the sun is hidden and draw the rest of the
/// sky there instead.
pub const BRIGHT: f64 = 32.0;

impl Environment {
    /// A map of `width` x `height` texels (rows from the top) seen through
    /// `to_world` (a rotation).
    pub fn new(
        name: String,
        width: usize,
        height: usize,
        texels: Vec<Vec3>,
        to_world: Mat3,
    ) -> Self {
        assert!(width >= 1 && height >= 2 && texels.len() == width * height);
        let block = (
            width.div_ceil(MAX_SKY_CELLS),
            (height - 1).div_ceil(MAX_SKY_CELLS / 2),
        );
        let grid = (width.div_ceil(block.0), (height - 1).div_ceil(block.1));
        let mut env = Self {
            name,
            width,
            height,
            texels,
            to_local: to_world.inverse(),
            block,
            grid,
            density: Vec::new(),
            part: Vec::new(),
            shares: [1.0, 0.0],
            tables: [Vec::new(), Vec::new()],
            power: 0.0,
            model: None,
        };
        env.build_sampling();
        env
    }

    /// The map as NEE's shape of an analytic sky that `words` describe
    /// ([`sky_model`]).
    pub fn with_model(mut self, words: Vec<[f32; 4]>) -> Self {
        self.model = Some(words);
        self
    }

    /// The map at about half its width and height: each new texel the mean
    /// of the old map (as `eval` reads it, between texels) over the new
    /// texel's span, a box of two columns by a tent of three rows; the pole
    /// rows stay the poles.
    pub fn halved(&self) -> Self {
        let (w, h) = (self.width, self.height);
        let (nw, nh) = (w.div_ceil(2), (h - 1).div_ceil(2) + 1);
        // The old map at data point (x, y): columns wrap, rows clamp.
        let at = |x: f32, y: f32| {
            let y = y.clamp(0.0, (h - 1) as f32);
            let (i, j) = (x.floor(), (y.floor() as usize).min(h - 2));
            let (fx, fy) = (x - i, y - j as f32);
            let col = |k: f32| (k as i64).rem_euclid(w as i64) as usize;
            let (i0, i1) = (col(i), col(i + 1.0));
            let row = |j: usize| self.texel(i0, j).lerp(self.texel(i1, j), fx);
            row(j).lerp(row(j + 1), fy)
        };
        let (sx, sy) = (w as f32 / nw as f32, (h - 1) as f32 / (nh - 1) as f32);
        let mut texels = Vec::with_capacity(nw * nh);
        for j in 0..nh {
            let y = j as f32 * sy;
            for i in 0..nw {
                let x = (i as f32 + 0.5) * sx - 0.5;
                let column = |y: f32| 0.5 * (at(x - 0.25 * sx, y) + at(x + 0.25 * sx, y));
                texels.push(
                    0.25 * column(y - 0.5 * sy) + 0.5 * column(y) + 0.25 * column(y + 0.5 * sy),
                );
            }
        }
        let mut halved = Self::new(self.name.clone(), nw, nh, texels, self.to_local.inverse());
        halved.model.clone_from(&self.model);
        halved
    }

    /// One radiance from every direction: Mitsuba's `constant`.
    pub fn constant(radiance: Vec3) -> Self {
        Self::new("constant".into(), 1, 2, vec![radiance; 2], Mat3::IDENTITY)
    }

    /// NEE's cells.
    pub fn cells(&self) -> usize {
        self.grid.0 * self.grid.1
    }

    fn texel(&self, x: usize, y: usize) -> Vec3 {
        self.texels[y * self.width + x % self.width]
    }

    /// Cell (i, j)'s columns and rows of the cells between texels, where
    /// the map is bilinear in its four corners.
    fn span(&self, i: usize, j: usize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        let (bx, by) = self.block;
        (
            i * bx..((i + 1) * bx).min(self.width),
            j * by..((j + 1) * by).min(self.height - 1),
        )
    }

    /// The solid angle of the columns `x` and rows `y` of the cells between
    /// texels (row j lies between θ = π j / (h − 1) and the next).
    fn solid_angle(&self, x: &std::ops::Range<usize>, y: &std::ops::Range<usize>) -> f32 {
        let h = (self.height - 1) as f32;
        let (c0, c1) = (
            (PI * y.start as f32 / h).cos(),
            (PI * y.end as f32 / h).cos(),
        );
        2.0 * PI * x.len() as f32 / self.width as f32 * (c0 - c1)
    }

    /// The solid angle NEE's cell `c` spans.
    fn cell_solid_angle(&self, c: usize) -> f32 {
        let (xs, ys) = self.span(c % self.grid.0, c / self.grid.0);
        self.solid_angle(&xs, &ys)
    }

    /// Each cell's weight: over the cells between texels it holds, their
    /// corners' mean luminance (the mean of a bilinear patch) times their
    /// solid angle; then Walker's alias table.
    fn build_sampling(&mut self) {
        let n = self.cells();
        let weights: Vec<f64> = (0..n)
            .map(|c| {
                let (xs, ys) = self.span(c % self.grid.0, c / self.grid.0);
                let mut w = 0.0f64;
                for j in ys.clone() {
                    let row = self.solid_angle(&(0..1), &(j..j + 1)) as f64;
                    for i in xs.clone() {
                        let corners = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
                        let mean: f32 = corners
                            .iter()
                            .map(|&(x, y)| luminance(self.texel(x, y)))
                            .sum::<f32>()
                            / 4.0;
                        w += mean.max(0.0) as f64 * row;
                    }
                }
                w
            })
            .collect();
        let total: f64 = weights.iter().sum();
        self.power = total as f32;
        // A black sky: uniform, so that the tables stay valid (NEE never
        // picks it: its power is 0).
        let p: Vec<f64> = if total > 0.0 {
            weights.iter().map(|x| x / total).collect()
        } else {
            vec![1.0 / n as f64; n]
        };
        let angles: Vec<f64> = (0..n).map(|c| self.cell_solid_angle(c) as f64).collect();
        self.density = (0..n).map(|c| (p[c] / angles[c]) as f32).collect();
        // The bright cells: a density of the sky's whole power (1) at least
        // BRIGHT times its mean, 1 / 4 pi.
        let bright = |c: usize| p[c] / angles[c] >= BRIGHT / (4.0 * std::f64::consts::PI);
        let (mut bright_share, mut bright_angle) = (0.0f64, 0.0f64);
        for c in (0..n).filter(|&c| bright(c)) {
            bright_share += p[c];
            bright_angle += angles[c];
        }
        // (The rest must keep some power: NEE divides by its share.)
        let split = total > 0.0
            && (0.05..1.0 - 1e-6).contains(&bright_share)
            && bright_angle <= 4.0 * std::f64::consts::PI / 50.0;
        self.part = (0..n).map(|c| u8::from(split && bright(c))).collect();
        self.shares = if split {
            [(1.0 - bright_share) as f32, bright_share as f32]
        } else {
            [1.0, 0.0]
        };
        self.tables = [0u8, 1].map(|k| {
            let cells: Vec<usize> = (0..n).filter(|&c| self.part[c] == k).collect();
            let table = alias_table(&cells.iter().map(|&c| p[c]).collect::<Vec<_>>());
            table
                .into_iter()
                .zip(&cells)
                .map(|((q, a), &c)| (q, a, c as u32))
                .collect()
        });
    }

    /// (u, v) of a direction in the map's frame (Mitsuba's convention).
    fn uv(&self, d: Vec3) -> Vec2 {
        let l = self.to_local * d;
        Vec2::new(
            l.x.atan2(-l.z) * (0.5 / PI),
            Vec2::new(l.x, l.z).length().atan2(l.y) / PI,
        )
    }

    /// Data coordinates of (u, v): columns from texel centres, wrapping;
    /// rows from the top row at v = 0 to the bottom one at v = 1.
    fn data(&self, uv: Vec2) -> Vec2 {
        let u = uv.x - 0.5 / self.width as f32;
        Vec2::new(
            (u - u.floor()) * self.width as f32,
            uv.y * (self.height - 1) as f32,
        )
    }

    /// The cell between texels a data point lies in.
    fn texel_cell(&self, p: Vec2) -> (usize, usize) {
        let i = (p.x.max(0.0) as usize).min(self.width - 1);
        let j = (p.y.max(0.0) as usize).min(self.height - 2);
        (i, j)
    }

    /// NEE's cell a data point lies in.
    fn cell(&self, p: Vec2) -> usize {
        let (i, j) = self.texel_cell(p);
        (j / self.block.1) * self.grid.0 + i / self.block.0
    }

    /// Radiance arriving from world direction `d` (unit).
    pub fn eval(&self, d: Vec3) -> Vec3 {
        if let Some(words) = &self.model {
            return sky_model(words, self.to_local * d);
        }
        let p = self.data(self.uv(d));
        let (i, j) = self.texel_cell(p);
        let f = p - Vec2::new(i as f32, j as f32);
        let top = self.texel(i, j).lerp(self.texel(i + 1, j), f.x);
        let bottom = self.texel(i, j + 1).lerp(self.texel(i + 1, j + 1), f.x);
        top.lerp(bottom, f.y)
    }

    /// The solid-angle density NEE draws `d` with, picking the parts by
    /// power.
    pub fn pdf(&self, d: Vec3) -> f32 {
        self.density[self.cell(self.data(self.uv(d)))]
    }

    /// The part `d` lies in.
    pub fn part_of(&self, d: Vec3) -> usize {
        self.part[self.cell(self.data(self.uv(d)))] as usize
    }

    /// Whether the sky is two of NEE's lights.
    pub fn parts(&self) -> usize {
        if self.tables[1].is_empty() {
            1
        } else {
            2
        }
    }

    /// A direction drawn by `u` (four uniform numbers: the part, by power,
    /// and its cell, the cell's alias, the point in it, uniform in azimuth
    /// and cos θ), with its density (`pdf`'s).
    pub fn sample(&self, u: [f32; 4]) -> (Vec3, f32) {
        let (part, x) = if u[0] < self.shares[0] || self.parts() == 1 {
            (0, u[0] / self.shares[0])
        } else {
            (1, (u[0] - self.shares[0]) / self.shares[1])
        };
        self.sample_part(part, [x.min(1.0 - 0.5 * f32::EPSILON), u[1], u[2], u[3]])
    }

    /// A direction of part `part` drawn by `u` (its cell, the cell's
    /// alias, the point in it), with the density `pdf` gives it (over the
    /// part's share, the density within the part).
    pub fn sample_part(&self, part: usize, u: [f32; 4]) -> (Vec3, f32) {
        let table = &self.tables[part];
        let n = table.len();
        let mut slot = ((u[0] * n as f32) as usize).min(n - 1);
        if u[1] >= table[slot].0 {
            slot = table[slot].1 as usize;
        }
        let c = table[slot].2 as usize;
        let (xs, ys) = self.span(c % self.grid.0, c / self.grid.0);
        let (w, h) = (self.width as f32, (self.height - 1) as f32);
        let x = xs.start as f32 + u[2] * xs.len() as f32;
        let phi = 2.0 * PI * ((x + 0.5) / w);
        let (c0, c1) = (
            (PI * ys.start as f32 / h).cos(),
            (PI * ys.end as f32 / h).cos(),
        );
        let cos_theta = c0 + (c1 - c0) * u[3];
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        let local = Vec3::new(phi.sin() * sin_theta, cos_theta, -phi.cos() * sin_theta);
        (self.to_local.transpose() * local, self.density[c])
    }

    /// The layout glsl/environment.glsl reads the buffer by (SKY_*).
    pub fn layout(&self, dense: bool) -> u32 {
        if self.model.is_some() {
            shaders::SKY_MODEL
        } else if dense {
            shaders::SKY_DENSE
        } else {
            shaders::SKY_TEXEL_WORDS
        }
    }

    /// Words (16 bytes each) of the buffer [`Environment::pack`] makes.
    pub fn words(&self, dense: bool) -> usize {
        let texel_words = if let Some(words) = &self.model {
            words.len()
        } else if dense {
            (3 * self.texels.len()).div_ceil(4) + 1
        } else {
            self.texels.len()
        };
        shaders::ENVIRONMENT_HEADER_WORDS as usize + texel_words + 2 * self.cells()
    }

    /// The environment buffer glsl/environment.glsl reads: a header (width,
    /// height, cells, first cell word; the three rows of to_local, with
    /// the cells' block width, block height and columns), the texels (RGB floats: a word each, or `dense`, one after another,
    /// four texels in three words and a word to spare, 25% less memory for
    /// two reads a texel), its parts (cells in each, share of the power of
    /// each), then per cell (density, part), then each part's alias table,
    /// a slot each (threshold, alias slot, cell, its density).
    pub fn pack(&self, dense: bool) -> Vec<[u32; 4]> {
        let first_cell = self.words(dense) - 2 * self.cells();
        let texel_words = first_cell - shaders::ENVIRONMENT_HEADER_WORDS as usize;
        let mut out = Vec::with_capacity(self.words(dense));
        out.push([
            self.width as u32,
            self.height as u32,
            self.cells() as u32,
            first_cell as u32,
        ]);
        let extra = [self.block.0 as u32, self.block.1 as u32, self.grid.0 as u32];
        for (r, e) in extra.into_iter().enumerate() {
            let m = self.to_local;
            out.push([
                m.x_axis[r].to_bits(),
                m.y_axis[r].to_bits(),
                m.z_axis[r].to_bits(),
                e,
            ]);
        }
        out.push([
            self.tables[0].len() as u32,
            self.tables[1].len() as u32,
            self.shares[0].to_bits(),
            self.shares[1].to_bits(),
        ]);
        let bits = |t: &Vec3| t.to_array().map(f32::to_bits);
        if let Some(words) = &self.model {
            out.extend(words.iter().map(|w| w.map(f32::to_bits)));
        } else if dense {
            let mut floats: Vec<u32> = self.texels.iter().flat_map(bits).collect();
            floats.resize(4 * texel_words, 0);
            out.extend(floats.chunks_exact(4).map(|w| [w[0], w[1], w[2], w[3]]));
        } else {
            out.extend(self.texels.iter().map(|t| {
                let [r, g, b] = bits(t);
                [r, g, b, 0]
            }));
        }
        out.extend(
            self.density
                .iter()
                .zip(&self.part)
                .map(|(&d, &k)| [d.to_bits(), k as u32, 0, 0]),
        );
        for table in &self.tables {
            out.extend(
                table
                    .iter()
                    .map(|&(q, a, c)| [q.to_bits(), a, c, self.density[c as usize].to_bits()]),
            );
        }
        out
    }
}

/// Walker's alias table (Vose's method) of weights `p` (any scale): per
/// slot, the threshold below which it keeps itself, and its alias.
fn alias_table(p: &[f64]) -> Vec<(f32, u32)> {
    let n = p.len();
    let total: f64 = p.iter().sum();
    let mut scaled: Vec<f64> = p.iter().map(|x| x * n as f64 / total).collect();
    let mut alias = vec![(1.0f32, 0u32); n];
    let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
    while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
        alias[s] = (scaled[s] as f32, l as u32);
        scaled[l] -= 1.0 - scaled[s];
        if scaled[l] < 1.0 {
            large.pop();
            small.push(l);
        }
    }
    for i in small.into_iter().chain(large) {
        alias[i] = (1.0, i as u32);
    }
    alias
}

/// Mitsuba's `sunsky` at unit direction `l` of the map's frame (y up), from
/// the words src/scene/mitsuba/sunsky.rs writes: (the sun's direction,
/// the sine of its disk's radius), (the sine of that radius, whether
/// the sun's limb darkens), three words per channel of the sky's nine
/// parameters and its radiance, the sun's radiance, then where the limb
/// darkens the sun per elevation segment 3 channels x 4 powers of the
/// elevation x 6 of the limb's cosine. The twin of glsl/environment.glsl's
/// sky_model, in the same single precision.
pub fn sky_model(words: &[[f32; 4]], l: Vec3) -> Vec3 {
    if l.y < 0.0 {
        return Vec3::ZERO;
    }
    let sun = Vec3::from_slice(&words[0]);
    let cos_gamma = l.dot(sun).clamp(-1.0, 1.0);
    let sin_gamma = l.cross(sun).length();
    let gamma = sin_gamma.atan2(l.dot(sun));
    let mut radiance = Vec3::ZERO;
    for c in 0..3 {
        let (a, b, e) = (words[2 + 3 * c], words[3 + 3 * c], words[4 + 3 * c]);
        let c1 = 1.0 + a[0] * (a[1] / (l.y + 0.01)).exp();
        let q = 1.0 + e[0] * e[0] - 2.0 * e[0] * cos_gamma;
        let chi = (1.0 + cos_gamma * cos_gamma) / (q * q.sqrt());
        let c2 = a[2]
            + a[3] * (b[0] * gamma).exp()
            + b[1] * cos_gamma * cos_gamma
            + b[2] * chi
            + b[3] * l.y.sqrt();
        radiance[c] = c1 * c2 * e[1];
    }
    if sin_gamma <= words[0][3] && cos_gamma > 0.0 {
        let [sin_half, limb, ..] = words[1];
        if limb == 0.0 {
            radiance += Vec3::from_slice(&words[11]);
        } else {
            let elevation = l.y.atan2(Vec2::new(l.x, l.z).length());
            let segment =
                (((2.0 * elevation / PI).max(0.0).powf(1.0 / 3.0) * 45.0) as usize).min(44);
            let x = elevation - 0.5 * PI * (segment as f32 / 45.0).powi(3);
            let ratio = sin_gamma / sin_half;
            let cos_psi = (1.0 - ratio * ratio).max(0.0).sqrt();
            let float = |i: usize| words[12 + (segment * 72 + i) / 4][(segment * 72 + i) % 4];
            for c in 0..3 {
                let mut x_k = 1.0;
                for k in 0..4 {
                    let mut psi_j = 1.0;
                    for j in 0..6 {
                        radiance[c] += x_k * psi_j * float((c * 4 + k) * 6 + j);
                        psi_j *= cos_psi;
                    }
                    x_k *= x;
                }
            }
        }
    }
    radiance
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 x 3 map of random radiance (the EXR Mitsuba read).
    #[allow(clippy::excessive_precision)] // as numpy printed them
    fn map(to_world: Mat3) -> Environment {
        #[rustfmt::skip]
        let t = [
            [0.271298348903656, 0.5736210346221924, 1.7025489807128906], [1.2643240690231323, 0.28825727105140686, 0.9662538766860962], [1.0581026077270508, 0.41947782039642334, 1.5691542625427246], [0.32734403014183044, 0.882456362247467, 1.1334803104400635],
            [0.9612560272216797, 1.2735971212387085, 1.5756756067276], [2.0125346183776855, 0.6684023141860962, 1.3970943689346313], [1.4924319982528687, 0.6854414939880371, 0.10298016667366028], [2.0469205379486084, 0.6968024373054504, 0.7279720306396484],
            [1.8834221363067627, 1.2703258991241455, 1.0426193475723267], [1.6465539932250977, 0.1606920212507248, 1.5139302015304565], [0.8484876751899719, 0.28170543909072876, 1.4210001230239868], [1.9629276990890503, 0.5143823623657227, 1.360180377960205],
        ];
        let texels = t.iter().map(|c| 1.5 * Vec3::from(*c)).collect();
        Environment::new("env34".into(), 4, 3, texels, to_world)
    }

    const DIRECTIONS: [[f32; 3]; 5] = [
        [0.3, 0.5, -0.8],
        [-0.6, -0.2, 0.7],
        [1.0, 0.0, 0.0],
        [0.001, -0.999, 0.002],
        [0.2, 0.1, 0.97],
    ];

    /// Mitsuba 3.9.1's `envmap` (scalar_rgb, scale 1.5) `eval` in these
    /// directions, without and with a to_world of rotate(y, 30)·rotate(x, 20).
    #[test]
    fn envmap_evaluates_as_mitsuba() {
        let plain = [
            [1.39395, 1.44311, 2.12057],
            [2.14819, 0.943517, 0.506234],
            [2.23034, 1.4565, 2.22958],
            [2.22553, 0.279259, 2.24157],
            [2.66899, 0.979611, 1.40248],
        ];
        let turned = [
            [1.26361, 1.70951, 2.38672],
            [2.40631, 1.00313, 0.487766],
            [2.60834, 1.0972, 2.0909],
            [2.04041, 0.484714, 1.96039],
            [2.23975, 0.898798, 1.07776],
        ];
        let rotation =
            Mat3::from_rotation_y(30f32.to_radians()) * Mat3::from_rotation_x(20f32.to_radians());
        for (env, want) in [(map(Mat3::IDENTITY), plain), (map(rotation), turned)] {
            for (d, w) in DIRECTIONS.iter().zip(want) {
                let got = env.eval(Vec3::from(*d).normalize());
                assert!(
                    (got - Vec3::from(w)).abs().max_element() < 2e-4,
                    "{d:?}: {got} vs Mitsuba's {w:?}"
                );
            }
        }
    }

    fn assert_densities_integrate_to_one(env: &Environment, tolerance: f32) {
        let total: f32 = (0..env.cells())
            .map(|c| env.density[c] * env.cell_solid_angle(c))
            .sum();
        assert!(
            (total - 1.0).abs() < tolerance,
            "densities integrate to {total}"
        );
    }

    /// The sampler's density integrates to 1, agrees with `pdf` at the
    /// directions it draws, and the draws follow it (χ² over cells).
    #[test]
    fn sampler_follows_its_density() {
        let env = map(Mat3::from_rotation_y(0.4));
        let n = 200_000;
        let mut counts = vec![0u32; env.cells()];
        let mut rng = crate::fuzz::Rng::new(9);
        let mut u = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        for _ in 0..n {
            let (d, pdf) = env.sample([u(), u(), u(), u()]);
            assert!((d.length() - 1.0).abs() < 1e-4);
            let back = env.pdf(d);
            assert!(
                (back - pdf).abs() <= 1e-3 * pdf,
                "pdf {pdf} drawn, {back} looked up at {d}"
            );
            counts[env.cell(env.data(env.uv(d)))] += 1;
        }
        assert_densities_integrate_to_one(&env, 1e-5);
        let cell_angle = |c: usize| env.cell_solid_angle(c);
        let chi2: f64 = counts
            .iter()
            .enumerate()
            .map(|(c, &k)| {
                let e = n as f64 * (env.density[c] * cell_angle(c)) as f64;
                (k as f64 - e).powi(2) / e
            })
            .sum();
        // 8 cells, 7 degrees of freedom: p = 0.001 at 24.3.
        assert!(chi2 < 24.3, "chi2 {chi2}");
    }

    /// A map wider than NEE's cells (blocks of three columns) with a
    /// bright sun: the densities integrate to 1 and agree with the draws,
    /// and the draws find the sun as often as its share says.
    #[test]
    fn a_wide_map_with_a_bright_sun_samples_by_blocks() {
        let (w, h) = (2050, 9);
        let mut texels = vec![Vec3::splat(0.5); w * h];
        texels[4 * w + 1000] = Vec3::splat(1.0e6);
        let env = Environment::new("wide".into(), w, h, texels, Mat3::IDENTITY);
        assert_eq!((env.block, env.grid), ((3, 1), (684, 8)));
        assert_densities_integrate_to_one(&env, 1e-4);
        let mut rng = crate::fuzz::Rng::new(5);
        let mut u = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        let (mut near_sun, n) = (0, 20_000);
        for _ in 0..n {
            let (d, pdf) = env.sample([u(), u(), u(), u()]);
            assert!((env.pdf(d) - pdf).abs() <= 1e-3 * pdf, "{d}");
            let (i, j) = env.texel_cell(env.data(env.uv(d)));
            near_sun += usize::from((999..=1001).contains(&i) && (3..5).contains(&j));
        }
        // The blocks of the sun's four cells hold nearly all the power.
        assert!(
            near_sun as f32 > 0.95 * n as f32,
            "{near_sun} of {n} near the sun"
        );
    }

    /// A sky with a sun is two of NEE's lights: the sun's cells and the
    /// rest, each drawn from its own table with the density `pdf` gives;
    /// a sky without one stays one.
    #[test]
    fn a_sun_is_a_part_of_its_own() {
        let (w, h) = (64, 33);
        let mut texels = vec![Vec3::new(0.4, 0.5, 0.7); w * h];
        texels[10 * w + 20] = Vec3::splat(2.0e4);
        let env = Environment::new("sun".into(), w, h, texels, Mat3::IDENTITY);
        assert_eq!(env.parts(), 2);
        assert!((env.shares[0] + env.shares[1] - 1.0).abs() < 1e-6);
        assert!(env.shares[1] > 0.9, "{:?}", env.shares);
        // The four cells around the sun's texel, and no others.
        assert_eq!(env.tables[1].len(), 4);
        let mut rng = crate::fuzz::Rng::new(9);
        let mut u = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        for part in 0..2 {
            for _ in 0..2_000 {
                let (d, pdf) = env.sample_part(part, [u(), u(), u(), u()]);
                assert_eq!(env.part_of(d), part, "{d}");
                assert!((env.pdf(d) - pdf).abs() <= 1e-3 * pdf, "{d}");
            }
        }
        assert_densities_integrate_to_one(&env, 1e-4);
        assert_eq!(map(Mat3::IDENTITY).parts(), 1);
        assert_eq!(Environment::constant(Vec3::ONE).parts(), 1);
    }

    #[test]
    fn a_halved_sky_keeps_its_power_and_its_sun() {
        // A sky of a smooth gradient and a small sun, as a map too large
        // for a device buffer would be halved: the power that reaches the
        // scene (about) the same, the sun where it was.
        let (w, h) = (256, 129);
        let mut texels: Vec<Vec3> = (0..w * h)
            .map(|i| Vec3::new(0.5, 0.6, 0.8) * (1.0 + (i / w) as f32 / h as f32))
            .collect();
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            texels[(40 + dy) * w + 100 + dx] = Vec3::splat(2000.0);
        }
        let env = Environment::new("sun".into(), w, h, texels, Mat3::from_rotation_y(0.3));
        let half = env.halved();
        assert_eq!((half.width, half.height), (128, 65));
        assert!(
            (half.power / env.power - 1.0).abs() < 0.02,
            "{} vs {}",
            half.power,
            env.power
        );
        let brightest = |e: &Environment| {
            let i = (0..e.texels.len())
                .max_by(|&a, &b| e.texels[a].x.total_cmp(&e.texels[b].x))
                .unwrap();
            let (x, y) = ((i % e.width) as f32 + 0.5, (i / e.width) as f32);
            (x / e.width as f32, y / (e.height - 1) as f32)
        };
        let ((u0, v0), (u1, v1)) = (brightest(&env), brightest(&half));
        assert!((u0 - u1).abs() < 1.0 / 128.0 && (v0 - v1).abs() < 1.0 / 64.0);
        assert_densities_integrate_to_one(&half, 1e-4);
    }

    #[test]
    fn a_constant_sky_is_uniform_over_the_sphere() {
        let env = Environment::constant(Vec3::new(0.5, 1.0, 2.0));
        for d in DIRECTIONS {
            let d = Vec3::from(d).normalize();
            assert!((env.eval(d) - Vec3::new(0.5, 1.0, 2.0)).abs().max_element() < 1e-6);
            assert!((env.pdf(d) - 0.25 / PI).abs() < 1e-6);
        }
        assert!((env.power - 4.0 * PI * luminance(Vec3::new(0.5, 1.0, 2.0))).abs() < 1e-4);
    }
}
