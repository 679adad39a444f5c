//! Mitsuba's `serialized` meshes: a file of zlib-compressed shapes (each
//! positions, optional normals, texture coordinates and colours, and
//! triangles) followed by a table of where each starts. Counts are checked
//! against the triangle limit before anything is allocated for them, and
//! decompression reads no more than the counts call for.

use super::ply::IndexedMesh;
use glam::{Vec2, Vec3};
use std::io::Read;

const MAGIC: u16 = 0x041c;
const HAS_NORMALS: u32 = 0x0001;
const HAS_TEXCOORDS: u32 = 0x0002;
const HAS_COLORS: u32 = 0x0008;
/// The shape asks to be shaded with its faces' normals.
pub const FACE_NORMALS: u32 = 0x0010;
const SINGLE: u32 = 0x1000;
const DOUBLE: u32 = 0x2000;

/// A shape of a serialized file, and its flags.
pub struct Shape {
    pub mesh: IndexedMesh,
    pub flags: u32,
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

/// Reads shape `index` of a serialized file, refusing more than
/// `max_triangles` triangles.
pub fn parse_serialized(bytes: &[u8], index: u32, max_triangles: usize) -> Result<Shape, String> {
    let truncated = || "the file is truncated".to_string();
    if bytes.len() < 8 {
        return Err(truncated());
    }
    let count = u32_at(bytes, bytes.len() - 4).ok_or_else(truncated)?;
    if index >= count {
        return Err(format!(
            "shape_index {index}, but the file holds {count} shape{}",
            if count == 1 { "" } else { "s" }
        ));
    }
    let version = u16::from_le_bytes([bytes[2], bytes[3]]);
    if u16::from_le_bytes([bytes[0], bytes[1]]) != MAGIC {
        return Err("not a Mitsuba serialized mesh (wrong magic number)".into());
    }
    // The table of offsets: u64 each from version 4 on, u32 before.
    let start = if version >= 4 {
        let table = (bytes.len() - 4)
            .checked_sub(8 * count as usize)
            .ok_or_else(truncated)?;
        u64_at(bytes, table + 8 * index as usize).ok_or_else(truncated)? as usize
    } else {
        let table = (bytes.len() - 4)
            .checked_sub(4 * count as usize)
            .ok_or_else(truncated)?;
        u32_at(bytes, table + 4 * index as usize).ok_or_else(truncated)? as usize
    };
    let header = bytes.get(start..start + 4).ok_or_else(truncated)?;
    if u16::from_le_bytes([header[0], header[1]]) != MAGIC {
        return Err(format!(
            "shape {index} does not start with the magic number"
        ));
    }
    let version = u16::from_le_bytes([header[2], header[3]]);
    if !(3..=4).contains(&version) {
        return Err(format!("format version {version}; qtrace reads 3 and 4"));
    }
    let mut z = flate2::read::ZlibDecoder::new(&bytes[start + 4..]);
    let mut read = |n: usize| -> Result<Vec<u8>, String> {
        let mut buf = vec![0u8; n];
        z.read_exact(&mut buf)
            .map_err(|e| format!("shape {index}: the compressed data ends early ({e})"))?;
        Ok(buf)
    };
    let flags = u32::from_le_bytes(read(4)?.try_into().unwrap_or_default());
    if version >= 4 {
        // The shape's name, ended by a zero byte.
        let mut len = 0;
        while read(1)?[0] != 0 {
            len += 1;
            if len > 4096 {
                return Err("the shape's name is too long".into());
            }
        }
    }
    let vertices = u64::from_le_bytes(read(8)?.try_into().unwrap_or_default());
    let triangles = u64::from_le_bytes(read(8)?.try_into().unwrap_or_default());
    if triangles > max_triangles as u64 {
        return Err(format!(
            "shape {index} has {triangles} triangles, more than the {max_triangles} a scene may have"
        ));
    }
    // Vertices no triangle uses are allowed, but not beyond any sense.
    if vertices > 3 * max_triangles as u64 + 1024 {
        return Err(format!("shape {index} claims {vertices} vertices"));
    }
    let (vertices, triangles) = (vertices as usize, triangles as usize);
    let double = match flags & (SINGLE | DOUBLE) {
        SINGLE => false,
        DOUBLE => true,
        _ => return Err(format!("shape {index}: flags {flags:#x} give no precision")),
    };
    let size = if double { 8 } else { 4 };
    let mut floats = |n: usize| -> Result<Vec<f32>, String> {
        let raw = read(n * size)?;
        Ok(raw
            .chunks_exact(size)
            .map(|c| {
                if double {
                    f64::from_le_bytes(c.try_into().unwrap_or_default()) as f32
                } else {
                    f32::from_le_bytes(c.try_into().unwrap_or_default())
                }
            })
            .collect())
    };
    let v3 = |f: Vec<f32>| -> Vec<Vec3> {
        f.chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect()
    };
    let positions = v3(floats(3 * vertices)?);
    let normals = if flags & HAS_NORMALS != 0 {
        Some(v3(floats(3 * vertices)?))
    } else {
        None
    };
    let uvs = if flags & HAS_TEXCOORDS != 0 {
        Some(
            floats(2 * vertices)?
                .chunks_exact(2)
                .map(|c| Vec2::new(c[0], c[1]))
                .collect(),
        )
    } else {
        None
    };
    if flags & HAS_COLORS != 0 {
        floats(3 * vertices)?;
    }
    let wide = vertices > u32::MAX as usize;
    let raw = read(3 * triangles * if wide { 8 } else { 4 })?;
    let mut out = Vec::with_capacity(triangles);
    let index_at = |i: usize| -> u64 {
        if wide {
            u64::from_le_bytes(raw[8 * i..8 * i + 8].try_into().unwrap_or_default())
        } else {
            u32::from_le_bytes(raw[4 * i..4 * i + 4].try_into().unwrap_or_default()) as u64
        }
    };
    for t in 0..triangles {
        let tri = [index_at(3 * t), index_at(3 * t + 1), index_at(3 * t + 2)];
        if let Some(&bad) = tri.iter().find(|&&i| i >= vertices as u64) {
            return Err(format!(
                "shape {index}: a triangle names vertex {bad}, but the shape has {vertices}"
            ));
        }
        out.push(tri.map(|i| i as u32));
    }
    Ok(Shape {
        mesh: IndexedMesh {
            positions,
            normals,
            uvs,
            triangles: out,
            attributes: Vec::new(),
        },
        flags,
    })
}

/// A serialized file of `shapes` (their positions, normals if any, and
/// triangles), version 4, single precision: for tests and tools.
pub fn write_serialized(shapes: &[IndexedMesh]) -> Vec<u8> {
    use std::io::Write;
    let mut out = Vec::new();
    let mut offsets = Vec::new();
    for IndexedMesh {
        positions,
        normals,
        triangles,
        ..
    } in shapes
    {
        offsets.push(out.len() as u64);
        out.extend(MAGIC.to_le_bytes());
        out.extend(4u16.to_le_bytes());
        let mut body = Vec::new();
        let flags = SINGLE | if normals.is_some() { HAS_NORMALS } else { 0 };
        body.extend(flags.to_le_bytes());
        body.extend(b"shape\0");
        body.extend((positions.len() as u64).to_le_bytes());
        body.extend((triangles.len() as u64).to_le_bytes());
        for p in positions.iter().chain(normals.iter().flatten()) {
            for c in p.to_array() {
                body.extend(c.to_le_bytes());
            }
        }
        for t in triangles {
            for i in t {
                body.extend(i.to_le_bytes());
            }
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&body).expect("writing to memory");
        out.extend(z.finish().expect("writing to memory"));
    }
    for o in &offsets {
        out.extend(o.to_le_bytes());
    }
    out.extend((offsets.len() as u32).to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_shapes() -> Vec<u8> {
        let quad = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        write_serialized(&[
            IndexedMesh {
                positions: quad.clone(),
                triangles: vec![[0, 1, 2], [0, 2, 3]],
                ..Default::default()
            },
            IndexedMesh {
                positions: quad,
                normals: Some(vec![Vec3::Z; 4]),
                triangles: vec![[0, 1, 2]],
                ..Default::default()
            },
        ])
    }

    #[test]
    fn shapes_read_back_by_index() {
        let bytes = two_shapes();
        let a = parse_serialized(&bytes, 0, 10).unwrap();
        assert_eq!(a.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(a.mesh.positions[2], Vec3::new(1.0, 1.0, 0.0));
        assert!(a.mesh.normals.is_none());
        let b = parse_serialized(&bytes, 1, 10).unwrap();
        assert_eq!(b.mesh.triangles.len(), 1);
        assert_eq!(b.mesh.normals.unwrap()[3], Vec3::Z);
        let e = parse_serialized(&bytes, 2, 10).err().unwrap();
        assert!(e.contains("holds 2 shapes"), "{e}");
    }

    #[test]
    fn damage_is_an_error() {
        let bytes = two_shapes();
        for cut in [0, 3, 20, bytes.len() / 2, bytes.len() - 5] {
            assert!(
                parse_serialized(&bytes[..cut], 0, 10).is_err(),
                "cut at {cut}"
            );
        }
        let mut bad = bytes.clone();
        bad[0] = 0;
        assert!(parse_serialized(&bad, 0, 10).is_err());
        let e = parse_serialized(&bytes, 0, 1).err().unwrap();
        assert!(e.contains("more than the 1"), "{e}");
        for i in 4..bytes.len() - 16 {
            let mut flipped = bytes.clone();
            flipped[i] ^= 0x5a;
            let _ = parse_serialized(&flipped, 0, 10);
        }
    }
}
