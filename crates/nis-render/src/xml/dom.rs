//! Reading Mitsuba 3 XML into a small element tree with line numbers, substituting
//! `<default>` parameters, and reading typed properties (`float`, `rgb`, `transform`, …).
//!
//! Conventions follow Mitsuba 3's scene format documentation: `$name` in any attribute is
//! replaced by a parameter given on the command line or else by the scene's `<default>`;
//! numbers in `rgb`, `point` and `vector` values are separated by commas and/or spaces; the
//! operations of a `<transform>` apply in the order written (each new one multiplies from the
//! left); `rotate` angles are in degrees.

use std::collections::HashMap;

use glam::{Mat4, Vec3};
use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;

use crate::camera::look_at;

/// An XML element with its 1-based source line.
#[derive(Clone, Debug)]
pub struct Element {
    /// Tag name.
    pub name: String,
    /// Attributes in source order.
    pub attrs: Vec<(String, String)>,
    /// Child elements.
    pub children: Vec<Element>,
    /// Line of the start tag.
    pub line: usize,
}

/// A loader error before it is given the file name: line and message.
#[derive(Clone, Debug)]
pub struct XmlError {
    /// 1-based line.
    pub line: usize,
    /// What went wrong.
    pub message: String,
}

/// The error `message` at `line`.
pub fn error_at(line: usize, message: impl Into<String>) -> XmlError {
    XmlError {
        line,
        message: message.into(),
    }
}

/// Shorthand for an error at `line`.
pub fn err<T>(line: usize, message: impl Into<String>) -> Result<T, XmlError> {
    Err(error_at(line, message))
}

fn line_of(text: &str, pos: usize) -> usize {
    line_of_bytes(text.as_bytes(), pos)
}

fn start_element(e: &BytesStart, line: usize) -> Result<Element, XmlError> {
    let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
    let mut attrs = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|x| XmlError {
            line,
            message: format!("malformed attribute: {x}"),
        })?;
        let value = a.unescape_value().map_err(|x| XmlError {
            line,
            message: format!("malformed attribute value: {x}"),
        })?;
        attrs.push((
            String::from_utf8_lossy(a.key.as_ref()).into_owned(),
            value.into_owned(),
        ));
    }
    Ok(Element {
        name,
        attrs,
        children: Vec::new(),
        line,
    })
}

/// Deepest nesting of elements a scene may have. Mitsuba scenes nest a handful of levels; the
/// bound keeps every recursive walk of the tree (substitution, loading, dropping it) far from
/// the end of the stack, so a hostile file is an error, not a crash.
pub const MAX_DEPTH: usize = 64;

/// Line numbers of increasing byte positions, counted incrementally (a scene of n elements is
/// read in O(n), not O(n²)).
struct Lines<'a> {
    text: &'a [u8],
    pos: usize,
    line: usize,
}

impl Lines<'_> {
    fn at(&mut self, pos: usize) -> usize {
        let pos = pos.min(self.text.len());
        if pos < self.pos {
            return line_of_bytes(self.text, pos);
        }
        self.line += self.text[self.pos..pos]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        self.pos = pos;
        self.line
    }
}

