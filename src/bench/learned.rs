//! Pictures of what a guide learned: the Voronoi regions of the radiance
//! volumes as the camera sees them, and Q hemispheres near the light (of
//! the Sarsa guide's volumes, or inferred by the Neural-Q network).

use crate::gpu::GpuContext;
use crate::guide::{NeuralGuide, SarsaGuide};
use crate::image::Image;
use crate::render::probe::{self, SurfacePoint};
use crate::render::RenderError;
use crate::sampling;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use std::sync::Arc;

/// A colour per volume index, stable across runs.
fn volume_colour(i: u32) -> Vec3 {
    let mut h = i.wrapping_mul(0x9E37_79B1) ^ 0x5bd1_e995;
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    let c = Vec3::new(
        (h & 0xff) as f32,
        ((h >> 8) & 0xff) as f32,
        ((h >> 16) & 0xff) as f32,
    ) / 255.0;
    0.25 + 0.75 * c
}

/// A camera ray's first hit: the point a ray offset off the surface, on the
/// side facing the camera, that side's normal, and the triangle.
struct CameraHit {
    position: Vec3,
    normal: Vec3,
    triangle: u32,
    front: bool,
}

/// The first hit of each pixel's central camera ray, row by row.
fn camera_hits(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    width: u32,
    height: u32,
) -> Result<Vec<Option<CameraHit>>, RenderError> {
    let cam = &scene.camera;
    let rays: Vec<(Vec3, Vec3)> = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| cam.ray(x as f32 + 0.5, y as f32 + 0.5, width, height))
        .collect();
    let hits = probe::trace_rays(ctx, scene, &rays)?;
    Ok(rays
        .iter()
        .zip(&hits)
        .map(|((o, d), (hit, _))| {
            let (t, tri) = (*hit)?;
            let triangle = &scene.triangles[tri as usize];
            let n = Vec3::from(triangle.e1)
                .cross(Vec3::from(triangle.e2))
                .normalize();
            let front = n.dot(*d) < 0.0;
            let n = if front { n } else { -n };
            Some(CameraHit {
                position: *o + *d * t + n * scene.ray_offset(),
                normal: n,
                triangle: tri,
                front,
            })
        })
        .collect())
}

/// Pictures of the volumes as the camera sees them (shaded by the angle to
/// the camera so shapes stay readable; misses black): the Voronoi regions,
/// each pixel coloured by the volume its first hit uses, and where the
/// guide picks NEE's light, that choice (see `light_choice`) with its legend.
pub fn volume_pictures(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    width: u32,
    height: u32,
) -> Result<(Image, Option<(Image, String)>), RenderError> {
    let (volumes, shade) = seen_volumes(ctx, scene, guide, width, height)?;
    let voronoi = shaded(width, height, &volumes, &shade, |v| {
        v.map_or(Vec3::splat(0.1), volume_colour)
    });
    let choice = light_choice(scene, guide)?.map(|(colours, legend)| {
        let by_power = colours[colours.len() - 1];
        let image = shaded(width, height, &volumes, &shade, |v| {
            v.map_or(by_power, |v| colours[v as usize])
        });
        (image, legend)
    });
    Ok((voronoi, choice))
}

/// Colours of the lights in the light-choice picture, by light (see
/// `shaders::LightGroup`), and their names: as many as the guides pick
/// among (`shaders::MAX_GUIDED_LIGHTS`), so that no two lights share one.
pub const LIGHT_COLOURS: [([f32; 3], &str); 16] = [
    ([1.0, 0.15, 0.1], "red"),
    ([0.1, 0.9, 0.15], "green"),
    ([0.15, 0.3, 1.0], "blue"),
    ([1.0, 0.85, 0.1], "yellow"),
    ([0.9, 0.15, 0.9], "magenta"),
    ([0.1, 0.9, 0.9], "cyan"),
    ([1.0, 0.5, 0.0], "orange"),
    ([0.5, 0.2, 0.9], "purple"),
    ([0.6, 1.0, 0.3], "lime"),
    ([1.0, 0.6, 0.75], "pink"),
    ([0.0, 0.5, 0.5], "teal"),
    ([0.55, 0.3, 0.1], "brown"),
    ([0.1, 0.1, 0.5], "navy"),
    ([0.5, 0.5, 0.0], "olive"),
    ([0.5, 0.0, 0.1], "maroon"),
    ([0.95, 0.95, 0.95], "white"),
];

