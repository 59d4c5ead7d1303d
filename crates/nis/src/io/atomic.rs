//! Atomic file writes: a file is written to a temporary sibling, flushed to disk and renamed over
//! its target, so a reader (or a run killed at any instant) sees the previous file or the new
//! one, never half of one. `rename` within one directory is atomic on POSIX file systems.
//!
//! The temporary file of target `dir/NAME` is `dir/.NAME.PID-SEQ.tmp`: the writer's process id
//! and a per-process sequence number, so concurrent writers (processes or threads) never share a
//! temporary file; the last rename wins, and every rename installs a complete file.
//!
//! A process killed mid-write (SIGKILL, power loss) leaves its temporary file behind. The next
//! write to the same target removes such strays: every `.NAME.PID-SEQ.tmp` whose PID is not a
//! live process. Temporary files of live processes are left alone, since they may be writing
//! right now; a dead writer's PID reused by an unrelated process only delays its cleanup until
//! that process exits. A writer in another PID namespace (a container sharing the directory)
//! looks dead from here: its in-flight temporary file may be removed, and its rename then fails
//! with an I/O error — an error, never a damaged target.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};

/// Distinguishes the temporary files of one process's concurrent writes to the same target.
static SEQUENCE: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` atomically (see the module docs). A crash leaves either the old file
/// or the new one, never half of one.
///
/// ```
/// let path = std::env::temp_dir().join(format!("nis-doc-{}.txt", std::process::id()));
/// nis::io::write_atomic(&path, b"hello")?;
/// assert_eq!(std::fs::read(&path)?, b"hello");
/// # std::fs::remove_file(&path)?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut file = AtomicFile::create(path)?;
    file.write_all(bytes).map_err(|e| io_error(path, e))?;
    file.commit()
}

/// A file being written atomically, for outputs too big to hold in memory (streamed samples,
/// images written by an encoder): write to it (it is buffered and seekable), then
/// [`AtomicFile::commit`]. Dropped without a commit (an error, a panic), it removes its
/// temporary file and leaves the target untouched.
#[derive(Debug)]
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Starts writing `path`: removes stray temporary files of dead writers of `path` (best
    /// effort), then creates this writer's own temporary file beside it.
    pub fn create(path: &Path) -> Result<AtomicFile> {
        let name = path
            .file_name()
            .ok_or_else(|| io_error(path, io::Error::other("not a file path")))?;
        // Cleanup is a courtesy: a directory we cannot list is no reason to refuse the write.
        let _ = remove_stale_temps(path);
        let tmp = path.with_file_name(format!(
            ".{}.{}-{}.tmp",
            name.to_string_lossy(),
            std::process::id(),
            SEQUENCE.fetch_add(1, Ordering::Relaxed)
        ));
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| io_error(path, e))?;
        Ok(AtomicFile {
            path: path.to_path_buf(),
            tmp,
            file: Some(BufWriter::new(file)),
        })
    }

    /// The target this file replaces on commit.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes the data to disk and renames the temporary file over the target.
    pub fn commit(mut self) -> Result<()> {
        let file = self.file.take().expect("only commit takes the file");
        let result = (|| {
            let file = file.into_inner().map_err(io::IntoInnerError::into_error)?;
            file.sync_all()?;
            drop(file);
            fs::rename(&self.tmp, &self.path)
        })();
        if let Err(e) = result {
            let _ = fs::remove_file(&self.tmp);
            return Err(io_error(&self.path, e));
        }
        // Make the rename itself durable; some file systems cannot sync a directory, and the
        // file is already complete either way.
        if let Ok(dir) = File::open(parent(&self.path)) {
            let _ = dir.sync_all();
        }
        Ok(())
    }

    fn file(&mut self) -> &mut BufWriter<File> {
        self.file.as_mut().expect("the file is open until commit")
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.file().write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        self.file().write_all(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.file().flush()
    }
}

impl Seek for AtomicFile {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        self.file().seek(pos)
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// Removes the stray temporary files of `path` left by writers that are no longer running
/// (see the module docs); returns how many it removed. Called by every atomic write.
pub fn remove_stale_temps(path: &Path) -> io::Result<usize> {
    let Some(name) = path.file_name() else {
        return Ok(0);
    };
    let prefix = format!(".{}.", name.to_string_lossy());
    let mut removed = 0;
    for entry in fs::read_dir(parent(path))? {
        let entry = entry?;
        let file_name = entry.file_name();
        let Some(pid) = file_name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|n| n.strip_suffix(".tmp"))
            .and_then(temp_pid)
        else {
            continue;
        };
        if pid != std::process::id() && !process_is_alive(pid) {
            match fs::remove_file(entry.path()) {
                Ok(()) => removed += 1,
                // Another writer's cleanup got there first.
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            }
        }
    }
    Ok(removed)
}

