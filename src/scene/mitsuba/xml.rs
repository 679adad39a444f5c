//! Reading a Mitsuba 3 XML document: `<include>` spliced in, `<default>`
//! parameters and `-D` definitions substituted for `$name`, every element
//! remembering its file and line; then typed access to a plugin's
//! properties that notices the ones nobody read.

use super::super::{Loader, SceneError};
use glam::{Mat4, Vec3};
use std::cell::Cell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Deepest chain of `<include>`s followed (a cycle would never end).
const MAX_INCLUDE_DEPTH: usize = 16;

/// One element of the document, its attributes already substituted.
#[derive(Clone, Debug)]
pub struct Element {
    pub tag: String,
    pub attrs: Vec<(String, String)>,
    pub children: Vec<Element>,
    pub file: Rc<PathBuf>,
    pub line: u32,
    /// Where the scene's files are looked for (see [`Element::read_file`]).
    pub search: Search,
}

/// The directories a scene's relative file names are looked up in, as
/// Mitsuba's file resolver does: each `<path>`'s, the latest first, then the
/// main scene file's. Shared by every element, as Mitsuba resolves names
/// once the whole document is read.
pub type Search = Rc<std::cell::RefCell<Vec<PathBuf>>>;

/// An error at an element: "file:line: message", on one line whatever
/// the file's text put into the message.
pub fn at(file: &Path, line: u32, message: impl Into<String>) -> SceneError {
    let message: String = message
        .into()
        .chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect();
    SceneError::At {
        path: file.to_path_buf(),
        line: line as usize,
        message,
    }
}

