//! Stanford PLY meshes, ASCII and binary (either byte order): vertex
//! positions, normals and texture coordinates, faces as polygons (fans of
//! triangles), and the vertices' and faces' other properties as Mitsuba 3
//! groups them into attributes (`vertex_color`, `face_color`, ...). Other
//! elements are read past. Every count
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
    /// Per-vertex and per-face attributes, as Mitsuba 3 names them.
    pub attributes: Vec<Attribute>,
}

/// Properties of vertices or faces read as one attribute (Mitsuba's mesh
/// attributes, which its `mesh_attribute` texture reads).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Attribute {
    /// `vertex_...` or `face_...`.
    pub name: String,
    /// Its values' channels: 1 or 3 (or 4 for an `r g b a` colour, which
    /// Mitsuba reads but cannot evaluate).
    pub channels: usize,
    /// `channels` values per vertex, or per triangle for a face attribute
    /// (a polygon's repeated for each of its triangles).
    pub values: Vec<f32>,
    /// Whether the file stores it in integers: Mitsuba reads those as
    /// they are (a byte colour's 255 is 255), with a warning.
    pub integer: bool,
}

impl Attribute {
    pub fn per_face(&self) -> bool {
        self.name.starts_with("face_")
    }
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

/// Which of an element's scalar properties Mitsuba 3 reads as attributes,
/// and under what names (`kind` is `vertex_` or `face_`): `r g b [a]` (or
/// `red green blue [alpha]`) as `<kind>color`; other properties named
/// `<prefix>_<c>`, one or three in a row with one prefix and the suffixes
/// of one of x y z, r g b (then named `<kind><prefix>_color`), 0 1 2 or
/// 1 2 3, as `<kind><prefix>`. Anything else it ignores. Returns each
/// attribute's name, property indices and whether they are integers.
fn attribute_fields(
    kind: &str,
    properties: &[Property],
    reserved: &[&str],
) -> Vec<(String, Vec<usize>, bool)> {
    let scalar = |i: usize| match &properties[i] {
        Property::Scalar(n, t) => Some((n.as_str(), *t)),
        Property::List(..) => None,
    };
    let find =
        |name: &str| (0..properties.len()).find(|&i| scalar(i).is_some_and(|(n, _)| n == name));
    let integer = |t: Scalar| !matches!(t, Scalar::F32 | Scalar::F64);
    let mut out = Vec::new();
    let mut taken: Vec<&str> = reserved.to_vec();
    for names in [["r", "g", "b", "a"], ["red", "green", "blue", "alpha"]] {
        if let (Some(r), Some(g), Some(b)) = (find(names[0]), find(names[1]), find(names[2])) {
            let mut fields = vec![r, g, b];
            fields.extend(find(names[3]));
            let int = scalar(r).is_some_and(|(_, t)| integer(t));
            out.push((format!("{kind}color"), fields, int));
            taken.extend(names);
            break;
        }
    }
    taken.extend(["r", "g", "b", "a"]);
    const SUFFIXES: [&[u8; 4]; 4] = [b"xr01", b"yg12", b"zb23", b"wa34"];
    let mut seen: Vec<String> = Vec::new();
    // The attribute being read: its prefix, suffix family and fields.
    let mut current: Option<(String, usize, Vec<usize>)> = None;
    let flush = |current: &mut Option<(String, usize, Vec<usize>)>,
                 seen: &mut Vec<String>,
                 out: &mut Vec<(String, Vec<usize>, bool)>| {
        if let Some((prefix, family, fields)) = current.take() {
            if matches!(fields.len(), 1 | 3) {
                let last = fields[fields.len() - 1];
                let int = scalar(last).is_some_and(|(_, t)| integer(t));
                let color = if family == 1 { "_color" } else { "" };
                out.push((format!("{kind}{prefix}{color}"), fields, int));
            }
            seen.push(prefix);
        }
    };
    for i in 0..properties.len() {
        let Some((name, _)) = scalar(i) else { continue };
        if taken.contains(&name) {
            continue;
        }
        let split = name.rsplit_once('_').filter(|(_, s)| s.len() == 1);
        let Some((prefix, suffix)) = split else {
            flush(&mut current, &mut seen, &mut out);
            continue;
        };
        let c = suffix.as_bytes()[0];
        if current.as_ref().is_some_and(|(p, _, _)| p != prefix) {
            flush(&mut current, &mut seen, &mut out);
        }
        match &mut current {
            Some((_, family, fields)) => {
                let next = SUFFIXES.get(fields.len()).map(|s| s[*family]);
                if next == Some(c) {
                    fields.push(i);
                } else {
                    // An invalid sequence: the attribute is ignored.
                    fields.clear();
                }
            }
            None if seen.iter().any(|p| p == prefix) => {}
            None => {
                if let Some(family) = SUFFIXES[0].iter().position(|&s| s == c) {
                    current = Some((prefix.to_string(), family, vec![i]));
                }
            }
        }
    }
    flush(&mut current, &mut seen, &mut out);
    out
}

/// Attributes named by `fields`, with room for `count` items.
fn new_attributes(fields: &[(String, Vec<usize>, bool)], count: usize) -> Vec<Attribute> {
    fields
        .iter()
        .map(|(name, f, integer)| Attribute {
            name: name.clone(),
            channels: f.len(),
            values: Vec::with_capacity(count * f.len()),
            integer: *integer,
        })
        .collect()
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
    const RESERVED: [&str; 14] = [
        "x",
        "y",
        "z",
        "nx",
        "ny",
        "nz",
        "u",
        "v",
        "s",
        "t",
        "texture_u",
        "texture_v",
        "texture_s",
        "texture_t",
    ];
    let fields = attribute_fields("vertex_", &e.properties, &RESERVED);
    let mut attributes = new_attributes(&fields, e.count);
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
        for (a, (_, f, _)) in attributes.iter_mut().zip(&fields) {
            a.values.extend(f.iter().map(|&k| row[k] as f32));
        }
    }
    mesh.normals = has_normals.then_some(normals);
    mesh.uvs = has_uvs.then_some(uvs);
    mesh.attributes.extend(attributes);
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
    let fields = attribute_fields("face_", &e.properties, &[]);
    let mut attributes = new_attributes(&fields, e.count);
    let mut corners: Vec<u32> = Vec::new();
    let mut row = vec![0.0f64; e.properties.len()];
    for _ in 0..e.count {
        let first = mesh.triangles.len();
        for (k, p) in e.properties.iter().enumerate() {
            match p {
                Property::Scalar(_, t) => {
                    row[k] = v.next(*t)?;
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
        for (a, (_, f, _)) in attributes.iter_mut().zip(&fields) {
            for _ in first..mesh.triangles.len() {
                a.values.extend(f.iter().map(|&k| row[k] as f32));
            }
        }
    }
    mesh.attributes.extend(attributes);
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
    fn attributes_are_named_as_mitsuba_names_them() {
        // Header and values as Mitsuba 3.9.1 read them (through its Python
        // API): byte colours as they are, polygons' face values on each of
        // their triangles, and runs of one or three suffixed properties.
        let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
            property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
            property uchar blue\nproperty float rough_0\nproperty float quality\n\
            property float two_x\nproperty float two_y\nproperty float Col_r\n\
            property float Col_g\nproperty float Col_b\nelement face 2\n\
            property list uchar int vertex_indices\nproperty float q_x\nend_header\n\
            0 0 0 255 0 128 0.1 9 1 2 0.5 0.6 0.7\n1 0 0 0 64 0 0.2 9 1 2 0 0 0\n\
            1 1 0 1 2 3 0.3 9 1 2 1 1 1\n0 1 0 4 5 6 0.4 9 1 2 0 0 1\n\
            4 0 1 2 3 0.25\n3 0 1 2 0.75\n";
        let m = parse_ply(text.as_bytes(), 10).unwrap();
        let names: Vec<(&str, usize, bool)> = m
            .attributes
            .iter()
            .map(|a| (a.name.as_str(), a.channels, a.integer))
            .collect();
        assert_eq!(
            names,
            [
                ("vertex_color", 3, true),
                ("vertex_rough", 1, false),
                ("vertex_Col_color", 3, false),
                ("face_q", 1, false)
            ]
        );
        assert_eq!(
            m.attributes[0].values[..6],
            [255.0, 0.0, 128.0, 0.0, 64.0, 0.0]
        );
        assert_eq!(m.attributes[1].values, [0.1, 0.2, 0.3, 0.4]);
        assert_eq!(m.attributes[2].values[..3], [0.5, 0.6, 0.7]);
        assert_eq!(m.attributes[3].values, [0.25, 0.25, 0.75]);
        assert!(m.attributes[3].per_face() && !m.attributes[0].per_face());
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