fn line_of_bytes(text: &[u8], pos: usize) -> usize {
    text[..pos.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// Parse `text` into its root element.
pub fn parse(text: &str) -> Result<Element, XmlError> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut lines = Lines {
        text: text.as_bytes(),
        pos: 0,
        line: 1,
    };
    let mut stack: Vec<Element> = Vec::new();
    let mut root = None;
    loop {
        // Skip whitespace so that the recorded position is the tag's own line.
        let mut pos = reader.buffer_position() as usize;
        while pos < text.len() && text.as_bytes()[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let event = reader.read_event().map_err(|e| XmlError {
            line: line_of(text, reader.error_position() as usize),
            message: format!("malformed XML: {e}"),
        })?;
        match event {
            Event::Start(e) => {
                let line = lines.at(pos);
                if stack.len() == MAX_DEPTH {
                    return err(
                        line,
                        format!("elements nest deeper than {MAX_DEPTH} levels"),
                    );
                }
                stack.push(start_element(&e, line)?)
            }
            Event::Empty(e) => {
                let el = start_element(&e, lines.at(pos))?;
                match stack.last_mut() {
                    Some(parent) => parent.children.push(el),
                    None => root = Some(el),
                }
            }
            Event::End(_) => {
                let el = stack.pop().expect("the reader checks that end tags match");
                match stack.last_mut() {
                    Some(parent) => parent.children.push(el),
                    None => root = Some(el),
                }
            }
            Event::Text(t) if !t.iter().all(u8::is_ascii_whitespace) => {
                return err(lines.at(pos), "unexpected text outside of attributes");
            }
            Event::Eof => break,
            _ => {}
        }
    }
    if let Some(open) = stack.last() {
        return err(open.line, format!("<{}> is never closed", open.name));
    }
    root.ok_or(XmlError {
        line: 1,
        message: "the file contains no XML element".into(),
    })
}

/// Replace `$name` in every attribute (except `<default>`'s own) using `params`, in one pass:
/// a value that itself contains `$` is inserted as it is (as in Mitsuba), so no definition can
/// expand forever. `budget` bounds the bytes that substitution may add in all (many references
/// to a long value would otherwise multiply the file's size).
pub fn substitute(
    el: &mut Element,
    params: &HashMap<String, String>,
    budget: &mut usize,
) -> Result<(), XmlError> {
    if el.name != "default" {
        for (_, value) in &mut el.attrs {
            if !value.contains('$') {
                continue;
            }
            let mut out = String::with_capacity(value.len());
            let mut rest = value.as_str();
            while let Some(start) = rest.find('$') {
                out.push_str(&rest[..start]);
                let after = &rest[start + 1..];
                let len = after
                    .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                    .unwrap_or(after.len());
                let key = &after[..len];
                let Some(v) = params.get(key) else {
                    return err(el.line, format!("parameter ${key} has no value (add a <default> or pass it on the command line)"));
                };
                *budget = budget.checked_sub(v.len()).ok_or(XmlError {
                    line: el.line,
                    message: "parameter substitution makes the scene implausibly large".into(),
                })?;
                out.push_str(v);
                rest = &after[len..];
            }
            out.push_str(rest);
            *value = out;
        }
    }
    for c in &mut el.children {
        substitute(c, params, budget)?;
    }
    Ok(())
}

impl Element {
    /// Value of attribute `key`.
    pub fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Set attribute `key` (that already exists) to `value`.
    pub fn set_attr(&mut self, key: &str, value: impl Into<String>) {
        let value = value.into();
        for (k, v) in &mut self.attrs {
            if k == key {
                v.clone_from(&value);
            }
        }
    }

    /// Value of a required attribute.
    pub fn required(&self, key: &str) -> Result<&str, XmlError> {
        self.attr(key).ok_or(XmlError {
            line: self.line,
            message: format!("<{}> needs the attribute '{key}'", self.name),
        })
    }
}

/// Parse a finite float, naming the element on failure (`1e39` overflows f32, and no scene
/// quantity is meaningful as ±∞ or NaN).
pub fn parse_float(s: &str, line: usize) -> Result<f32, XmlError> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => err(
            line,
            format!("'{s}' is not a finite number (in single precision)"),
        ),
        Err(_) => err(line, format!("'{s}' is not a number")),
    }
}

/// Parse one or three numbers separated by commas and/or spaces.
pub fn parse_vector(s: &str, line: usize) -> Result<Vec3, XmlError> {
    let v: Vec<f32> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .map(|p| parse_float(p, line))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [a] => Ok(Vec3::splat(*a)),
        [a, b, c] => Ok(Vec3::new(*a, *b, *c)),
        _ => err(line, format!("expected 1 or 3 numbers, got '{s}'")),
    }
}