impl Element {
    pub fn attr(&self, name: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    /// An error naming this element's file and line.
    pub fn error(&self, message: impl Into<String>) -> SceneError {
        at(&self.file, self.line, message)
    }

    pub fn required(&self, name: &str) -> Result<&str, SceneError> {
        self.attr(name)
            .ok_or_else(|| self.error(format!("<{}> needs the attribute '{name}'", self.tag)))
    }

    /// The plugin's `type`, for messages and dispatch.
    pub fn plugin(&self) -> Result<&str, SceneError> {
        self.required("type")
    }

    /// The file a property of this element names, and its bytes (see
    /// [`find_file`]).
    pub fn read_file(
        &self,
        loader: &Loader<'_>,
        name: &str,
    ) -> std::io::Result<(PathBuf, Vec<u8>)> {
        find_file(&self.search, &self.file, loader, name)
    }
}

/// File `name`, named in `file`, and its bytes: an absolute name as it is,
/// a relative one from the first of `search`'s directories that has it,
/// else beside `file` (an included file's neighbours, which Mitsuba would
/// not find).
fn find_file(
    search: &Search,
    file: &Path,
    loader: &Loader<'_>,
    name: &str,
) -> std::io::Result<(PathBuf, Vec<u8>)> {
    let own = file.parent().unwrap_or(Path::new(".")).join(name);
    let mut candidates: Vec<PathBuf> = search.borrow().iter().map(|d| d.join(name)).collect();
    if Path::new(name).is_absolute() {
        candidates.clear();
    }
    candidates.push(own);
    candidates.dedup();
    let mut first = None;
    for path in candidates {
        match (loader.read)(&path) {
            Ok(bytes) => return Ok((path, bytes)),
            Err(e) => {
                first.get_or_insert(e);
            }
        }
    }
    Err(first.expect("one candidate at least"))
}

/// The `<scene>` of `path` as a list of top-level elements, includes
/// spliced in, `defines` (the command line's `-D`) taking precedence over
/// the document's `<default>`s.
pub fn read_scene(
    path: &Path,
    loader: &Loader<'_>,
    defines: &[(String, String)],
) -> Result<Vec<Element>, SceneError> {
    let mut params: HashMap<String, String> = defines.iter().cloned().collect();
    let fixed: Vec<String> = defines.iter().map(|(k, _)| k.clone()).collect();
    let search: Search = Rc::new(std::cell::RefCell::new(vec![path
        .parent()
        .unwrap_or(Path::new("."))
        .to_path_buf()]));
    let mut reader = Reader {
        loader,
        params: &mut params,
        fixed: &fixed,
        search: search.clone(),
    };
    let mut top = reader.document(path, 0)?;
    // Mitsuba's <alias id as>: the object under a second id.
    let mut i = 0;
    while i < top.len() {
        if top[i].tag == "alias" {
            let a = top.remove(i);
            let (id, name) = (a.required("id")?, a.required("as")?);
            let Some(target) = top.iter().find(|e| e.attr("id") == Some(id)) else {
                return Err(a.error(format!("<alias>: no object has the id '{id}'")));
            };
            let mut copy = target.clone();
            copy.attrs.retain(|(k, _)| k != "id");
            copy.attrs.push(("id".into(), name.into()));
            top.insert(i, copy);
        }
        i += 1;
    }
    // A top-level spectrum plugin that is one colour (see `plain_spectrum`)
    // stands wherever a `<ref>` names it, and a top-level BSDF wherever one
    // names it inside another BSDF (twosided, mask, blendbsdf, a normal or
    // bump map), as Mitsuba allows.
    let (constants, mut top): (Vec<Element>, Vec<Element>) = top
        .drain(..)
        .partition(|e| matches!(e.tag.as_str(), "rgb" | "spectrum") && e.attr("id").is_some());
    if !constants.is_empty() {
        top.iter_mut().for_each(|e| inline_constants(e, &constants));
    }
    let bsdfs: Vec<Element> = top
        .iter()
        .filter(|e| e.tag == "bsdf" && e.attr("id").is_some())
        .cloned()
        .collect();
    if !bsdfs.is_empty() {
        top.iter_mut().for_each(|e| inline_bsdfs(e, &bsdfs, 0));
    }
    Ok(top)
}

/// Each `<ref id>` inside a BSDF under `el` that names one of `bsdfs`,
/// replaced by a copy of that BSDF (itself so treated, to a depth that a
/// cycle of references cannot pass). A shape's own `<ref>` stays: the
/// shapes that name one BSDF share it.
fn inline_bsdfs(el: &mut Element, bsdfs: &[Element], depth: usize) {
    if depth > MAX_INCLUDE_DEPTH {
        return;
    }
    let inside = el.tag == "bsdf";
    for c in &mut el.children {
        if c.tag == "ref" && inside {
            let Some(b) = bsdfs.iter().find(|b| b.attr("id") == c.attr("id")) else {
                continue;
            };
            *c = stand_in(b, c);
            inline_bsdfs(c, bsdfs, depth + 1);
        } else {
            inline_bsdfs(c, bsdfs, depth + 1);
        }
    }
}

/// Each `<ref name id>` under `el` that names one of `constants`, replaced
/// by that colour under the ref's name.
fn inline_constants(el: &mut Element, constants: &[Element]) {
    for c in &mut el.children {
        if c.tag == "ref" {
            let Some(k) = constants.iter().find(|k| k.attr("id") == c.attr("id")) else {
                continue;
            };
            *c = stand_in(k, c);
        } else {
            inline_constants(c, constants);
        }
    }
}

/// A copy of `target` to stand where `reference` (a `<ref>`) named it:
/// under the reference's name, without the target's id.
fn stand_in(target: &Element, reference: &Element) -> Element {
    let mut copy = target.clone();
    copy.attrs.retain(|(k, _)| k != "id" && k != "name");
    copy.attrs
        .extend(reference.attrs.iter().filter(|(k, _)| k == "name").cloned());
    copy
}

struct Reader<'a, 'l> {
    loader: &'a Loader<'l>,
    params: &'a mut HashMap<String, String>,
    /// Names set on the command line, which `<default>` does not change.
    fixed: &'a [String],
    search: Search,
}

impl Reader<'_, '_> {
    fn document(&mut self, path: &Path, depth: usize) -> Result<Vec<Element>, SceneError> {
        let text = self.loader.text(path).map_err(|source| SceneError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let doc = roxmltree::Document::parse(&text).map_err(|e| {
            let pos = e.pos();
            at(path, pos.row, format!("malformed XML: {e}"))
        })?;
        let file = Rc::new(path.to_path_buf());
        let root = doc.root_element();
        let line = |n: roxmltree::Node| doc.text_pos_at(n.range().start).row;
        if root.tag_name().name() != "scene" {
            return Err(at(
                path,
                line(root),
                format!(
                    "the root element is <{}>, not <scene>",
                    root.tag_name().name()
                ),
            ));
        }
        // Mitsuba 0.x scenes (camelCase names) are upgraded as Mitsuba 3
        // upgrades them when it loads one.
        let old = match root.attribute("version") {
            None => {
                return Err(at(path, line(root), "<scene> needs a version (3.0.0)"));
            }
            Some(v) => match v
                .split('.')
                .next()
                .and_then(|m| m.trim().parse::<u32>().ok())
            {
                Some(0 | 1) => true,
                Some(2 | 3) => false,
                _ => {
                    return Err(at(
                        path,
                        line(root),
                        format!("scene version {v}: qtrace reads Mitsuba's formats 0.x to 3.x"),
                    ))
                }
            },
        };
        let mut out = Vec::new();
        for node in root.children().filter(|n| n.is_element()) {
            let ln = line(node);
            match node.tag_name().name() {
                "default" => {
                    let name = node.attribute("name");
                    let value = node.attribute("value");
                    let (Some(name), Some(value)) = (name, value) else {
                        return Err(at(path, ln, "<default> needs 'name' and 'value'"));
                    };
                    if !self.fixed.iter().any(|f| f == name) {
                        let value = self.substitute(path, ln, value)?;
                        self.params.insert(name.to_string(), value);
                    }
                }
                "include" => {
                    let name = node
                        .attribute("filename")
                        .ok_or_else(|| at(path, ln, "<include> needs a 'filename'"))?;
                    let name = self.substitute(path, ln, name)?;
                    if depth + 1 >= MAX_INCLUDE_DEPTH {
                        return Err(at(
                            path,
                            ln,
                            format!("includes nest deeper than {MAX_INCLUDE_DEPTH} (a cycle?)"),
                        ));
                    }
                    let included = self.locate(path, &name);
                    out.extend(self.document(&included, depth + 1).map_err(|e| match e {
                        SceneError::Read { source, .. } => at(
                            path,
                            ln,
                            format!("cannot read <include> file '{name}': {source}"),
                        ),
                        e => e,
                    })?);
                }
                // Mitsuba's <path>: a directory to look for files in first,
                // relative to this file's.
                "path" => {
                    let value = node
                        .attribute("value")
                        .ok_or_else(|| at(path, ln, "<path> needs a 'value'"))?;
                    let value = self.substitute(path, ln, value)?;
                    let dir = path.parent().unwrap_or(Path::new(".")).join(value);
                    self.search.borrow_mut().insert(0, dir);
                }
                _ => {
                    let mut el = self.element(&doc, node, &file)?;
                    if old {
                        upgrade(&mut el);
                    }
                    out.push(el);
                }
            }
        }
        Ok(out)
    }

    /// Where file `name`, named in `file`, is found (see [`find_file`]);
    /// where it is not, beside `file`, for the reader's message.
    fn locate(&self, file: &Path, name: &str) -> PathBuf {
        find_file(&self.search, file, self.loader, name).map_or_else(
            |_| file.parent().unwrap_or(Path::new(".")).join(name),
            |(path, _)| path,
        )
    }

    /// Spectrum file `name` (named in `file` at `line`) as
    /// `wavelength:value` pairs.
    fn spectrum_file(&self, file: &Path, line: u32, name: &str) -> Result<String, SceneError> {
        let path = self.locate(file, name);
        let text = self.loader.text(&path).map_err(|e| {
            at(
                file,
                line,
                format!("cannot read the spectrum '{name}': {e}"),
            )
        })?;
        let mut pairs = Vec::new();
        for (i, l) in text.lines().enumerate() {
            let l = l.split('#').next().unwrap_or("").trim();
            if l.is_empty() {
                continue;
            }
            let words: Vec<&str> = l.split_whitespace().collect();
            let [w, v] = words[..] else {
                return Err(at(
                    file,
                    line,
                    format!(
                        "the spectrum '{name}', line {}: '{l}' is not a wavelength and a value",
                        i + 1
                    ),
                ));
            };
            pairs.push(format!("{w}:{v}"));
        }
        Ok(pairs.join(", "))
    }

    fn element(
        &self,
        doc: &roxmltree::Document,
        node: roxmltree::Node,
        file: &Rc<PathBuf>,
    ) -> Result<Element, SceneError> {
        let line = doc.text_pos_at(node.range().start).row;
        let mut attrs = Vec::new();
        for a in node.attributes() {
            attrs.push((
                a.name().to_string(),
                self.substitute(file, line, a.value())?,
            ));
        }
        // Mitsuba's spectrum file (lines of wavelength and value, `#`
        // comments), read here into the pairs a `value` gives.
        if node.tag_name().name() == "spectrum" {
            if let Some(k) = attrs.iter().position(|(n, _)| n == "filename") {
                let (_, name) = attrs.remove(k);
                let pairs = self.spectrum_file(file, line, &name)?;
                attrs.push(("value".into(), pairs));
            }
        }
        let mut children = Vec::new();
        for c in node.children().filter(|n| n.is_element()) {
            children.push(self.element(doc, c, file)?);
        }
        let el = Element {
            tag: node.tag_name().name().to_string(),
            attrs,
            children,
            file: file.clone(),
            line,
            search: self.search.clone(),
        };
        plain_spectrum(el)
    }

    /// `value` with each `$name` replaced by its parameter's value.
    fn substitute(&self, file: &Path, line: u32, value: &str) -> Result<String, SceneError> {
        if !value.contains('$') {
            return Ok(value.to_string());
        }
        let mut out = String::with_capacity(value.len());
        let mut rest = value;
        while let Some(i) = rest.find('$') {
            out.push_str(&rest[..i]);
            let tail = &rest[i + 1..];
            let len = tail
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(tail.len());
            let name = &tail[..len];
            match self.params.get(name) {
                Some(v) if !name.is_empty() => out.push_str(v),
                _ => {
                    return Err(at(
                        file,
                        line,
                        format!(
                            "${name} is not defined (give it a <default name=\"{name}\" value=...> or -D {name}=...)"
                        ),
                    ))
                }
            }
            rest = &tail[len..];
        }
        out.push_str(rest);
        Ok(out)
    }
}

/// A Mitsuba 0.x element as Mitsuba 3 upgrades it: property names from
/// camelCase to snake_case (`toWorld` to `to_world`, `intIOR` to
/// `int_ior`), `<lookAt>` to `<lookat>`, ids that begin with `_` renamed,
/// a diffuse BSDF's `diffuse_reflectance` to `reflectance`, and a
/// texture's `uoffset`, `voffset`, `uscale`, `vscale` to its `to_uv`.
fn upgrade(el: &mut Element) {
    if let Some(name) = el.attrs.iter_mut().find(|(k, _)| k == "name") {
        name.1 = snake_case(&name.1);
    }
    if let Some(id) = el.attrs.iter_mut().find(|(k, _)| k == "id") {
        if id.1.starts_with('_') {
            id.1 = format!("ID{}__UPGR", id.1);
        }
    }
    if el.tag == "lookAt" {
        el.tag = "lookat".into();
    }
    el.children.iter_mut().for_each(upgrade);
    if el.tag == "bsdf" && el.attr("type") == Some("diffuse") {
        for c in &mut el.children {
            if let Some(name) = c
                .attrs
                .iter_mut()
                .find(|(k, v)| k == "name" && v == "diffuse_reflectance")
            {
                name.1 = "reflectance".into();
            }
        }
    }
    let uv = ["uoffset", "voffset", "uscale", "vscale"];
    let value = |el: &Element, name: &str| {
        el.children
            .iter()
            .find(|c| c.tag == "float" && c.attr("name") == Some(name))
            .and_then(|c| c.attr("value"))
            .map(str::to_string)
    };
    let [uo, vo, us, vs] = uv.map(|n| value(el, n));
    if uo.is_some() || vo.is_some() || us.is_some() || vs.is_some() {
        el.children
            .retain(|c| !(c.tag == "float" && c.attr("name").is_some_and(|n| uv.contains(&n))));
        let op = |tag: &str, x: Option<String>, y: Option<String>, default: &str| Element {
            tag: tag.into(),
            attrs: vec![
                ("x".into(), x.unwrap_or_else(|| default.into())),
                ("y".into(), y.unwrap_or_else(|| default.into())),
            ],
            children: Vec::new(),
            file: el.file.clone(),
            line: el.line,
            search: el.search.clone(),
        };
        // As Mitsuba writes it: the translation first, then the scale.
        let mut ops = Vec::new();
        if uo.is_some() || vo.is_some() {
            ops.push(op("translate", uo, vo, "0"));
        }
        if us.is_some() || vs.is_some() {
            ops.push(op("scale", us, vs, "1"));
        }
        el.children.push(Element {
            tag: "transform".into(),
            attrs: vec![("name".into(), "to_uv".into())],
            children: ops,
            file: el.file.clone(),
            line: el.line,
            search: el.search.clone(),
        });
    }
}

/// `camelCase` as Mitsuba 3's upgrade writes it: an underscore before each
/// run of capitals that follows a small letter, the run lowered.
fn snake_case(name: &str) -> String {
    let mut s: Vec<u8> = name.as_bytes().to_vec();
    let mut i = 0;
    while i + 1 < s.len() {
        if s[i].is_ascii_lowercase() && s[i + 1].is_ascii_uppercase() {
            s.insert(i + 1, b'_');
            i += 2;
            while i < s.len() && s[i].is_ascii_uppercase() {
                s[i] = s[i].to_ascii_lowercase();
                i += 1;
            }
            continue;
        }
        i += 1;
    }
    String::from_utf8(s).unwrap_or_else(|_| name.to_string())
}

/// A spectrum plugin (`<spectrum type=...>`, or the same as a `<texture>`)
/// that is one constant colour in Mitsuba's RGB variants, as the `<rgb>` or
/// `<spectrum value=...>` it amounts to, so that every reader of a colour
/// takes it; other elements as they are. `irregular`, `regular` and
/// `blackbody`, which Mitsuba's RGB variants load but cannot evaluate, become
/// their wavelength:value pairs, turned into RGB as Mitsuba turns such pairs.
fn plain_spectrum(el: Element) -> Result<Element, SceneError> {
    if !matches!(el.tag.as_str(), "spectrum" | "texture") {
        return Ok(el);
    }
    let Some(kind) = el.attr("type") else {
        return Ok(el);
    };
    if !matches!(
        kind,
        "uniform" | "d65" | "srgb" | "irregular" | "regular" | "blackbody"
    ) {
        return Ok(el);
    }
    let what = plugin_name(&el);
    let mut used = vec![false; el.children.len()];
    // The child property `name` of one of `tags`, its `value`.
    let mut take = |name: &str, tags: &[&str]| -> Result<Option<(usize, &str)>, SceneError> {
        let Some(i) = el
            .children
            .iter()
            .position(|c| c.attr("name") == Some(name))
        else {
            return Ok(None);
        };
        let c = &el.children[i];
        if !tags.contains(&c.tag.as_str()) {
            return Err(c.error(format!(
                "{what}: '{name}' must be <{}>",
                tags.join("> or <")
            )));
        }
        used[i] = true;
        c.required("value").map(|v| Some((i, v)))
    };
    let number = |i: usize, v: &str| -> Result<f32, SceneError> {
        let c = &el.children[i];
        match numbers(c, v)?[..] {
            [x] => Ok(x),
            _ => Err(c.error(format!("{what}: '{v}' is not one number"))),
        }
    };
    let list = |i: usize, v: &str| numbers(&el.children[i], v);
    let missing = |name: &str| el.error(format!("{what} needs the property '{name}'"));
    let (tag, value) = match kind {
        "uniform" => {
            let (i, v) = take("value", &["float", "integer"])?.ok_or_else(|| missing("value"))?;
            ("rgb", number(i, v)?.to_string())
        }
        "d65" | "srgb" => {
            let color = match take("color", &["rgb"])? {
                Some((i, v)) => match list(i, v)?[..] {
                    [x] => Vec3::splat(x),
                    [r, g, b] => Vec3::new(r, g, b),
                    _ => {
                        return Err(
                            el.children[i].error(format!("{what}: 'color' needs three numbers"))
                        )
                    }
                },
                None if kind == "d65" => Vec3::ONE,
                None => return Err(missing("color")),
            };
            let scale = match take("scale", &["float", "integer"])? {
                Some((i, v)) if kind == "d65" => number(i, v)?,
                _ => 1.0,
            };
            if kind == "srgb" {
                let unbounded = match take("unbounded", &["boolean"])? {
                    Some((_, v)) => v.trim().eq_ignore_ascii_case("true"),
                    None => false,
                };
                if !unbounded && (color.min_element() < 0.0 || color.max_element() > 1.0) {
                    return Err(el.error(format!(
                        "{what}: the color {color} lies outside [0, 1] (Mitsuba refuses it too; set 'unbounded' to true)"
                    )));
                }
            }
            let c = color * scale;
            ("rgb", format!("{}, {}, {}", c.x, c.y, c.z))
        }
        "irregular" => {
            let (i, w) = take("wavelengths", &["string"])?.ok_or_else(|| missing("wavelengths"))?;
            let (j, v) = take("values", &["string"])?.ok_or_else(|| missing("values"))?;
            let (w, v) = (list(i, w)?, list(j, v)?);
            if w.len() != v.len() {
                return Err(el.error(format!(
                    "{what} has {} wavelengths and {} values",
                    w.len(),
                    v.len()
                )));
            }
            ("spectrum", pairs(w.into_iter().zip(v)))
        }
        "regular" => {
            let (i, lo) = take("wavelength_min", &["float", "integer"])?
                .ok_or_else(|| missing("wavelength_min"))?;
            let (j, hi) = take("wavelength_max", &["float", "integer"])?
                .ok_or_else(|| missing("wavelength_max"))?;
            let (k, v) = take("values", &["string"])?.ok_or_else(|| missing("values"))?;
            let (lo, hi, v) = (number(i, lo)?, number(j, hi)?, list(k, v)?);
            if v.len() < 2 || hi <= lo {
                return Err(el.error(format!(
                    "{what} needs two values or more over wavelength_min < wavelength_max"
                )));
            }
            let step = (hi - lo) / (v.len() - 1) as f32;
            (
                "spectrum",
                pairs(
                    v.into_iter()
                        .enumerate()
                        .map(|(n, y)| (lo + n as f32 * step, y)),
                ),
            )
        }
        _ => {
            let (i, t) = take("temperature", &["float", "integer"])?
                .ok_or_else(|| missing("temperature"))?;
            let t = number(i, t)?;
            if t <= 0.0 {
                return Err(el.error(format!("{what}: the temperature must be positive, not {t}")));
            }
            let (lo, hi) = (super::cie::FIRST_NM as u32, super::cie::LAST_NM as u32);
            (
                "spectrum",
                pairs((lo..=hi).map(|nm| (nm as f32, blackbody(nm as f64, t as f64) as f32))),
            )
        }
    };
    if let Some(i) = used.iter().position(|u| !u) {
        let c = &el.children[i];
        return Err(c.error(format!(
            "{what} has {}, which qtrace does not support",
            c.attr("name")
                .map_or_else(|| format!("<{}>", c.tag), |n| format!("'{n}'"))
        )));
    }
    let mut attrs: Vec<(String, String)> = el
        .attrs
        .iter()
        .filter(|(k, _)| k != "type")
        .cloned()
        .collect();
    attrs.push(("value".into(), value));
    Ok(Element {
        tag: tag.into(),
        attrs,
        children: Vec::new(),
        file: el.file,
        line: el.line,
        search: el.search,
    })
}

/// `wavelength:value, ...`
fn pairs(points: impl Iterator<Item = (f32, f32)>) -> String {
    points
        .map(|(w, v)| format!("{w}:{v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Planck's law at `nm` nanometres and `kelvin`, in W m⁻² sr⁻¹ nm⁻¹, with
/// Mitsuba 3's constants.
fn blackbody(nm: f64, kelvin: f64) -> f64 {
    let (c, h, k) = (2.997_924_58e8, 6.626_070_04e-34, 1.380_648_52e-23);
    let l = nm * 1e-9;
    let p1 = 2.0 * h * c * c / l.powi(5);
    let p2 = ((h * c) / (k * l * kelvin)).exp() - 1.0;
    p1 / p2 * 1e-9
}

/// Property tags, as opposed to nested plugins.
const PROPERTY_TAGS: &[&str] = &[
    "integer",
    "float",
    "boolean",
    "string",
    "rgb",
    "spectrum",
    "point",
    "vector",
    "transform",
];

/// A plugin's properties (its children with a `name`), read by type; each
/// read marks the property used, and [`Props::finish`] rejects the rest.
pub struct Props<'e> {
    pub el: &'e Element,
    used: Vec<Cell<bool>>,
}

impl<'e> Props<'e> {
    pub fn new(el: &'e Element) -> Self {
        Self {
            el,
            used: el.children.iter().map(|_| Cell::new(false)).collect(),
        }
    }

    /// The property element called `name`, marked used.
    fn find(&self, name: &str) -> Option<&'e Element> {
        let i = self.el.children.iter().position(|c| {
            PROPERTY_TAGS.contains(&c.tag.as_str()) && c.attr("name") == Some(name)
        })?;
        self.used[i].set(true);
        Some(&self.el.children[i])
    }

    /// Nested plugins of tag `tag` (bsdf, emitter, ...), marked used.
    pub fn nested(&self, tag: &str) -> Vec<&'e Element> {
        let mut out = Vec::new();
        for (i, c) in self.el.children.iter().enumerate() {
            if c.tag == tag {
                self.used[i].set(true);
                out.push(c);
            }
        }
        out
    }

    /// Parameters given as textures: nested `<texture name>` and
    /// `<ref name id>`, marked used.
    pub fn textures(&self) -> Vec<&'e Element> {
        let mut out = Vec::new();
        for (i, c) in self.el.children.iter().enumerate() {
            if (c.tag == "texture" || c.tag == "ref") && c.attr("name").is_some() {
                self.used[i].set(true);
                out.push(c);
            }
        }
        out
    }

