//! The writers of `docs/`: benchmark results go into a tagged section of a Markdown file
//! (`<!-- key:start -->` … `<!-- key:end -->`), keeping the other sections, with the machine they
//! ran on.

use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};

/// A one-line description of this machine: CPU model, logical cores, date.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let date = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    format!("{cpu}, {cores} logical cores, {date}")
}

/// Replaces (or appends) the section tagged `key` in `path` with `body`, atomically.
pub fn write_section(path: &Path, key: &str, title: &str, body: &str) -> Result<()> {
    let old = std::fs::read_to_string(path).unwrap_or_else(|_| "# Benchmarks\n".into());
    let (start, end) = (
        format!("<!-- {key}:start -->"),
        format!("<!-- {key}:end -->"),
    );
    let section = format!(
        "{start}\n## {title}\n\nMachine: {}.\n\n{body}\n{end}",
        machine()
    );
    let new = match (old.find(&start), old.find(&end)) {
        (Some(a), Some(b)) if a < b => format!("{}{section}{}", &old[..a], &old[b + end.len()..]),
        _ => format!("{}\n{section}\n", old.trim_end()),
    };
    write_file(path, new.as_bytes())
}

/// Creates `dir` and its parents.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })
}

/// Writes `bytes` to `path` atomically, creating its directory.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent() {
        create_dir(dir)?;
    }
    Ok(nis::io::write_atomic(path, bytes)?)
}

/// `path` relative to the directory of the Markdown file `docs`, for links inside it (with `..`
/// where `path` is outside that directory; `path` as given where the two share no root).
pub fn relative_to(docs: &Path, path: &Path) -> String {
    let dir = docs.parent().unwrap_or(Path::new(""));
    if let Ok(inside) = path.strip_prefix(dir) {
        return inside.display().to_string();
    }
    let named = |c: &Component| matches!(c, Component::Normal(_));
    let (a, b): (Vec<Component>, Vec<Component>) =
        (dir.components().collect(), path.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let rooted = |c: &[Component]| c.first().is_some_and(|c| !named(c));
    if rooted(&a) != rooted(&b) || !a[common..].iter().all(named) {
        return path.display().to_string();
    }
    let mut out: PathBuf = a[common..].iter().map(|_| "..").collect();
    out.extend(&b[common..]);
    out.display().to_string()
}

/// The folder of the figures of the Markdown file `docs`: `img/` beside it, or beside its folder
/// when that is `results` (the figures of `docs/results/*.md` live in `docs/img`).
pub fn images_dir(docs: &Path) -> PathBuf {
    let dir = docs.parent().unwrap_or(Path::new(""));
    match dir.file_name() {
        Some(name) if name == "results" => dir.parent().unwrap_or(Path::new("")).join("img"),
        _ => dir.join("img"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_section_is_replaced_in_place_and_others_are_kept() {
        let dir = std::env::temp_dir().join(format!("nis-report-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("B.md");
        std::fs::write(&path, "# Benchmarks\n\nintro\n").unwrap();
        write_section(&path, "a", "A", "first").unwrap();
        write_section(&path, "b", "B", "other").unwrap();
        write_section(&path, "a", "A", "second").unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("# Benchmarks\n\nintro\n"));
        assert!(text.contains("second") && !text.contains("first") && text.contains("other"));
        assert!(text.find("second").unwrap() < text.find("other").unwrap());
        assert_eq!(
            relative_to(&dir.join("B.md"), &dir.join("img/x.png")),
            "img/x.png"
        );
        let docs = Path::new("docs/results/integration.md");
        assert_eq!(images_dir(docs), Path::new("docs/img"));
        assert_eq!(
            relative_to(docs, &images_dir(docs).join("x.png")),
            "../img/x.png"
        );
        assert_eq!(images_dir(&dir.join("B.md")), dir.join("img"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