/// Where the guide picks NEE's light: each volume's colour, then that of
/// the row by power for points without one, the lights' colours
/// (LIGHT_COLOURS, one per light: an emitter's connected triangles, a delta
/// light, the sky, or nearby ones together) mixed by the probabilities with
/// which NEE picks them there; and a legend: which light each colour is.
/// None where the guide picks no light.
fn light_choice(
    scene: &Scene,
    guide: &SarsaGuide,
) -> Result<Option<(Vec<Vec3>, String)>, RenderError> {
    if !guide.chooses_lights() {
        return Ok(None);
    }
    let choice = guide.download_light_choice()?;
    let count = scene.light_group_count();
    let colour = |g: usize| LIGHT_COLOURS[g % LIGHT_COLOURS.len()];
    let colours: Vec<Vec3> = (0..count).map(|g| Vec3::from(colour(g).0)).collect();
    let names = scene.light_names();
    let legend: Vec<String> = names
        .iter()
        .enumerate()
        .map(|(g, name)| format!("{}: {name}", colour(g).1))
        .collect();
    let mixed = choice
        .chunks(colours.len())
        .map(|p| p.iter().zip(&colours).map(|(&p, &c)| p * c).sum())
        .collect();
    Ok(Some((mixed, legend.join(", "))))
}

/// An image of `colour` of each pixel's volume, shaded; misses black.
fn shaded(
    width: u32,
    height: u32,
    volumes: &[Option<u32>],
    shade: &[f32],
    colour: impl Fn(Option<u32>) -> Vec3,
) -> Image {
    let mut image = Image::new(width as usize, height as usize);
    for (i, &v) in volumes.iter().enumerate() {
        if shade[i] > 0.0 {
            image.pixels[i] = (colour(v) * shade[i]).into();
        }
    }
    image
}

/// The volume each pixel's first hit uses, and the pixel's shade by the
/// angle to the camera (0 for a miss).
fn seen_volumes(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    width: u32,
    height: u32,
) -> Result<(Vec<Option<u32>>, Vec<f32>), RenderError> {
    let cam = scene.camera.position;
    let mut queries = Vec::new();
    let mut shade = Vec::new();
    for hit in camera_hits(ctx, scene, width, height)? {
        match hit {
            Some(h) => {
                queries.push(SurfacePoint {
                    position: h.position,
                    triangle: h.triangle,
                    front: h.front,
                });
                let d = (h.position - cam).normalize();
                shade.push(0.35 + 0.65 * h.normal.dot(-d).abs());
            }
            None => {
                queries.push(SurfacePoint {
                    position: Vec3::ZERO,
                    triangle: 0,
                    front: true,
                });
                shade.push(0.0);
            }
        }
    }
    let volumes = probe::nearest_volumes(ctx, scene, guide, &queries)?;
    Ok((volumes, shade))
}

/// Indices of the `count` points nearest to the centre of the brightest light.
fn nearest_light(
    scene: &Scene,
    points: &[crate::guide::volumes::Volume],
    count: usize,
) -> Vec<u32> {
    let Some(light) = scene.lights.iter().max_by(|a, b| a.pdf.total_cmp(&b.pdf)) else {
        return (0..count.min(points.len()) as u32).collect();
    };
    let t = &scene.triangles[light.triangle as usize];
    let centre = Vec3::from(t.v0) + (Vec3::from(t.e1) + Vec3::from(t.e2)) / 3.0;
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.sort_by(|&a, &b| {
        let da = Vec3::from(points[a as usize].position).distance_squared(centre);
        let db = Vec3::from(points[b as usize].position).distance_squared(centre);
        da.total_cmp(&db)
    });
    order.truncate(count);
    order
}