    /// Marks `name` used without reading it: a property that does not
    /// change the image (an output format, say).
    pub fn ignore(&self, name: &str) {
        self.find(name);
    }

    fn number(&self, el: &Element, text: &str) -> Result<f32, SceneError> {
        parse_f32(text).ok_or_else(|| {
            el.error(format!(
                "'{text}' is not a number (property '{}')",
                el.attr("name").unwrap_or("")
            ))
        })
    }

    fn typed(&self, name: &str, tags: &[&str]) -> Result<Option<&'e Element>, SceneError> {
        let Some(el) = self.find(name) else {
            return Ok(None);
        };
        if !tags.contains(&el.tag.as_str()) {
            return Err(el.error(format!(
                "'{name}' is a <{}>; {} expects <{}>",
                el.tag,
                plugin_name(self.el),
                tags.join("> or <")
            )));
        }
        Ok(Some(el))
    }

    pub fn float(&self, name: &str) -> Result<Option<f32>, SceneError> {
        let Some(el) = self.typed(name, &["float", "integer"])? else {
            return Ok(None);
        };
        self.number(el, el.required("value")?).map(Some)
    }

    /// A number a BSDF reads from a texture (Mitsuba's `eval_1`): a
    /// `<float>`, or the mean of an `<rgb>`'s or `<spectrum>`'s channels
    /// (Blender 4's exporter writes principled's tints as colours).
    pub fn mean_number(&self, name: &str) -> Result<Option<f32>, SceneError> {
        let colour = self
            .find(name)
            .is_some_and(|el| matches!(el.tag.as_str(), "rgb" | "spectrum"));
        if colour {
            return Ok(self.color(name)?.map(|c| (c.x + c.y + c.z) / 3.0));
        }
        self.float(name)
    }

