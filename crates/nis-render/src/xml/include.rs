//! Mitsuba 3's `<include filename="…"/>` (another scene file's elements, in place),
//! `<path value="…"/>` (a folder where relative file names are also looked for), and objects
//! defined once at the top with an `id` and used by `<ref id="…"/>` where only a nested object
//! means anything (an area emitter, a sampler, a film, a filter), applied to the element tree
//! before anything else is read. An included file is upgraded by its own version. (BSDFs and
//! textures given by reference are shared, not copied: the loader keeps them by id.)

use std::path::{Path, PathBuf};

use super::dom::{self, err, Element, XmlError};
use super::upgrade;

/// Deepest chain of includes (a file that includes itself would otherwise never end).
pub const MAX_INCLUDE_DEPTH: usize = 16;

/// Replace every `<include>` among `root`'s children by the children of the file it names and
/// collect the `<path>` folders (resolved against `base_dir`, the including file's folder),
/// appending them to `paths`; an included legacy file's upgrade warnings go to `warnings` with
/// the include's line. An include's file is looked for as Mitsuba 3's file resolver looks for
/// it: in the including file's folder, in the `<path>` folders, then in `scene_dir`, the main
/// scene file's (Mitsuba's own test scenes include `include/preamble.xml` from
/// `include/test-scene-base.xml`).
pub fn expand(
    root: &mut Element,
    base_dir: &Path,
    scene_dir: &Path,
    paths: &mut Vec<PathBuf>,
    warnings: &mut Vec<(usize, String)>,
    depth: usize,
) -> Result<(), XmlError> {
    let children = std::mem::take(&mut root.children);
    for c in children {
        match c.name.as_str() {
            "path" => paths.push(base_dir.join(c.required("value")?)),
            "include" => {
                if depth >= MAX_INCLUDE_DEPTH {
                    return err(
                        c.line,
                        format!("includes nest deeper than {MAX_INCLUDE_DEPTH} files"),
                    );
                }
                let name = c.required("filename")?;
                let mut file = resolve(base_dir, paths, name);
                if !file.exists() && scene_dir.join(name).exists() {
                    file = scene_dir.join(name);
                }
                let text = std::fs::read_to_string(&file).or_else(|e| {
                    err(
                        c.line,
                        format!("cannot read the included file {}: {e}", file.display()),
                    )
                })?;
                let mut included = dom::parse(&text).map_err(|e| XmlError {
                    line: c.line,
                    message: format!(
                        "in the included file {}:{}: {}",
                        file.display(),
                        e.line,
                        e.message
                    ),
                })?;
                if included.name != "scene" {
                    return err(
                        c.line,
                        format!("the included file {} is not a <scene>", file.display()),
                    );
                }
                if upgrade::is_legacy(&included)? {
                    let mut notes = Vec::new();
                    upgrade::upgrade(&mut included, &mut notes)?;
                    warnings.extend(notes.into_iter().map(|(_, m)| (c.line, m)));
                }
                let dir = file.parent().map(Path::to_path_buf).unwrap_or_default();
                expand(&mut included, &dir, scene_dir, paths, warnings, depth + 1)?;
                // Errors inside name the include's line: the element tree keeps one file's
                // lines.
                for mut e in included.children {
                    relabel(&mut e, c.line);
                    root.children.push(e);
                }
            }
            _ => root.children.push(c),
        }
    }
    Ok(())
}

fn relabel(e: &mut Element, line: usize) {
    e.line = line;
    for c in &mut e.children {
        relabel(c, line);
    }
}

/// `name` relative to `base_dir`, or to the first of `paths` where it exists.
pub fn resolve(base_dir: &Path, paths: &[PathBuf], name: &str) -> PathBuf {
    let first = base_dir.join(name);
    if first.exists() {
        return first;
    }
    paths
        .iter()
        .map(|p| p.join(name))
        .find(|p| p.exists())
        .unwrap_or(first)
}

/// Top-level elements that mean something only where they are referenced.
fn referenced_only(e: &Element) -> bool {
    matches!(e.name.as_str(), "sampler" | "film" | "rfilter")
        || (e.name == "emitter" && e.attr("type") == Some("area"))
}

/// Move the top-level [`referenced_only`] elements with an `id` to where `<ref id=…>` names
/// them.
pub fn inline_references(root: &mut Element) {
    let (defined, rest): (Vec<Element>, Vec<Element>) = std::mem::take(&mut root.children)
        .into_iter()
        .partition(|e| referenced_only(e) && e.attr("id").is_some());
    root.children = rest;
    if defined.is_empty() {
        return;
    }
    fn replace(e: &mut Element, defined: &[Element]) {
        for c in &mut e.children {
            if c.name == "ref" {
                if let Some(d) = defined.iter().find(|d| d.attr("id") == c.attr("id")) {
                    *c = d.clone();
                    continue;
                }
            }
            replace(c, defined);
        }
    }
    replace(root, &defined);
}
