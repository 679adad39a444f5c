//! Wavefront OBJ and MTL, the parts a renderer of triangles and materials
//! needs. Every malformed line is an error naming its line; nothing in a
//! file can make the parser panic or allocate beyond the file's own size.

use glam::{Vec2, Vec3};

/// A material as the MTL file gives it; keys the renderer does not use are
/// kept out (`scene` turns these into a surface: docs/scenes.md).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MtlMaterial {
    pub name: String,
    /// `Kd`, diffuse reflectance.
    pub diffuse: Option<[f32; 3]>,
    /// `Ke`, emitted radiance.
    pub emission: Option<[f32; 3]>,
    /// `Ks`, specular reflectance (a conductor's reflectance).
    pub specular: Option<[f32; 3]>,
    /// `Tf`, transmission filter (glass's tint).
    pub transmission: Option<[f32; 3]>,
    /// `Pm`, metallic: 1 makes a conductor.
    pub metallic: Option<f32>,
    /// `Pr`, roughness.
    pub roughness: Option<f32>,
    /// `Ni`, index of refraction.
    pub ior: Option<f32>,
    /// `d` (or 1 − `Tr`), dissolve: 0 with `Ni` > 1 makes glass.
    pub dissolve: Option<f32>,
    /// Keys of the MTL's Phong model (`Ns`, `illum`) that were present.
    pub phong_keys: Vec<&'static str>,
    /// `map_Kd`: the image file of the diffuse reflectance, as written.
    pub diffuse_map: Option<String>,
}

/// The triangles of one `o` / `g` group of an OBJ file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjGroup {
    pub name: String,
    /// Index into the MTL materials, per triangle; None: no `usemtl` (or an
    /// unknown name).
    pub material: Vec<Option<usize>>,
    pub triangles: Vec<[Vec3; 3]>,
    /// Each triangle's corners: indices into the file's positions, and
    /// into its `vn` normals (NO_NORMAL where a corner has none).
    pub corners: Vec<[u32; 3]>,
    pub normal_corners: Vec<[u32; 3]>,
    /// Each corner's index into the `vt` texture coordinates (NO_NORMAL
    /// where it has none).
    pub uv_corners: Vec<[u32; 3]>,
}

/// A face corner without a `vn` normal.
pub const NO_NORMAL: u32 = u32::MAX;

/// What an OBJ file (with its MTL files) holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Obj {
    pub groups: Vec<ObjGroup>,
    /// The file's `vn` normals, as written.
    pub normals: Vec<Vec3>,
    /// The file's `vt` texture coordinates (u, v), as written.
    pub uvs: Vec<Vec2>,
    pub materials: Vec<MtlMaterial>,
    /// `usemtl` names no MTL defines (their faces get the default material).
    pub unknown_materials: Vec<String>,
}

/// Texture coordinates at each triangle's corners from the file's `vt`
/// (v turned over with `flip_v`), or barycentric where a face gives none.
pub fn corner_uvs(uvs: &[Vec2], corners: &[[u32; 3]], flip_v: bool) -> Vec<[Vec2; 3]> {
    corners
        .iter()
        .map(|c| {
            if c.iter().all(|&i| i != NO_NORMAL) {
                c.map(|i| {
                    let p = uvs[i as usize];
                    Vec2::new(p.x, if flip_v { 1.0 - p.y } else { p.y })
                })
            } else {
                [Vec2::ZERO, Vec2::X, Vec2::Y]
            }
        })
        .collect()
}

/// Where parsing stopped: the line (1-based) and why. The caller names the file.
#[derive(Clone, Debug, PartialEq)]
pub struct ParseError {
    /// The MTL file's name as `mtllib` gives it, or None for the OBJ itself.
    pub mtl: Option<String>,
    pub line: usize,
    pub message: String,
}

impl std::fmt::Display for ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.mtl {
            Some(m) => write!(f, "{m}, line {}: {}", self.line, self.message),
            None => write!(f, "line {}: {}", self.line, self.message),
        }
    }
}

fn number(word: Option<&str>, what: &str) -> Result<f32, String> {
    let w = word.ok_or_else(|| format!("{what}: a number is missing"))?;
    w.parse::<f32>()
        .map_err(|_| format!("{what}: '{w}' is not a number"))
}