    pub fn float_or(&self, name: &str, default: f32) -> Result<f32, SceneError> {
        Ok(self.float(name)?.unwrap_or(default))
    }

    /// A `<float>` as Ok, a `<string>` as Err.
    pub fn number_or_string(&self, name: &str) -> Result<Option<Result<f32, &'e str>>, SceneError> {
        let Some(el) = self.typed(name, &["float", "integer", "string"])? else {
            return Ok(None);
        };
        let v = el.required("value")?;
        Ok(Some(if el.tag == "string" {
            Err(v)
        } else {
            Ok(self.number(el, v)?)
        }))
    }

    pub fn integer(&self, name: &str) -> Result<Option<i64>, SceneError> {
        let Some(el) = self.typed(name, &["integer"])? else {
            return Ok(None);
        };
        let v = el.required("value")?;
        v.trim()
            .parse::<i64>()
            .map(Some)
            .map_err(|_| el.error(format!("'{v}' is not an integer (property '{name}')")))
    }

    pub fn boolean(&self, name: &str) -> Result<Option<bool>, SceneError> {
        let Some(el) = self.typed(name, &["boolean"])? else {
            return Ok(None);
        };
        // Mitsuba takes either in any case ("True", as Python writes it).
        match el.required("value")?.trim().to_ascii_lowercase().as_str() {
            "true" => Ok(Some(true)),
            "false" => Ok(Some(false)),
            v => Err(el.error(format!("'{v}' is not true or false (property '{name}')"))),
        }
    }

    pub fn string(&self, name: &str) -> Result<Option<&'e str>, SceneError> {
        let Some(el) = self.typed(name, &["string"])? else {
            return Ok(None);
        };
        el.required("value").map(Some)
    }

    /// A colour from `<rgb>`, a `<spectrum>` (one value, or
    /// wavelength:value pairs) or a `<float>`: a reflectance or other
    /// bounded quantity.
    pub fn color(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        self.color_as(name, false)
    }

    /// [`Props::color`] for an emitter's radiance, whose spectrum Mitsuba
    /// turns into RGB without the white point and without bounds.
    pub fn radiance(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        self.color_as(name, true)
    }

    fn color_as(&self, name: &str, emitted: bool) -> Result<Option<Vec3>, SceneError> {
        let Some(el) = self.find(name) else {
            return Ok(None);
        };
        let value = || el.required("value");
        let c = match el.tag.as_str() {
            "rgb" => {
                let v = self.numbers(el, value()?)?;
                match v[..] {
                    [x] => Vec3::splat(x),
                    [r, g, b] => Vec3::new(r, g, b),
                    _ => {
                        return Err(el.error(format!(
                            "<rgb name=\"{name}\"> needs three numbers, not {}",
                            v.len()
                        )))
                    }
                }
            }
            "spectrum" => {
                let text = value()?;
                if text.contains(':') {
                    return spectrum_to_rgb(el, text, !emitted).map(Some);
                }
                let v = self.numbers(el, text)?;
                match v[..] {
                    // A flat spectrum emitted is, in Mitsuba's RGB variants,
                    // its colour under CIE 1931 with no white point: equal
                    // energy is pinkish in sRGB.
                    [x] if emitted => x * EQUAL_ENERGY_RGB,
                    [x] => Vec3::splat(x),
                    _ => {
                        return Err(el.error(format!(
                            "<spectrum name=\"{name}\"> needs one value or wavelength:value pairs"
                        )))
                    }
                }
            }
            "float" | "integer" => Vec3::splat(self.number(el, value()?)?),
            "texture" | "ref" => {
                return Err(el.error(format!(
                    "'{name}' is a texture: textures are not supported yet; give <rgb>"
                )))
            }
            other => {
                return Err(el.error(format!(
                    "'{name}' is a <{other}>; a colour is <rgb>, <spectrum> or <float>"
                )))
            }
        };
        if !c.is_finite() {
            return Err(el.error(format!("'{name}' is not finite")));
        }
        Ok(Some(c))
    }

    /// A point from `<point>` (x, y, z or value).
    pub fn point(&self, name: &str) -> Result<Option<Vec3>, SceneError> {
        let Some(el) = self.typed(name, &["point", "vector"])? else {
            return Ok(None);
        };
        vector_attrs(el, 0.0).map(Some)
    }

    pub fn transform(&self, name: &str) -> Result<Option<Mat4>, SceneError> {
        let Some(el) = self.typed(name, &["transform"])? else {
            return Ok(None);
        };
        transform(el).map(Some)
    }

    fn numbers(&self, el: &Element, text: &str) -> Result<Vec<f32>, SceneError> {
        numbers(el, text)
    }

    /// Fails on the first child nobody read: an unknown parameter or plugin
    /// would change the image silently.
    pub fn finish(self) -> Result<(), SceneError> {
        for (c, used) in self.el.children.iter().zip(&self.used) {
            if used.get() {
                continue;
            }
            let what = match c.attr("name") {
                Some(n) if PROPERTY_TAGS.contains(&c.tag.as_str()) => format!("parameter '{n}'"),
                _ => format!(
                    "<{}{}>",
                    c.tag,
                    c.attr("type")
                        .map(|t| format!(" type=\"{t}\""))
                        .unwrap_or_default()
                ),
            };
            return Err(c.error(format!(
                "{} has {what}, which qtrace does not support (see docs/mitsuba.md)",
                plugin_name(self.el)
            )));
        }
        Ok(())
    }
}