/// The PID in the middle of a temporary file's name, `PID-SEQ` (or a bare `PID`, as older
/// versions wrote); anything else is not ours.
fn temp_pid(middle: &str) -> Option<u32> {
    let (pid, seq) = middle.split_once('-').unwrap_or((middle, "0"));
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if digits(pid) && digits(seq) {
        pid.parse().ok()
    } else {
        None
    }
}

/// Whether a process with this id exists (a zombie counts as alive until reaped).
#[cfg(unix)]
fn process_is_alive(pid: u32) -> bool {
    // PID 0 and negative ids address process groups, not a process: no writer had them.
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if pid <= 0 {
        return false;
    }
    // SAFETY: signal 0 delivers nothing; kill only checks that the process exists and that we
    // may signal it. It fails with ESRCH exactly when there is no such process (EPERM: it
    // exists but belongs to another user).
    let sent = unsafe { libc::kill(pid, 0) };
    sent == 0 || io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Without a portable liveness check, every writer counts as alive: strays are never removed.
#[cfg(not(unix))]
fn process_is_alive(_pid: u32) -> bool {
    true
}

fn parent(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

fn io_error(path: &Path, source: io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("nis-atomic-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// A PID that no process has: above the kernel's maximum (4194304 at most on Linux).
    const DEAD_PID: u32 = 2_000_000_000;

    #[cfg(unix)]
    #[test]
    fn stray_temps_of_dead_writers_are_removed_by_the_next_write() {
        let dir = scratch("stray");
        let path = dir.join("model.safetensors");
        let dead = [
            format!(".model.safetensors.{DEAD_PID}.tmp"),
            format!(".model.safetensors.{DEAD_PID}-7.tmp"),
        ];
        // Kept: a live writer's (our parent's) file, another target's, and look-alikes.
        let kept = [
            format!(
                ".model.safetensors.{}-0.tmp",
                std::os::unix::process::parent_id()
            ),
            format!(".other.{DEAD_PID}-0.tmp"),
            format!(".model.safetensors.x{DEAD_PID}.tmp"),
            format!(".model.safetensors.{DEAD_PID}.tmp.bak"),
            "model.safetensors.1.tmp".to_string(),
        ];
        for n in dead.iter().chain(&kept) {
            fs::write(dir.join(n), b"partial").unwrap();
        }
        write_atomic(&path, b"new").unwrap();
        let mut expected: Vec<String> = kept.to_vec();
        expected.push("model.safetensors".into());
        expected.sort();
        assert_eq!(names(&dir), expected);
        assert_eq!(fs::read(&path).unwrap(), b"new");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_uncommitted_file_leaves_the_target_untouched_and_no_temp() {
        let dir = scratch("drop");
        let path = dir.join("samples.csv");
        write_atomic(&path, b"old").unwrap();
        {
            let mut f = AtomicFile::create(&path).unwrap();
            f.write_all(b"half of the new").unwrap();
            f.flush().unwrap();
            assert_eq!(names(&dir).len(), 2);
        }
        assert_eq!(names(&dir), ["samples.csv"]);
        assert_eq!(fs::read(&path).unwrap(), b"old");
        // Streaming with seeks: a header patched after the body.
        let mut f = AtomicFile::create(&path).unwrap();
        f.write_all(b"....body").unwrap();
        f.seek(SeekFrom::Start(0)).unwrap();
        f.write_all(b"HEAD").unwrap();
        f.commit().unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"HEADbody");
        assert_eq!(names(&dir), ["samples.csv"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn concurrent_writers_of_one_target_each_install_a_whole_file() {
        let dir = scratch("threads");
        let path = dir.join("out.bin");
        std::thread::scope(|s| {
            for t in 0..4u8 {
                let path = &path;
                s.spawn(move || {
                    for _ in 0..20 {
                        write_atomic(path, &[t; 4096]).unwrap();
                    }
                });
            }
        });
        let bytes = fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 4096);
        assert!(bytes.iter().all(|&b| b == bytes[0]));
        assert_eq!(names(&dir), ["out.bin"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn errors_name_the_target() {
        let err = write_atomic(Path::new("/nonexistent-dir/x.json"), b"{}").unwrap_err();
        assert!(err.to_string().contains("/nonexistent-dir/x.json"), "{err}");
        assert!(write_atomic(Path::new("/"), b"").is_err());
        assert_eq!(temp_pid("12-3"), Some(12));
        assert_eq!(temp_pid("12"), Some(12));
        assert_eq!(temp_pid("12-"), None);
        assert_eq!(temp_pid("a.12"), None);
    }
}
