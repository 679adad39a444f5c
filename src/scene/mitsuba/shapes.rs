//! Mitsuba's built-in shapes as triangles in world space. The curved ones
//! are tessellated finely and scaled so that their area is the true shape's
//! (an emitter's power, a sphere's silhouette stay right).

use glam::{Mat3, Mat4, Vec2, Vec3};
use std::f32::consts::PI;

/// Segments around a disk, a cylinder or (at most) a sphere's equator.
pub const SEGMENTS: u32 = 128;
/// Fewest segments around a sphere's equator.
pub const MIN_SPHERE_SEGMENTS: u32 = 16;
/// The most a sphere's outline may fall inside the true one, in pixels
/// of the image (see [`sphere_segments`]).
const SPHERE_PIXEL_ERROR: f32 = 0.05;

/// Segments around the equator of a sphere that spans `pixels` pixels
/// in radius on the image: enough that no chord of its outline falls
/// more than SPHERE_PIXEL_ERROR inside the true circle (a chord of n
/// segments falls r pi² / (2 n²) inside), a multiple of 4 in
/// MIN_SPHERE_SEGMENTS..=SEGMENTS. A sphere of 128 segments is 16,256
/// triangles: a point cloud of thousands of small spheres (as the usual
/// Mitsuba template renders one) would not fit a scene at that detail.
pub fn sphere_segments(pixels: f32) -> u32 {
    let n = PI * (pixels / (2.0 * SPHERE_PIXEL_ERROR)).sqrt();
    // Not a number (no measure of its size) takes the most.
    if n.is_nan() || n >= SEGMENTS as f32 {
        return SEGMENTS;
    }
    ((n.ceil() as u32).div_ceil(4) * 4).clamp(MIN_SPHERE_SEGMENTS, SEGMENTS)
}

/// Triangles of an analytic shape (or a shapegroup's, placed by an
/// instance), wound so that their normal is Mitsuba's:
/// the shape's normal transformed as a normal, which keeps its side even
/// where `to_world` mirrors.
pub(super) fn placed(to_world: Mat4, triangles: Vec<[Vec3; 3]>) -> Vec<[Vec3; 3]> {
    let mirrors = Mat3::from_mat4(to_world).determinant() < 0.0;
    triangles
        .into_iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| to_world.transform_point3(v));
            if mirrors {
                [a, c, b]
            } else {
                [a, b, c]
            }
        })
        .collect()
}

/// Texture coordinates wound as [`placed`] winds.
pub(super) fn placed_uvs(to_world: Mat4, uvs: Vec<[Vec2; 3]>) -> Vec<[Vec2; 3]> {
    let mirrors = Mat3::from_mat4(to_world).determinant() < 0.0;
    uvs.into_iter()
        .map(|[a, b, c]| if mirrors { [a, c, b] } else { [a, b, c] })
        .collect()
}

/// Normals at `local`'s corners (a unit sphere's points are their own
/// normals), transformed as normals and wound as [`placed`] winds.
pub(super) fn placed_normals(to_world: Mat4, local: &[[Vec3; 3]]) -> Vec<[Vec3; 3]> {
    let m = Mat3::from_mat4(to_world);
    let normal_matrix = m.inverse().transpose();
    let mirrors = m.determinant() < 0.0;
    local
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|n| (normal_matrix * n).normalize());
            if mirrors {
                [a, c, b]
            } else {
                [a, b, c]
            }
        })
        .collect()
}

/// [-1, 1]² in the plane z = 0, facing +z; Mitsuba's (u, v) is
/// ((x + 1) / 2, (y + 1) / 2).
pub fn rectangle(to_world: Mat4) -> (Vec<[Vec3; 3]>, Vec<[Vec2; 3]>) {
    let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
    let local = vec![
        [p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0)],
        [p(-1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)],
    ];
    let uvs = local
        .iter()
        .map(|t| t.map(|v| Vec2::new(0.5 * (v.x + 1.0), 0.5 * (v.y + 1.0))))
        .collect();
    (placed(to_world, local), placed_uvs(to_world, uvs))
}

