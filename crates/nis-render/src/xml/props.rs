//! The typed properties of one Mitsuba plugin element (`<float name=… value=…/>` and friends),
//! read by name with Mitsuba's defaults; like Mitsuba, a property that no one reads is an error,
//! so a misspelt or unsupported parameter never goes unnoticed.

use std::cell::RefCell;
use std::collections::{HashMap, HashSet};

use glam::{Mat4, Vec3};

use super::dom::{err, parse_float, parse_transform, parse_vector, Element, XmlError};
use crate::geometry::Rgb;
use crate::spectrum::{list_to_rgb, uniform_to_rgb, Role};

/// The property children of a plugin element, with a record of which were read.
pub(super) struct Props<'a> {
    el: &'a Element,
    pub(super) by_name: HashMap<&'a str, &'a Element>,
    used: RefCell<HashSet<&'a str>>,
}

pub(super) const PROPERTY_TAGS: [&str; 9] = [
    "float",
    "integer",
    "boolean",
    "string",
    "rgb",
    "spectrum",
    "point",
    "vector",
    "transform",
];

impl<'a> Props<'a> {
    pub(super) fn new(el: &'a Element) -> Result<Self, XmlError> {
        let mut by_name = HashMap::new();
        for c in &el.children {
            if PROPERTY_TAGS.contains(&c.name.as_str())
                && by_name.insert(c.required("name")?, c).is_some()
            {
                return err(
                    c.line,
                    format!("property '{}' is given twice", c.required("name")?),
                );
            }
        }
        Ok(Props {
            el,
            by_name,
            used: RefCell::new(HashSet::new()),
        })
    }