/// `r [g b]`: one value stands for a grey (as the MTL format allows).
fn color<'a>(mut words: impl Iterator<Item = &'a str>, key: &str) -> Result<[f32; 3], String> {
    let first = words.next();
    if matches!(first, Some("spectral" | "xyz")) {
        return Err(format!("{key}: only RGB colours are supported"));
    }
    let r = number(first, key)?;
    match words.next() {
        None => Ok([r; 3]),
        g => Ok([r, number(g, key)?, number(words.next(), key)?]),
    }
}

/// Parses an MTL file's text.
pub fn parse_mtl(text: &str) -> Result<Vec<MtlMaterial>, (usize, String)> {
    let mut materials: Vec<MtlMaterial> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let fail = |m: String| (i + 1, m);
        match key {
            "newmtl" => {
                let name = words.collect::<Vec<_>>().join(" ");
                if name.is_empty() {
                    return Err(fail("newmtl without a name".into()));
                }
                materials.push(MtlMaterial {
                    name,
                    ..Default::default()
                });
            }
            "Kd" | "Ke" | "Ks" | "Tf" => {
                let c = color(words, key).map_err(fail)?;
                let Some(m) = materials.last_mut() else {
                    return Err(fail(format!("{key} before any newmtl")));
                };
                *match key {
                    "Kd" => &mut m.diffuse,
                    "Ke" => &mut m.emission,
                    "Ks" => &mut m.specular,
                    _ => &mut m.transmission,
                } = Some(c);
            }
            "Pm" | "Pr" | "Ni" | "d" | "Tr" | "Ns" | "illum" => {
                let v = number(words.next(), key).map_err(fail)?;
                let Some(m) = materials.last_mut() else {
                    return Err(fail(format!("{key} before any newmtl")));
                };
                match key {
                    "Pm" => m.metallic = Some(v),
                    "Pr" => m.roughness = Some(v),
                    "Ni" => m.ior = Some(v),
                    "d" => m.dissolve = Some(v),
                    "Tr" => m.dissolve = Some(1.0 - v),
                    "Ns" => m.phong_keys.push("Ns"),
                    _ => m.phong_keys.push("illum"),
                }
            }
            // Exporters write these; the renderer does not use them, but a
            // value that is there must still be well formed.
            "Ka" => {
                color(words, key).map_err(fail)?;
            }
            "Ps" | "Pc" | "Pcr" | "aniso" | "anisor" | "sharpness" => {
                number(words.next(), key).map_err(fail)?;
            }
            "map_Kd" => {
                let file = line.trim_start()[key.len()..].trim();
                if file.is_empty() {
                    return Err(fail("map_Kd names no file".into()));
                }
                if file.starts_with('-') {
                    return Err(fail(format!(
                        "map_Kd options ({}) are not supported; give the image file alone",
                        file.split_whitespace().next().unwrap_or("")
                    )));
                }
                let Some(m) = materials.last_mut() else {
                    return Err(fail("map_Kd before any newmtl".into()));
                };
                m.diffuse_map = Some(file.to_string());
            }
            // Other texture maps and anything else: not used.
            _ => {}
        }
    }
    Ok(materials)
}

/// An `f` corner's optional index (1-based, or negative from the end) into
/// `count` items defined so far, or NO_NORMAL where it has none.
fn optional_index(word: &str, part: Option<&str>, what: &str, count: usize) -> Result<u32, String> {
    match part.filter(|n| !n.is_empty()) {
        None => Ok(NO_NORMAL),
        Some(n) => {
            let k: i64 = n
                .parse()
                .map_err(|_| format!("face corner '{word}': '{n}' is not a {what} index"))?;
            let at = if k > 0 { k - 1 } else { count as i64 + k };
            if k == 0 || at < 0 || at >= count as i64 {
                return Err(format!(
                    "face corner '{word}' names {what} {k}, but {count} are defined so far"
                ));
            }
            Ok(at as u32)
        }
    }
}

/// One `f` corner: the position index (1-based, or negative from the end),
/// and the `vt` and `vn` indices after it, if any.
fn corner(
    word: &str,
    positions: usize,
    (uvs, normals): (usize, usize),
) -> Result<(usize, u32, u32), String> {
    let mut parts = word.split('/');
    let v = parts.next().unwrap_or("");
    let i: i64 = v
        .parse()
        .map_err(|_| format!("face corner '{word}' has no vertex index"))?;
    let index = if i > 0 { i - 1 } else { positions as i64 + i };
    if i == 0 || index < 0 || index >= positions as i64 {
        return Err(format!(
            "face corner '{word}' names vertex {i}, but {positions} are defined so far"
        ));
    }
    // A vt index that names none is left out, as before vt was read:
    // files that refer to texture coordinates they do not define exist.
    let uv = optional_index(word, parts.next(), "texture coordinate", uvs).unwrap_or(NO_NORMAL);
    let normal = optional_index(word, parts.next(), "normal", normals)?;
    Ok((index as usize, uv, normal))
}