/// [-1, 1]³, its faces facing out. A mesh in Mitsuba: the winding, not
/// the transformed normal, says which side is out. Each face's (u, v) is
/// Mitsuba's: two of ((1 ± x) / 2, (1 ± y) / 2, (1 ± z) / 2) per face
/// (`cube_uv`).
pub fn cube(to_world: Mat4) -> (Vec<[Vec3; 3]>, Vec<[Vec2; 3]>) {
    let mut out = Vec::with_capacity(12);
    let mut uvs = Vec::with_capacity(12);
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            // u × v = n, so (c, c+u, c+u+v) winds counter-clockwise seen from outside.
            let mut u = Vec3::ZERO;
            u[(axis + 1) % 3] = 1.0;
            let v = n.cross(u);
            let local = |a: f32, b: f32| n + a * u + b * v;
            for t in [
                [local(-1.0, -1.0), local(1.0, -1.0), local(1.0, 1.0)],
                [local(-1.0, -1.0), local(1.0, 1.0), local(-1.0, 1.0)],
            ] {
                out.push(t.map(|p| to_world.transform_point3(p)));
                uvs.push(t.map(|p| cube_uv(axis, sign, p)));
            }
        }
    }
    (out, uvs)
}

/// Mitsuba's (u, v) on the cube's face along `axis` on side `sign`.
fn cube_uv(axis: usize, sign: f32, p: Vec3) -> Vec2 {
    let h = |c: f32| 0.5 * (1.0 + c);
    match (axis, sign > 0.0) {
        (2, true) => Vec2::new(h(p.y), h(p.x)),
        (2, false) => Vec2::new(h(-p.y), h(p.x)),
        (0, true) => Vec2::new(h(p.y), h(-p.z)),
        (0, false) => Vec2::new(h(p.y), h(p.z)),
        (1, true) => Vec2::new(h(-p.x), h(-p.z)),
        _ => Vec2::new(h(p.z), h(p.x)),
    }
}

/// The unit disk in the plane z = 0, facing +z; Mitsuba's (u, v) is the
/// radius and the angle over 2π, interpolated across each triangle.
pub fn disk(to_world: Mat4) -> (Vec<[Vec3; 3]>, Vec<[Vec2; 3]>) {
    let n = SEGMENTS as f32;
    // The polygon's area n/2 sin(2 pi / n) r² made pi r².
    let r = (PI / (0.5 * n * (2.0 * PI / n).sin())).sqrt();
    let rim = |i: u32| {
        let phi = 2.0 * PI * i as f32 / n;
        Vec3::new(r * phi.cos(), r * phi.sin(), 0.0)
    };
    let triangles = (0..SEGMENTS)
        .map(|i| [Vec3::ZERO, rim(i), rim(i + 1)])
        .collect();
    // The centre takes the angle of its triangle's middle.
    let uvs = (0..SEGMENTS)
        .map(|i| {
            let v = |k: f32| k / n;
            [
                Vec2::new(0.0, v(i as f32 + 0.5)),
                Vec2::new(1.0, v(i as f32)),
                Vec2::new(1.0, v(i as f32 + 1.0)),
            ]
        })
        .collect();
    (placed(to_world, triangles), placed_uvs(to_world, uvs))
}

/// A sphere of `segments` segments around its equator and half as many
/// rings, its faces facing out, its normals at their corners, and
/// Mitsuba's (u, v): the angle about z over 2π and from +z over π.
#[allow(clippy::type_complexity)]
pub fn sphere(
    to_world: Mat4,
    center: Vec3,
    radius: f32,
    segments: u32,
) -> (Vec<[Vec3; 3]>, Vec<[Vec3; 3]>, Vec<[Vec2; 3]>) {
    let rings = segments / 2;
    let point = |ring: u32, seg: u32| {
        let theta = PI * ring as f32 / rings as f32;
        let phi = 2.0 * PI * (seg % segments) as f32 / segments as f32;
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    };
    let uv =
        |ring: u32, seg: u32| Vec2::new(seg as f32 / segments as f32, ring as f32 / rings as f32);
    let mut unit = Vec::with_capacity((2 * segments * (rings - 1)) as usize);
    let mut uvs = Vec::with_capacity(unit.capacity());
    for ring in 0..rings {
        for seg in 0..segments {
            let (a, b) = (point(ring, seg), point(ring, seg + 1));
            let (c, d) = (point(ring + 1, seg), point(ring + 1, seg + 1));
            // Counter-clockwise seen from outside; the poles' rings have one.
            if ring > 0 {
                unit.push([a, c, b]);
                uvs.push([uv(ring, seg), uv(ring + 1, seg), uv(ring, seg + 1)]);
            }
            if ring + 1 < rings {
                unit.push([b, c, d]);
                uvs.push([uv(ring, seg + 1), uv(ring + 1, seg), uv(ring + 1, seg + 1)]);
            }
        }
    }
    let area: f32 = unit
        .iter()
        .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
        .sum();
    let scale = radius * (4.0 * PI / area).sqrt();
    let local = Mat4::from_translation(center) * Mat4::from_scale(Vec3::splat(scale));
    let normals = placed_normals(to_world, &unit);
    (
        placed(to_world * local, unit),
        normals,
        placed_uvs(to_world, uvs),
    )
}

