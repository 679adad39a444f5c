//! Stanford PLY meshes, ASCII and binary (either byte order): vertex
//! positions, normals and texture coordinates, and faces as polygons (fans
//! of triangles). Other elements and properties are read past. Every count
//! the header gives is checked against the bytes that follow before anything
//! is allocated for it, so no file can make the reader panic or allocate
//! beyond its own size.

use glam::{Vec2, Vec3};

/// A PLY mesh: vertices, and triangles as indices into them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexedMesh {
    pub positions: Vec<Vec3>,
    /// Per vertex, where the file has `nx ny nz`.
    pub normals: Option<Vec<Vec3>>,
    /// Per vertex, where the file has `u v` (or `s t`, `texture_u ...`).
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
enum Property {
    Scalar(String, Scalar),
    /// A list: the count's type and the items'.
    List(String, Scalar, Scalar),
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ascii,
    Little,
    Big,
}

/// Reads values one after another, from text or bytes.
struct Values<'a> {
    format: Format,
    bytes: &'a [u8],
    at: usize,
}

impl Values<'_> {
    fn next(&mut self, t: Scalar) -> Result<f64, String> {
        if self.format == Format::Ascii {
            while self.at < self.bytes.len() && self.bytes[self.at].is_ascii_whitespace() {
                self.at += 1;
            }
            let start = self.at;
            while self.at < self.bytes.len() && !self.bytes[self.at].is_ascii_whitespace() {
                self.at += 1;
            }
            if start == self.at {
                return Err("the file ends before its elements do".into());
            }
            let word = std::str::from_utf8(&self.bytes[start..self.at]).unwrap_or("?");
            return word
                .parse::<f64>()
                .map_err(|_| format!("'{word}' is not a number"));
        }
        let n = t.size();
        let Some(b) = self.bytes.get(self.at..self.at + n) else {
            return Err("the file ends before its elements do".into());
        };
        self.at += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == Format::Big {
            a[..n].reverse();
        }
        Ok(match t {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }

    /// Bytes (binary) or characters (ASCII) left: a bound on how many
    /// values can follow.
    fn left(&self) -> usize {
        self.bytes.len() - self.at
    }
}

/// The header's lines up to `end_header`, and where the body starts.
fn header(bytes: &[u8]) -> Result<(Vec<&str>, usize), String> {
    let mut lines = Vec::new();
    let mut at = 0;
    loop {
        let Some(len) = bytes[at..].iter().position(|&b| b == b'\n') else {
            return Err("the header has no end_header line".into());
        };
        let line = std::str::from_utf8(&bytes[at..at + len])
            .map_err(|_| "the header is not text".to_string())?
            .trim_end_matches('\r')
            .trim();
        at += len + 1;
        if line == "end_header" {
            return Ok((lines, at));
        }
        lines.push(line);
    }
}

/// Parses a PLY file, refusing more than `max_triangles` triangles.
pub fn parse_ply(bytes: &[u8], max_triangles: usize) -> Result<IndexedMesh, String> {
    if !bytes.starts_with(b"ply") {
        return Err("not a PLY file (it does not start with 'ply')".into());
    }
    let (lines, body) = header(bytes)?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in lines.iter().enumerate().skip(1) {
        let fail = |m: &str| format!("header line {}: {m}", i + 1);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _version] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    other => return Err(fail(&format!("unknown format '{other}'"))),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| fail(&format!("'{count}' is not a count")))?,
                properties: Vec::new(),
            }),
            ["property", "list", count, item, name] => {
                let (Some(c), Some(t)) = (Scalar::parse(count), Scalar::parse(item)) else {
                    return Err(fail("unknown list type"));
                };
                if matches!(c, Scalar::F32 | Scalar::F64) {
                    return Err(fail("a list's count must be an integer type"));
                }
                elements
                    .last_mut()
                    .ok_or_else(|| fail("a property before any element"))?
                    .properties
                    .push(Property::List(name.to_string(), c, t));
            }
            ["property", t, name] => {
                let t = Scalar::parse(t).ok_or_else(|| fail(&format!("unknown type '{t}'")))?;
                elements
                    .last_mut()
                    .ok_or_else(|| fail("a property before any element"))?
                    .properties
                    .push(Property::Scalar(name.to_string(), t));
            }
            _ => return Err(fail(&format!("cannot read '{line}'"))),
        }
    }
    let format = format.ok_or("the header has no format line")?;
    let mut values = Values {
        format,
        bytes: &bytes[body..],
        at: 0,
    };
    let mut mesh = IndexedMesh::default();
    for e in &elements {
        // Each item takes at least one byte (or character): a count beyond
        // what is left is a lie.
        let least: usize = e
            .properties
            .iter()
            .map(|p| match p {
                Property::Scalar(_, t) | Property::List(_, t, _) => t.size(),
            })
            .sum::<usize>()
            .max(1);
        let least = if format == Format::Ascii { 1 } else { least };
        if e.count.saturating_mul(least) > values.left() {
            return Err(format!(
                "element '{}' claims {} items, more than the file holds",
                e.name, e.count
            ));
        }
        match e.name.as_str() {
            "vertex" => read_vertices(e, &mut values, &mut mesh)?,
            "face" => read_faces(e, &mut values, &mut mesh, max_triangles)?,
            _ => skip(e, &mut values)?,
        }
    }
    for t in &mesh.triangles {
        if t.iter().any(|&i| i as usize >= mesh.positions.len()) {
            return Err(format!(
                "a face names vertex {}, but the file has {}",
                t.iter().max().unwrap_or(&0),
                mesh.positions.len()
            ));
        }
    }
    Ok(mesh)
}