/// A `wavelength:value, ...` spectrum as Mitsuba 3's RGB variants see it:
/// its colour under the CIE 1931 observer (lit by D65, for a `reflectance`
/// that is not emitted), in linear sRGB, integrated as Mitsuba does (1000
/// steps over 360-830 nm, the spectrum linear between its points and zero
/// outside them), clamped to [0, 1] (`bounded`) or to non-negative values.
pub fn spectrum_to_rgb(el: &Element, text: &str, bounded: bool) -> Result<Vec3, SceneError> {
    let mut points: Vec<(f32, f32)> = Vec::new();
    for pair in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let parsed = pair
            .split_once(':')
            .and_then(|(w, v)| Some((parse_f32(w)?, parse_f32(v)?)));
        let Some((w, v)) = parsed else {
            return Err(el.error(format!("'{pair}' is not wavelength:value")));
        };
        if points.last().is_some_and(|&(last, _)| w <= last) {
            return Err(el.error("a spectrum's wavelengths must increase"));
        }
        points.push((w, v));
    }
    if points.len() < 2 {
        return Err(el.error("a spectrum needs at least two wavelength:value pairs"));
    }
    let cmf = |x: f32| -> [f32; 4] {
        let t = (x - super::cie::FIRST_NM).clamp(0.0, (super::cie::TABLE.len() - 1) as f32);
        let i = (t as usize).min(super::cie::TABLE.len() - 2);
        let f = t - i as f32;
        let (a, b) = (super::cie::TABLE[i], super::cie::TABLE[i + 1]);
        [0, 1, 2, 3].map(|k| a[k] + f * (b[k] - a[k]))
    };
    const STEPS: usize = 1000;
    let (lo, hi) = (super::cie::FIRST_NM, super::cie::LAST_NM);
    let mut xyz = glam::DVec3::ZERO;
    for i in 0..STEPS {
        let x = lo + (i as f32 / (STEPS - 1) as f32) * (hi - lo);
        if x < points[0].0 || x > points[points.len() - 1].0 {
            continue;
        }
        let k = points
            .windows(2)
            .position(|w| x <= w[1].0)
            .unwrap_or(points.len() - 2);
        let ((x0, y0), (x1, y1)) = (points[k], points[k + 1]);
        let y = y0 + (x - x0) / (x1 - x0) * (y1 - y0);
        let [cx, cy, cz, d65] = cmf(x);
        let weight = if bounded { d65 } else { 1.0 } as f64 * y as f64;
        xyz += glam::DVec3::new(cx as f64, cy as f64, cz as f64) * weight;
    }
    xyz *= (hi - lo) as f64 / STEPS as f64 * CIE_Y_NORMALIZATION;
    let rgb = (XYZ_TO_SRGB * xyz).as_vec3();
    let clamped = if bounded {
        rgb.clamp(Vec3::ZERO, Vec3::ONE)
    } else {
        rgb.max(Vec3::ZERO)
    };
    if clamped != rgb {
        log::warn!(
            "{}:{}: the spectrum's colour {rgb} lies outside sRGB; clamped to {clamped}, as Mitsuba does",
            el.file.display(),
            el.line
        );
    }
    Ok(clamped)
}