/// A `point`/`vector`/`translate`-style triple from `value` or `x`/`y`/`z` attributes.
fn xyz(el: &Element, default: f32) -> Result<Vec3, XmlError> {
    if let Some(v) = el.attr("value") {
        return parse_vector(v, el.line);
    }
    let get = |k| match el.attr(k) {
        Some(s) => parse_float(s, el.line),
        None => Ok(default),
    };
    Ok(Vec3::new(get("x")?, get("y")?, get("z")?))
}

/// The matrix of a `<transform>` element.
pub fn parse_transform(el: &Element) -> Result<Mat4, XmlError> {
    let mut m = Mat4::IDENTITY;
    for op in &el.children {
        let t = match op.name.as_str() {
            "translate" => Mat4::from_translation(xyz(op, 0.0)?),
            "scale" => Mat4::from_scale(xyz(op, 1.0)?),
            "rotate" => {
                let axis = xyz(op, 0.0)?;
                let angle = parse_float(op.required("angle")?, op.line)?;
                if axis.length_squared() == 0.0 {
                    return err(op.line, "<rotate> needs a non-zero axis");
                }
                Mat4::from_axis_angle(axis.normalize(), angle.to_radians())
            }
            "matrix" => {
                let v: Vec<f32> = op
                    .required("value")?
                    .split(|c: char| c == ',' || c.is_whitespace())
                    .filter(|p| !p.is_empty())
                    .map(|p| parse_float(p, op.line))
                    .collect::<Result<_, _>>()?;
                if v.len() != 16 {
                    return err(op.line, format!("<matrix> needs 16 numbers, got {}", v.len()));
                }
                // Mitsuba writes matrices row by row.
                Mat4::from_cols_array(&v.try_into().expect("16 numbers")).transpose()
            }
            "lookat" => {
                let origin = parse_vector(op.required("origin")?, op.line)?;
                let target = parse_vector(op.required("target")?, op.line)?;
                let up = match op.attr("up") {
                    Some(u) => parse_vector(u, op.line)?,
                    None => Vec3::Y,
                };
                let dir = target - origin;
                if dir.length_squared() == 0.0 || up.cross(dir).length_squared() == 0.0 {
                    return err(
                        op.line,
                        "invalid <lookat>: the target equals the origin, or `up` is parallel to the view direction",
                    );
                }
                look_at(origin, target, up)
            }
            other => {
                return err(
                    op.line,
                    format!("unsupported transform operation <{other}> (supported: translate, scale, rotate, matrix, lookat)"),
                )
            }
        };
        m = t * m;
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_apply_in_written_order() {
        let el = parse(
            r#"<transform name="to_world">
                 <scale value="2"/>
                 <translate x="1"/>
               </transform>"#,
        )
        .unwrap();
        let m = parse_transform(&el).unwrap();
        // Scale first, then translate: (1,0,0) → (2,0,0) → (3,0,0).
        assert!((m.transform_point3(Vec3::X) - Vec3::new(3.0, 0.0, 0.0)).length() < 1e-6);
    }

    #[test]
    fn a_degenerate_lookat_is_an_error() {
        for (target, up) in [("0, 0, 0", "0, 1, 0"), ("0, 2, 0", "0, 1, 0")] {
            let el = parse(&format!(
                r#"<transform name="to_world"><lookat origin="0, 0, 0" target="{target}" up="{up}"/></transform>"#
            ))
            .unwrap();
            assert!(parse_transform(&el).unwrap_err().message.contains("lookat"));
        }
    }

    #[test]
    fn malformed_xml_reports_its_line() {
        let e = parse("<scene>\n  <shape type=\"cube\">\n  </shap>\n</scene>").unwrap_err();
        assert_eq!(e.line, 3, "{}", e.message);
        let e = parse("<scene>\n\n <float name=\"x\" value=\"1/>\n</scene>").unwrap_err();
        assert!(e.line >= 3, "{} {}", e.line, e.message);
    }
}