/// The volumes nearest to the centre of the brightest light.
pub fn volumes_near_light(scene: &Scene, guide: &SarsaGuide, count: usize) -> Vec<u32> {
    nearest_light(scene, &guide.volumes, count)
}

/// Q of every sector of the given volumes, one row each.
pub fn volume_rows(guide: &SarsaGuide, q: &[f32], volumes: &[u32]) -> Vec<Vec<f32>> {
    let n = guide.settings.sectors() as usize;
    volumes
        .iter()
        .map(|&v| q[v as usize * n..(v as usize + 1) * n].to_vec())
        .collect()
}

/// Q̂ of every sector as the network infers it at the `count` points the
/// camera sees nearest the brightest light (first hits of a grid of camera
/// rays, shaded on the side facing the camera: states the network trained on).
pub fn neural_rows(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &NeuralGuide,
    count: usize,
) -> Result<Vec<Vec<f32>>, RenderError> {
    let points: Vec<crate::guide::volumes::Volume> = camera_hits(ctx, scene, 64, 64)?
        .into_iter()
        .flatten()
        .filter(|h| scene.triangles[h.triangle as usize].light_pdf == 0.0)
        .map(|h| crate::guide::volumes::Volume {
            position: h.position.into(),
            normal: h.normal.into(),
            ..Default::default()
        })
        .collect();
    let inputs: Vec<f32> = nearest_light(scene, &points, count)
        .iter()
        .flat_map(|&i| {
            let p = &points[i as usize];
            guide.encode(Vec3::from(p.position), Vec3::from(p.normal))
        })
        .collect();
    let q = guide.network.infer(ctx, &inputs)?;
    Ok(q.chunks(guide.settings.sectors() as usize)
        .map(<[f32]>::to_vec)
        .collect())
}

/// A perceptual-ish ramp from dark blue through red to pale yellow.
fn ramp(x: f32) -> Vec3 {
    let stops = [
        Vec3::new(0.02, 0.02, 0.10),
        Vec3::new(0.30, 0.05, 0.45),
        Vec3::new(0.80, 0.20, 0.20),
        Vec3::new(0.98, 0.60, 0.10),
        Vec3::new(0.99, 0.98, 0.75),
    ];
    let x = x.clamp(0.0, 1.0) * (stops.len() - 1) as f32;
    let i = (x as usize).min(stops.len() - 2);
    stops[i].lerp(stops[i + 1], x - i as f32)
}

/// One disk per row of Q (an a×b `grid` of sectors), side by side: the
/// hemisphere seen from above (the equal-area disk), each sector coloured by
/// its Q relative to the row's largest.
pub fn hemispheres(grid: [u32; 2], rows: &[Vec<f32>], size: usize) -> Image {
    let [a, b] = grid;
    let gap = size / 8;
    let mut image = Image::new(rows.len() * (size + gap) + gap, size + 2 * gap);
    for p in image.pixels.iter_mut() {
        *p = [0.12; 3];
    }
    for (slot, values) in rows.iter().enumerate() {
        let max = values.iter().cloned().fold(0.0f32, f32::max).max(1e-12);
        for y in 0..size {
            for x in 0..size {
                let d = Vec2::new(
                    2.0 * (x as f32 + 0.5) / size as f32 - 1.0,
                    1.0 - 2.0 * (y as f32 + 0.5) / size as f32,
                );
                if d.length() > 1.0 {
                    continue;
                }
                let u = sampling::disk_to_square(d);
                let k = ((u.x * a as f32) as usize).min(a as usize - 1)
                    + a as usize * ((u.y * b as f32) as usize).min(b as usize - 1);
                let px = gap + slot * (size + gap) + x;
                image.pixels[(gap + y) * image.width + px] = ramp(values[k] / max).into();
            }
        }
    }
    image
}