/// The linear sRGB of an emitted flat spectrum of 1, as Mitsuba 3.9.1's RGB
/// variants have it (`mi.traverse` of an area emitter's `<spectrum
/// name="radiance" value="1"/>`).
const EQUAL_ENERGY_RGB: Vec3 = Vec3::new(1.204_794, 0.948_291, 0.908_916);

/// CIE XYZ to linear sRGB, as Mitsuba 3 converts.
pub const XYZ_TO_SRGB: glam::DMat3 = glam::DMat3::from_cols_array(&[
    3.240479, -0.969256, 0.055648, -1.537150, 1.875991, -0.204043, -0.498535, 0.041556, 1.057311,
]);

/// 1 / the integral of the CIE 1931 ȳ over 360-830 nm, as Mitsuba 3 has it.
pub const CIE_Y_NORMALIZATION: f64 = 1.0 / 106.750_259_399_414_06;

/// "bsdf 'roughconductor'", say.
pub fn plugin_name(el: &Element) -> String {
    match el.attr("type") {
        Some(t) => format!("{} '{t}'", el.tag),
        None => format!("<{}>", el.tag),
    }
}

pub fn parse_f32(text: &str) -> Option<f32> {
    let v: f32 = text.trim().parse().ok()?;
    v.is_finite().then_some(v)
}