fn read_vertices(e: &Element, v: &mut Values, mesh: &mut IndexedMesh) -> Result<(), String> {
    let find = |names: &[&str]| {
        e.properties
            .iter()
            .position(|p| matches!(p, Property::Scalar(n, _) if names.contains(&n.as_str())))
    };
    let (Some(x), Some(y), Some(z)) = (find(&["x"]), find(&["y"]), find(&["z"])) else {
        return Err("element 'vertex' lacks x, y or z".into());
    };
    let normal = (find(&["nx"]), find(&["ny"]), find(&["nz"]));
    let uv = (
        find(&["u", "s", "texture_u", "texture_s"]),
        find(&["v", "t", "texture_v", "texture_t"]),
    );
    let has_normals = matches!(normal, (Some(_), Some(_), Some(_)));
    let has_uvs = matches!(uv, (Some(_), Some(_)));
    mesh.positions.reserve(e.count);
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut row = vec![0.0f64; e.properties.len()];
    for _ in 0..e.count {
        for (slot, p) in row.iter_mut().zip(&e.properties) {
            *slot = match p {
                Property::Scalar(_, t) => v.next(*t)?,
                Property::List(_, c, t) => {
                    let n = v.next(*c)?;
                    for _ in 0..list_len(n, v)? {
                        v.next(*t)?;
                    }
                    0.0
                }
            };
        }
        let p = Vec3::new(row[x] as f32, row[y] as f32, row[z] as f32);
        mesh.positions.push(p);
        if let (Some(a), Some(b), Some(c)) = normal {
            normals.push(Vec3::new(row[a] as f32, row[b] as f32, row[c] as f32));
        }
        if let (Some(a), Some(b)) = uv {
            uvs.push(Vec2::new(row[a] as f32, row[b] as f32));
        }
    }
    mesh.normals = has_normals.then_some(normals);
    mesh.uvs = has_uvs.then_some(uvs);
    Ok(())
}

/// A list's length, checked against what is left to read.
fn list_len(n: f64, v: &Values) -> Result<usize, String> {
    if !(n >= 0.0 && n.fract() == 0.0) || n as usize > v.left() {
        return Err(format!("a list claims {n} items"));
    }
    Ok(n as usize)
}