/// Parses an OBJ file's text, refusing more than `max_triangles` triangles
/// before it holds them; `mtl` gives the text of an MTL file `mtllib` names
/// (or why it cannot).
pub fn parse_obj(
    text: &str,
    max_triangles: usize,
    mtl: &mut dyn FnMut(&str) -> Result<String, String>,
) -> Result<Obj, ParseError> {
    let mut obj = Obj::default();
    let mut positions: Vec<Vec3> = Vec::new();
    let mut current: Option<usize> = None;
    let mut triangles = 0usize;
    let mut group = ObjGroup {
        name: "unnamed".into(),
        ..Default::default()
    };
    let mut corners: Vec<(usize, u32, u32)> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fail = |message: String| ParseError {
            mtl: None,
            line: i + 1,
            message,
        };
        let line = line.split('#').next().unwrap_or("");
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        match key {
            "v" => {
                let mut p = [0.0f32; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    *c = number(words.next(), &format!("vertex coordinate {}", k + 1))
                        .map_err(fail)?;
                }
                positions.push(Vec3::from(p));
            }
            "vn" => {
                let mut n = [0.0f32; 3];
                for (k, c) in n.iter_mut().enumerate() {
                    *c = number(words.next(), &format!("normal coordinate {}", k + 1))
                        .map_err(fail)?;
                }
                obj.normals.push(Vec3::from(n));
            }
            "vt" => {
                let u = number(words.next(), "texture coordinate u").map_err(fail)?;
                // v may be left out (a 1D texture): 0.
                let v = match words.next() {
                    Some(w) => number(Some(w), "texture coordinate v").map_err(fail)?,
                    None => 0.0,
                };
                obj.uvs.push(Vec2::new(u, v));
            }
            "f" => {
                corners.clear();
                for w in words {
                    corners.push(
                        corner(w, positions.len(), (obj.uvs.len(), obj.normals.len()))
                            .map_err(fail)?,
                    );
                }
                if corners.len() < 3 {
                    return Err(fail(format!(
                        "a face needs at least 3 corners, this one has {}",
                        corners.len()
                    )));
                }
                triangles += corners.len() - 2;
                if triangles > max_triangles {
                    return Err(fail(format!(
                        "more than {max_triangles} triangles, the most a scene may have"
                    )));
                }
                // A fan, as every OBJ reader triangulates a convex polygon.
                for k in 1..corners.len() - 1 {
                    let c = [corners[0], corners[k], corners[k + 1]];
                    group.triangles.push(c.map(|(p, _, _)| positions[p]));
                    group.corners.push(c.map(|(p, _, _)| p as u32));
                    group.uv_corners.push(c.map(|(_, t, _)| t));
                    group.normal_corners.push(c.map(|(_, _, n)| n));
                    group.material.push(current);
                }
            }
            "o" | "g" => {
                let name = words.collect::<Vec<_>>().join(" ");
                let name = if name.is_empty() {
                    "unnamed".into()
                } else {
                    name
                };
                let done = std::mem::replace(
                    &mut group,
                    ObjGroup {
                        name,
                        ..Default::default()
                    },
                );
                if !done.triangles.is_empty() {
                    obj.groups.push(done);
                }
            }
            "usemtl" => {
                let name = words.collect::<Vec<_>>().join(" ");
                current = obj.materials.iter().position(|m| m.name == name);
                if current.is_none() && !obj.unknown_materials.contains(&name) {
                    obj.unknown_materials.push(name);
                }
            }
            "mtllib" => {
                for file in words {
                    let text = mtl(file).map_err(fail)?;
                    let parsed = parse_mtl(&text).map_err(|(line, message)| ParseError {
                        mtl: Some(file.to_string()),
                        line,
                        message,
                    })?;
                    obj.materials.extend(parsed);
                }
            }
            // Smoothing groups, lines, points, curves: nothing the
            // renderer uses.
            _ => {}
        }
    }
    if !group.triangles.is_empty() {
        obj.groups.push(group);
    }
    Ok(obj)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn no_mtl(name: &str) -> Result<String, String> {
        Err(format!("{name} not found"))
    }

    #[test]
    fn faces_are_fans_with_relative_and_slashed_indices() {
        let text =
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\no quad\nf 1/1/1 2//2 3/3 -1\n";
        let obj = parse_obj(text, 100, &mut no_mtl).unwrap();
        assert_eq!(obj.groups.len(), 1);
        let g = &obj.groups[0];
        assert_eq!(g.name, "quad");
        assert_eq!(g.triangles.len(), 2);
        assert_eq!(
            g.triangles[1],
            [Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::Y]
        );
        assert_eq!(g.material, vec![None, None]);
        assert_eq!(g.corners, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(
            g.normal_corners,
            vec![[0, 1, NO_NORMAL], [0, NO_NORMAL, NO_NORMAL]]
        );
    }

    #[test]
    fn normals_come_from_vn_by_corner() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 1 0\nf 1//1 2//2 3/7/-1\nf 1 2 3\n";
        let obj = parse_obj(text, 100, &mut no_mtl).unwrap();
        assert_eq!(obj.normals, vec![Vec3::Z, Vec3::Y]);
        assert_eq!(
            obj.groups[0].normal_corners,
            vec![[0, 1, 1], [NO_NORMAL; 3]]
        );
        let e = parse_obj("v 0 0 0\nf 1//1 1 1\n", 100, &mut no_mtl).unwrap_err();
        assert!(e.to_string().contains("names normal 1"), "{e}");
    }

    #[test]
    fn materials_come_from_mtllib_by_name() {
        let text =
            "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl lamp\nf 1 2 3\nusemtl nope\nf 1 2 3\n";
        let obj = parse_obj(text, 100, &mut |name| {
            assert_eq!(name, "a.mtl");
            Ok("newmtl wall\nKd 0.5\nnewmtl lamp\nKd 0.1 0.2 0.3\nKe 4 4 4\nmap_Kd x.png\n".into())
        })
        .unwrap();
        assert_eq!(obj.materials[0].diffuse, Some([0.5; 3]));
        assert_eq!(obj.materials[1].emission, Some([4.0; 3]));
        assert_eq!(obj.groups[0].material, vec![Some(1), None]);
        assert_eq!(obj.unknown_materials, vec!["nope".to_string()]);
    }

    /// Each of these once panicked or must name its line.
    #[test]
    fn malformed_lines_name_their_line() {
        let cases: &[(&str, &str, &str)] = &[
            (
                "v 1 x 2\n",
                "",
                "line 1: vertex coordinate 2: 'x' is not a number",
            ),
            (
                "v 1 2\n",
                "",
                "line 1: vertex coordinate 3: a number is missing",
            ),
            (
                "v 0 0 0\nf 1 2 3\n",
                "",
                "line 2: face corner '2' names vertex 2",
            ),
            ("v 0 0 0\nf 1 1\n", "", "at least 3 corners"),
            ("v 0 0 0\nf 0 1 1\n", "", "names vertex 0"),
            ("v 0 0 0\nf -5 1 1\n", "", "names vertex -5"),
            ("v 0 0 0\nf /1 1 1\n", "", "no vertex index"),
            (
                "mtllib m.mtl\n",
                "newmtl a\nKd 0.78 0.\n",
                "m.mtl, line 2: Kd: a number is missing",
            ),
            (
                "mtllib m.mtl\n",
                "Kd 1 1 1\n",
                "m.mtl, line 1: Kd before any newmtl",
            ),
            ("mtllib m.mtl\n", "newmtl\n", "newmtl without a name"),
            (
                "mtllib m.mtl\n",
                "newmtl a\nNs\n",
                "Ns: a number is missing",
            ),
            (
                "mtllib m.mtl\n",
                "newmtl a\nKs spectral x.spd\n",
                "only RGB",
            ),
        ];
        for (obj, mtl, want) in cases {
            let e = parse_obj(obj, 100, &mut |_| Ok(mtl.to_string())).unwrap_err();
            assert!(e.to_string().contains(want), "{obj:?} {mtl:?}: {e}");
        }
        let e = parse_obj("mtllib gone.mtl\n", 100, &mut no_mtl).unwrap_err();
        assert_eq!(e.to_string(), "line 1: gone.mtl not found");
        let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
        let e = parse_obj(quad, 1, &mut no_mtl).unwrap_err();
        assert!(e.to_string().contains("more than 1 triangles"), "{e}");
    }
}