/// Numbers separated by commas and/or white space.
pub fn numbers(el: &Element, text: &str) -> Result<Vec<f32>, SceneError> {
    text.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .map(|s| parse_f32(s).ok_or_else(|| el.error(format!("'{s}' is not a finite number"))))
        .collect()
}

/// A vector from `value="x, y, z"` or the attributes x, y, z (each
/// `missing` when absent, as Mitsuba's translate and scale read them).
fn vector_attrs(el: &Element, missing: f32) -> Result<Vec3, SceneError> {
    if let Some(v) = el.attr("value") {
        let v = numbers(el, v)?;
        return match v[..] {
            [x] => Ok(Vec3::splat(x)),
            [x, y, z] => Ok(Vec3::new(x, y, z)),
            _ => Err(el.error(format!("<{}> needs three numbers", el.tag))),
        };
    }
    let mut out = [missing; 3];
    for (o, k) in out.iter_mut().zip(["x", "y", "z"]) {
        if let Some(s) = el.attr(k) {
            *o = parse_f32(s)
                .ok_or_else(|| el.error(format!("{k}=\"{s}\" is not a finite number")))?;
        }
    }
    Ok(Vec3::from(out))
}

/// A turn by `angle` about `axis` as Mitsuba 3's `rotate` makes it: the
/// axis-angle matrix with the axis as given (glam's `from_axis_angle`,
/// which wants a unit axis, in the same order of operations).
fn rotation(axis: Vec3, angle: f32) -> Mat4 {
    let (sin, cos) = angle.sin_cos();
    let (s, q, omc) = (axis * sin, axis * axis, 1.0 - cos);
    let (xy, xz, yz) = (
        axis.x * axis.y * omc,
        axis.x * axis.z * omc,
        axis.y * axis.z * omc,
    );
    Mat4::from_mat3(glam::Mat3::from_cols(
        Vec3::new(q.x * omc + cos, xy + s.z, xz - s.y),
        Vec3::new(xy - s.z, q.y * omc + cos, yz + s.x),
        Vec3::new(xz + s.y, yz - s.x, q.z * omc + cos),
    ))
}