/// Mitsuba's frame about a unit vector `n`: its (s, t), as its
/// `coordinate_system` builds them (Duff et al. 2017).
fn frame_about(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// An open tube from `p0` to `p1` of radius `radius`, facing out, its
/// normals at their corners, and Mitsuba's (u, v): the angle about the
/// axis over 2π (from Mitsuba's frame about it) and the distance along it
/// over its length. `None` where p0 and p1 coincide.
#[allow(clippy::type_complexity)]
pub fn cylinder(
    to_world: Mat4,
    p0: Vec3,
    p1: Vec3,
    radius: f32,
) -> Option<(Vec<[Vec3; 3]>, Vec<[Vec3; 3]>, Vec<[Vec2; 3]>)> {
    let axis = p1 - p0;
    let length = axis.length();
    if length == 0.0 || !length.is_finite() {
        return None;
    }
    let d = axis / length;
    let (s, t) = frame_about(d);
    let n = SEGMENTS as f32;
    // The prism's perimeter n 2 sin(pi / n) r made 2 pi r.
    let r = radius * PI / (n * (PI / n).sin());
    let local = Mat4::from_cols(
        (s * r).extend(0.0),
        (t * r).extend(0.0),
        (d * length).extend(0.0),
        p0.extend(1.0),
    );
    let rim = |i: u32, z: f32| {
        let phi = 2.0 * PI * (i % SEGMENTS) as f32 / n;
        Vec3::new(phi.cos(), phi.sin(), z)
    };
    let radial = |v: Vec3| Vec3::new(v.x, v.y, 0.0);
    let (mut unit, mut uvs) = (Vec::new(), Vec::new());
    for i in 0..SEGMENTS {
        let (a, b, c, e) = (rim(i, 0.0), rim(i + 1, 0.0), rim(i, 1.0), rim(i + 1, 1.0));
        let uv = |k: u32, z: f32| Vec2::new(k as f32 / n, z);
        // Counter-clockwise seen from outside.
        unit.push([a, b, e]);
        uvs.push([uv(i, 0.0), uv(i + 1, 0.0), uv(i + 1, 1.0)]);
        unit.push([a, e, c]);
        uvs.push([uv(i, 0.0), uv(i + 1, 1.0), uv(i, 1.0)]);
    }
    let normals: Vec<[Vec3; 3]> = unit.iter().map(|t| t.map(radial)).collect();
    let placed_to = to_world * local;
    Some((
        placed(placed_to, unit),
        placed_normals(placed_to, &normals),
        placed_uvs(placed_to, uvs),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(t: &[[Vec3; 3]]) -> f32 {
        t.iter()
            .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
            .sum()
    }

    fn normal(t: &[Vec3; 3]) -> Vec3 {
        (t[1] - t[0]).cross(t[2] - t[0]).normalize()
    }

    #[test]
    fn spheres_take_the_segments_their_size_on_the_image_needs() {
        // n = pi sqrt(pixels / 0.1), up to a multiple of 4, in 16..=128.
        assert_eq!(sphere_segments(0.0), 16);
        assert_eq!(sphere_segments(1.0), 16);
        assert_eq!(sphere_segments(10.0), 32);
        assert_eq!(sphere_segments(18.0), 44);
        assert_eq!(sphere_segments(160.0), 128);
        assert_eq!(sphere_segments(1e6), 128);
        assert_eq!(sphere_segments(f32::INFINITY), 128);
        assert_eq!(sphere_segments(f32::NAN), 128);
        // The outline's chord stays within the bound where not capped.
        for px in [3.0f32, 10.0, 40.0, 100.0, 150.0] {
            let n = sphere_segments(px) as f32;
            assert!(px * PI * PI / (2.0 * n * n) <= SPHERE_PIXEL_ERROR, "{px}");
        }
    }

    #[test]
    fn shapes_have_their_true_area_and_face_out() {
        let m = Mat4::IDENTITY;
        assert!((area(&rectangle(m).0) - 4.0).abs() < 1e-5);
        assert!((area(&cube(m).0) - 24.0).abs() < 1e-4);
        assert!((area(&disk(m).0) - PI).abs() < 1e-4);
        let (s, normals, _) = sphere(m, Vec3::new(1.0, 2.0, 3.0), 0.5, SEGMENTS);
        assert!((area(&s) - PI).abs() < 1e-3 * PI, "{}", area(&s));
        let (coarse, _, _) = sphere(m, Vec3::new(1.0, 2.0, 3.0), 0.5, MIN_SPHERE_SEGMENTS);
        assert!((area(&coarse) - PI).abs() < 1e-3 * PI, "{}", area(&coarse));
        assert_eq!(coarse.len(), 16 * 7 * 2);
        for (t, n) in s.iter().zip(&normals) {
            let c = (t[0] + t[1] + t[2]) / 3.0 - Vec3::new(1.0, 2.0, 3.0);
            assert!(normal(t).dot(c) > 0.0);
            // Each corner's normal points from the centre through it.
            for (v, n) in t.iter().zip(n) {
                assert!((*v - Vec3::new(1.0, 2.0, 3.0)).normalize().dot(*n) > 0.9999);
            }
        }
        for t in &cube(m).0 {
            assert!(normal(t).dot(t[0] + t[1] + t[2]) > 0.0);
        }
        assert!(rectangle(m).0.iter().all(|t| normal(t).z > 0.99));
        assert!(disk(m).0.iter().all(|t| normal(t).z > 0.99));
        // A tube along (1, 1, 1) from (1, 0, 0), of radius 0.5, length 3.
        let (p0, p1) = (Vec3::X, Vec3::X + Vec3::splat(3.0f32.sqrt()));
        let (c, normals, uvs) = cylinder(m, p0, p1, 0.5).unwrap();
        assert!(
            (area(&c) - 2.0 * PI * 0.5 * 3.0).abs() < 1e-3,
            "{}",
            area(&c)
        );
        let axis = (p1 - p0).normalize();
        for ((t, n), uv) in c.iter().zip(&normals).zip(&uvs) {
            for ((v, n), uv) in t.iter().zip(n).zip(uv) {
                let along = (*v - p0).dot(axis);
                let out = (*v - p0 - along * axis).normalize();
                assert!(out.dot(*n) > 0.9999 && out.dot(normal(t)) > 0.99);
                assert!((along / 3.0 - uv.y).abs() < 1e-5);
            }
        }
        assert!(cylinder(m, p0, p0, 1.0).is_none());
    }

    #[test]
    fn frames_are_mitsubas() {
        // Mitsuba 3.9.1's coordinate_system(n).
        for (n, s, t) in [
            (
                [0.882_108_6, 0.165_395_4, -0.441_054_3],
                [0.460_037_4, -0.101_243, 0.882_108_6],
                [0.101_243, -0.981_017, -0.165_395_4],
            ),
            (
                [0.303_045_8, 0.505_076_2, 0.808_122],
                [0.949_208_8, -0.084_652, -0.303_045_8],
                [-0.084_652, 0.858_913_3, -0.505_076_2],
            ),
            ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ] {
            let (fs, ft) = frame_about(Vec3::from(n));
            assert!((fs - Vec3::from(s)).length() < 1e-5 && (ft - Vec3::from(t)).length() < 1e-5);
        }
    }

    #[test]
    fn a_cylinders_angle_starts_where_mitsubas_does() {
        // Mitsuba's default cylinder: along z, (u, v) = (0, 0) at (1, 0, 0).
        let (c, _, uvs) = cylinder(Mat4::IDENTITY, Vec3::ZERO, Vec3::Z, 1.0).unwrap();
        let r = PI / (SEGMENTS as f32 * (PI / SEGMENTS as f32).sin());
        assert!((c[0][0] - Vec3::new(r, 0.0, 0.0)).length() < 1e-6);
        assert_eq!(uvs[0][0], Vec2::ZERO);
    }

    #[test]
    fn a_mirroring_transform_keeps_an_analytic_shape_facing_its_side() {
        // Mirrored in x, the rectangle's normal (a normal transformed by
        // the inverse transpose) still points to +z.
        let m = Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        assert!(rectangle(m).0.iter().all(|t| normal(t).z > 0.99));
        let (s, n, _) = sphere(m, Vec3::ZERO, 1.0, SEGMENTS);
        assert!(s.iter().all(|t| normal(t).dot(t[0] + t[1] + t[2]) > 0.0));
        assert!(s.iter().zip(&n).all(|(t, n)| n[1].dot(t[1]) > 0.99));
    }
}
