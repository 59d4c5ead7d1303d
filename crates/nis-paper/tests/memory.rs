//! The peak RSS of `nis bench memory` is that of each child alone. This lives in its own test
//! binary: on Linux a child's figure includes the peak of the process that spawned it, so the
//! spawner must be small and must not run other tests' allocations beside this one.

#![cfg(unix)]

use std::path::Path;

use nis_paper::bench::memory::measure;

#[test]
fn peak_rss_is_that_of_the_child_alone() {
    // A shell that holds ~64 MiB in a variable, then one that holds almost nothing: the
    // second figure must not inherit the first (RUSAGE_CHILDREN would).
    let log = std::env::temp_dir().join(format!("nis-memory-{}.log", std::process::id()));
    let sh = Path::new("/bin/sh");
    let big = measure(
        sh,
        &[
            "-c".into(),
            "x=$(head -c 67108864 /dev/zero | tr '\\0' a); echo ${#x} >&2".into(),
        ],
        &log,
    )
    .unwrap();
    let small = measure(sh, &["-c".into(), "true".into()], &log).unwrap();
    assert!(big.peak_rss > 64 << 20, "{}", big.peak_rss);
    assert!(small.peak_rss < 16 << 20, "{}", small.peak_rss);
    let err = measure(sh, &["-c".into(), "echo boom >&2; exit 3".into()], &log).unwrap_err();
    assert!(err.to_string().contains("boom"), "{err}");
    std::fs::remove_file(&log).unwrap();
}