/// A `<transform>`'s matrix: its steps applied in document order.
pub fn transform(el: &Element) -> Result<Mat4, SceneError> {
    let mut m = Mat4::IDENTITY;
    for step in &el.children {
        let s = match step.tag.as_str() {
            "translate" => Mat4::from_translation(vector_attrs(step, 0.0)?),
            "scale" => {
                let v = vector_attrs(step, 1.0)?;
                Mat4::from_scale(v)
            }
            "rotate" => {
                let axis = vector_attrs(step, 0.0)?;
                let angle = parse_f32(step.required("angle")?)
                    .ok_or_else(|| step.error("the angle is not a finite number"))?;
                if axis.length() == 0.0 {
                    return Err(step.error("<rotate> needs a non-zero axis"));
                }
                // Mitsuba 3 turns about the axis as given, without
                // normalizing it: one not of unit length stretches too.
                if (axis.length() - 1.0).abs() > 1e-4 {
                    log::warn!(
                        "{}:{}: <rotate>'s axis has length {}; Mitsuba 3 does not normalize it, so the turn also stretches, and qtrace renders it so",
                        step.file.display(),
                        step.line,
                        axis.length()
                    );
                }
                rotation(axis, angle.to_radians())
            }
            "matrix" => {
                let v = numbers(step, step.required("value")?)?;
                match v.len() {
                    16 => Mat4::from_cols_array(&v.try_into().unwrap()).transpose(),
                    9 => {
                        let r = |i: usize| glam::Vec4::new(v[i], v[i + 1], v[i + 2], 0.0);
                        Mat4::from_cols(r(0), r(3), r(6), glam::Vec4::W).transpose()
                    }
                    n => {
                        return Err(step.error(format!("<matrix> needs 16 (or 9) numbers, not {n}")))
                    }
                }
            }
            "lookat" => {
                let p = |k: &str| -> Result<Vec3, SceneError> {
                    let v = numbers(step, step.required(k)?)?;
                    match v[..] {
                        [x, y, z] => Ok(Vec3::new(x, y, z)),
                        _ => Err(step.error(format!("<lookat> {k} needs three numbers"))),
                    }
                };
                let origin = p("origin")?;
                let target = p("target")?;
                // Without an up, Mitsuba takes the first axis of its
                // orthonormal basis around the view direction.
                let up = if step.attr("up").is_some() {
                    p("up")?
                } else {
                    (target - origin)
                        .try_normalize()
                        .map_or(Vec3::Y, |d| coordinate_system(d).0)
                };
                look_at(origin, target, up).ok_or_else(|| {
                    step.error("<lookat>: target equals origin, or up is parallel to the view")
                })?
            }
            other => {
                return Err(step.error(format!(
                "<{other}> in a <transform>: expected translate, rotate, scale, matrix or lookat"
            )))
            }
        };
        m = s * m;
    }
    if !m.is_finite() {
        return Err(el.error("the transform is not finite"));
    }
    Ok(m)
}

/// Mitsuba's orthonormal basis around unit vector n (Duff et al. 2017).
pub fn coordinate_system(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(n.x * n.x * a * sign + 1.0, b * sign, -n.x * sign),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Mitsuba's look-at: the camera's +z toward the target, +y up and +x to
/// the image's left.
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> Option<Mat4> {
    let dir = (target - origin).try_normalize()?;
    let left = up.cross(dir).try_normalize()?;
    let new_up = dir.cross(left);
    Some(Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    ))
}

#[cfg(test)]
mod tests {
    /// Names as Mitsuba 3.9.1's upgrade of 0.x scenes writes them (read
    /// from its messages on unknown properties: `aBcD` as `a_bc_d`, `xYZw`
    /// as `x_yzw`).
    #[test]
    fn camel_case_becomes_snake_case_as_in_mitsuba() {
        for (old, new) in [
            ("toWorld", "to_world"),
            ("intIOR", "int_ior"),
            ("specularReflectance", "specular_reflectance"),
            ("alphaU", "alpha_u"),
            ("sampleCount", "sample_count"),
            ("filename", "filename"),
            ("to_world", "to_world"),
            ("aBcD", "a_bc_d"),
            ("xYZw", "x_yzw"),
            ("aB1cD", "a_b1c_d"),
            ("AbC", "Ab_c"),
            ("", ""),
        ] {
            assert_eq!(super::snake_case(old), new, "{old}");
        }
    }
}