fn read_faces(
    e: &Element,
    v: &mut Values,
    mesh: &mut IndexedMesh,
    max_triangles: usize,
) -> Result<(), String> {
    let index = e.properties.iter().position(
        |p| matches!(p, Property::List(n, _, _) if n == "vertex_indices" || n == "vertex_index"),
    );
    let Some(index) = index else {
        return Err("element 'face' has no vertex_indices list".into());
    };
    let mut corners: Vec<u32> = Vec::new();
    for _ in 0..e.count {
        for (k, p) in e.properties.iter().enumerate() {
            match p {
                Property::Scalar(_, t) => {
                    v.next(*t)?;
                }
                Property::List(_, c, t) => {
                    let n = list_len(v.next(*c)?, v)?;
                    if k != index {
                        for _ in 0..n {
                            v.next(*t)?;
                        }
                        continue;
                    }
                    corners.clear();
                    for _ in 0..n {
                        let i = v.next(*t)?;
                        if !(i >= 0.0 && i.fract() == 0.0 && i <= u32::MAX as f64) {
                            return Err(format!("a face names vertex {i}"));
                        }
                        corners.push(i as u32);
                    }
                    if n < 3 {
                        return Err(format!("a face has {n} corners; it needs at least 3"));
                    }
                    if mesh.triangles.len() + n - 2 > max_triangles {
                        return Err(format!(
                            "more than {max_triangles} triangles, the most a scene may have"
                        ));
                    }
                    for j in 1..n - 1 {
                        mesh.triangles
                            .push([corners[0], corners[j], corners[j + 1]]);
                    }
                }
            }
        }
    }
    Ok(())
}

fn skip(e: &Element, v: &mut Values) -> Result<(), String> {
    for _ in 0..e.count {
        for p in &e.properties {
            match p {
                Property::Scalar(_, t) => {
                    v.next(*t)?;
                }
                Property::List(_, c, t) => {
                    for _ in 0..list_len(v.next(*c)?, v)? {
                        v.next(*t)?;
                    }
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const ASCII: &str = "ply\nformat ascii 1.0\ncomment a quad\nelement vertex 4\n\
        property float x\nproperty float y\nproperty float z\nproperty float nx\n\
        property float ny\nproperty float nz\nproperty float u\nproperty float v\n\
        element face 1\nproperty list uchar int vertex_indices\nend_header\n\
        0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n1 1 0 0 0 1 1 1\n0 1 0 0 0 1 0 1\n4 0 1 2 3\n";

    /// The same quad, binary in the given byte order, with an extra vertex
    /// property and element that are read past.
    fn binary(big: bool) -> Vec<u8> {
        let order = if big { "big" } else { "little" };
        let mut out = format!(
            "ply\nformat binary_{order}_endian 1.0\nelement vertex 4\nproperty float x\n\
             property float y\nproperty float z\nproperty uchar red\nelement face 1\n\
             property list uchar uint vertex_indices\nelement edge 1\nproperty int a\n\
             property int b\nend_header\n"
        )
        .into_bytes();
        let f = |v: f32| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let u = |v: u32| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        for p in [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0f32],
        ] {
            for c in p {
                out.extend(f(c));
            }
            out.push(200);
        }
        out.push(4);
        for i in 0..4 {
            out.extend(u(i));
        }
        out.extend(u(7));
        out.extend(u(9));
        out
    }

    #[test]
    fn ascii_and_binary_read_the_same_quad() {
        let a = parse_ply(ASCII.as_bytes(), 10).unwrap();
        assert_eq!(a.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(a.positions[2], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(a.normals.as_ref().unwrap()[3], Vec3::Z);
        assert_eq!(a.uvs.as_ref().unwrap()[1], Vec2::new(1.0, 0.0));
        for big in [false, true] {
            let b = parse_ply(&binary(big), 10).unwrap();
            assert_eq!(b.positions, a.positions);
            assert_eq!(b.triangles, a.triangles);
            assert_eq!((b.normals, b.uvs), (None, None));
        }
    }

    #[test]
    fn lies_and_truncations_are_errors() {
        let whole = binary(false);
        for cut in [10, whole.len() - 30, whole.len() - 1] {
            assert!(parse_ply(&whole[..cut], 10).is_err(), "cut at {cut}");
        }
        let huge = String::from_utf8_lossy(&whole)
            .replace("element vertex 4", "element vertex 4000000000");
        let e = parse_ply(huge.as_bytes(), 10).unwrap_err();
        assert!(e.contains("more than the file holds"), "{e}");
        let e = parse_ply(ASCII.replace("4 0 1 2 3", "4 0 1 2 9").as_bytes(), 10).unwrap_err();
        assert!(e.contains("names vertex 9"), "{e}");
        let e = parse_ply(ASCII.as_bytes(), 1).unwrap_err();
        assert!(e.contains("more than 1 triangles"), "{e}");
        assert!(parse_ply(b"obj\n", 10).is_err());
        assert!(parse_ply(ASCII.replace("end_header", "end").as_bytes(), 10).is_err());
    }
}