    pub(super) fn get(
        &self,
        name: &'a str,
        tags: &[&str],
    ) -> Result<Option<&'a Element>, XmlError> {
        let Some(&p) = self.by_name.get(name) else {
            return Ok(None);
        };
        self.used.borrow_mut().insert(name);
        if !tags.contains(&p.name.as_str()) {
            return err(
                p.line,
                format!(
                    "property '{name}' must be one of <{}>, not <{}>",
                    tags.join(">, <"),
                    p.name
                ),
            );
        }
        Ok(Some(p))
    }

    pub(super) fn float(&self, name: &'a str, default: f32) -> Result<f32, XmlError> {
        Ok(self.float_opt(name)?.unwrap_or(default))
    }

    pub(super) fn float_opt(&self, name: &'a str) -> Result<Option<f32>, XmlError> {
        match self.get(name, &["float", "integer"])? {
            Some(p) => parse_float(p.required("value")?, p.line).map(Some),
            None => Ok(None),
        }
    }

    pub(super) fn int(&self, name: &'a str, default: i64) -> Result<i64, XmlError> {
        match self.get(name, &["integer"])? {
            Some(p) => {
                let v = p.required("value")?;
                v.trim()
                    .parse()
                    .or_else(|_| err(p.line, format!("'{v}' is not an integer")))
            }
            None => Ok(default),
        }
    }

    pub(super) fn boolean(&self, name: &'a str, default: bool) -> Result<bool, XmlError> {
        match self.get(name, &["boolean"])? {
            Some(p) => match p.required("value")? {
                "true" => Ok(true),
                "false" => Ok(false),
                v => err(p.line, format!("'{v}' is not true or false")),
            },
            None => Ok(default),
        }
    }

    pub(super) fn string(&self, name: &'a str) -> Result<Option<&'a str>, XmlError> {
        match self.get(name, &["string"])? {
            Some(p) => Ok(Some(p.required("value")?)),
            None => Ok(None),
        }
    }

    /// A reflectance from `<rgb>`, `<float>` or a `<spectrum>`.
    pub(super) fn rgb(&self, name: &'a str, default: Rgb) -> Result<Rgb, XmlError> {
        self.spectrum(name, default, Role::Reflectance)
    }

    /// A colour from `<rgb>`, `<float>` or a `<spectrum>` (a constant or `wavelength:value`
    /// pairs, converted as Mitsuba's RGB variants do for `role`).
    pub(super) fn spectrum(
        &self,
        name: &'a str,
        default: Rgb,
        role: Role,
    ) -> Result<Rgb, XmlError> {
        match self.get(name, &["rgb", "float", "spectrum"])? {
            Some(p) if p.name == "spectrum" => spectrum_value(p, role),
            Some(p) => parse_vector(p.required("value")?, p.line),
            None => Ok(default),
        }
    }

    pub(super) fn transform(&self, name: &'a str) -> Result<Mat4, XmlError> {
        match self.get(name, &["transform"])? {
            Some(p) => parse_transform(p),
            None => Ok(Mat4::IDENTITY),
        }
    }

    pub(super) fn point(&self, name: &'a str, default: Vec3) -> Result<Vec3, XmlError> {
        match self.get(name, &["point", "vector"])? {
            Some(p) => match p.attr("value") {
                Some(v) => parse_vector(v, p.line),
                None => Ok(Vec3::new(
                    parse_float(p.required("x")?, p.line)?,
                    parse_float(p.required("y")?, p.line)?,
                    parse_float(p.required("z")?, p.line)?,
                )),
            },
            None => Ok(default),
        }
    }

    /// The plugin element's line.
    pub(super) fn line(&self) -> usize {
        self.el.line
    }

    /// Accept (and ignore) properties that do not change the image.
    pub(super) fn ignore(&self, names: &[&'a str]) {
        self.used.borrow_mut().extend(names.iter().copied());
    }

    /// Fail on properties that were never read, as Mitsuba does.
    pub(super) fn finish(&self) -> Result<(), XmlError> {
        let used = self.used.borrow();
        let mut unused: Vec<_> = self
            .by_name
            .iter()
            .filter(|(k, _)| !used.contains(*k))
            .collect();
        unused.sort_by_key(|(_, e)| e.line);
        if let Some((name, p)) = unused.first() {
            let kind = self.el.attr("type").unwrap_or("");
            return err(
                p.line,
                format!(
                    "unsupported parameter '{name}' of <{} type=\"{kind}\">",
                    self.el.name
                ),
            );
        }
        Ok(())
    }
}

/// Index of refraction of a named material (Mitsuba 3's table) or a number.
pub(super) fn ior(value: &str, line: usize) -> Result<f32, XmlError> {
    const TABLE: [(&str, f32); 22] = [
        ("vacuum", 1.0),
        ("helium", 1.000_036),
        ("hydrogen", 1.000_132),
        ("air", 1.000_277),
        ("carbon dioxide", 1.000_45),
        ("water", 1.333),
        ("acetone", 1.36),
        ("ethanol", 1.361),
        ("carbon tetrachloride", 1.461),
        ("glycerol", 1.4729),
        ("benzene", 1.501),
        ("silicone oil", 1.520_45),
        ("bromine", 1.661),
        ("water ice", 1.31),
        ("fused quartz", 1.458),
        ("pyrex", 1.47),
        ("acrylic glass", 1.49),
        ("polypropylene", 1.49),
        ("bk7", 1.5046),
        ("sodium chloride", 1.544),
        ("amber", 1.55),
        ("diamond", 2.419),
    ];
    if value.trim().parse::<f32>().is_ok() {
        return parse_float(value, line);
    }
    TABLE
        .iter()
        .find(|(n, _)| *n == value)
        .map(|(_, v)| *v)
        .ok_or(XmlError {
            line,
            message: format!("unknown index of refraction '{value}'"),
        })
}

/// The RGB of a `<spectrum value=…>`: one number, or `wavelength:value` pairs separated by
/// commas.
pub(super) fn spectrum_value(p: &Element, role: Role) -> Result<Rgb, XmlError> {
    if p.attr("filename").is_some() {
        return err(
            p.line,
            "<spectrum filename=…> (a spectrum from a file) is not supported: give its \
             wavelength:value pairs in value=\"…\"",
        );
    }
    let v = p.required("value")?;
    if !v.contains(':') {
        return parse_float(v, p.line).map(|c| uniform_to_rgb(f64::from(c), role));
    }
    let mut points = Vec::new();
    for pair in v.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let Some((w, x)) = pair.split_once(':') else {
            return err(p.line, format!("'{pair}' is not a wavelength:value pair"));
        };
        points.push((
            f64::from(parse_float(w, p.line)?),
            f64::from(parse_float(x, p.line)?),
        ));
    }
    list_to_rgb(&points, role)
        .map(|(rgb, _)| rgb)
        .or_else(|m| err(p.line, m))
}
