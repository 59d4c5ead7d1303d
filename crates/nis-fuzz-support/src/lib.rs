//! What the fuzz tests of every reader of outside data share: a counting global allocator, the
//! per-case limits, the case count, and byte-level mutations. A dev-only crate: the
//! `tests/fuzz_readers.rs` of `nis`, `nis-render` and `nis-paper` depend on it, and each installs
//! [`Counting`] as its `#[global_allocator]`.
//!
//! The promise checked for every case: the reader returns a typed error or a valid value — no
//! panic (proptest reports a panic as a failing case and shrinks it), no more than
//! [`BASE_ALLOWANCE`] plus [`SIZE_FACTOR`]× the input's (decompressed) size live at the peak of
//! the case, and no case longer than [`MAX_CASE`]. Tests of one binary take a lock
//! ([`exclusive`]) so that the global counts belong to one case at a time.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError};

/// Live bytes allowed in any case whatever its input (the 64 MiB).
pub const BASE_ALLOWANCE: usize = 64 << 20;
/// Live bytes allowed per byte of input (its decompressed size where it has one).
pub const SIZE_FACTOR: usize = 16;
/// The longest one case may take.
pub const MAX_CASE: Duration = Duration::from_secs(10);

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// Allocations that would take the live bytes past this fail (the process then aborts with
/// "memory allocation of N bytes failed"): a reader that asks for a terabyte must not take
/// the machine with it before the case can be judged. Off (`usize::MAX`) outside cases.
static REFUSE_ABOVE: AtomicUsize = AtomicUsize::new(usize::MAX);

/// The system allocator, counting live bytes and their peak.
pub struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !reserve(layout.size()) {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !reserve(layout.size()) {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let old = layout.size();
        if new_size > old && !reserve(new_size - old) {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        match (p.is_null(), new_size > old) {
            (true, true) => {
                LIVE.fetch_sub(new_size - old, Ordering::Relaxed);
            }
            (false, false) => {
                LIVE.fetch_sub(old - new_size, Ordering::Relaxed);
            }
            _ => {}
        }
        p
    }
}

/// Counts `size` more live bytes unless that passes [`REFUSE_ABOVE`]; updates the peak.
fn reserve(size: usize) -> bool {
    let live = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    if live > REFUSE_ABOVE.load(Ordering::Relaxed) {
        LIVE.fetch_sub(size, Ordering::Relaxed);
        return false;
    }
    PEAK.fetch_max(live, Ordering::Relaxed);
    true
}

static EXCLUSIVE: Mutex<()> = Mutex::new(());

/// Held for a whole fuzz test, so that no other test of the binary allocates during its cases.
pub fn exclusive() -> MutexGuard<'static, ()> {
    EXCLUSIVE
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Cases per fuzz target: `NIS_FUZZ_CASES` when set (the long run of `scripts/test/fuzz.sh`), else
/// `default` (the normal test run).
pub fn cases(default: u32) -> u32 {
    match std::env::var("NIS_FUZZ_CASES") {
        Ok(v) => v
            .parse()
            .unwrap_or_else(|_| panic!("NIS_FUZZ_CASES={v:?} is not a number of cases")),
        Err(_) => default,
    }
}

/// proptest's settings for a target: `cases(default)` cases, a fixed seed (the same cases on
/// every run, whatever the machine), no regression files written next to the sources.
pub fn config(default: u32) -> Config {
    Config {
        cases: cases(default),
        failure_persistence: None,
        rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha,
        rng_seed: proptest::test_runner::RngSeed::Fixed(16),
        max_shrink_iters: 2000,
        ..Config::default()
    }
}

/// A runner of `cases(default)` cases from the fixed seed.
pub fn runner(default: u32) -> proptest::test_runner::TestRunner {
    proptest::test_runner::TestRunner::new(config(default))
}

/// Runs `strategy`'s cases through `test`, then prints the tally; panics on the first failing
/// case, shrunk to its smallest form.
pub fn fuzz<S: Strategy>(
    target: &str,
    default_cases: u32,
    strategy: S,
    test: impl Fn(&std::cell::RefCell<Tally>, S::Value) -> Result<(), TestCaseError>,
) {
    let _lock = exclusive();
    let tally = std::cell::RefCell::new(Tally::default());
    let result = runner(default_cases).run(&strategy, |input| test(&tally, input));
    tally.borrow().report(target);
    if let Err(e) = result {
        panic!("fuzz {target}: {e}");
    }
}

/// What one target saw: how many inputs were accepted, rejected with an error, and the
/// largest peak of live bytes above the baseline.
#[derive(Debug, Default)]
pub struct Tally {
    pub accepted: usize,
    pub rejected: usize,
    pub peak: usize,
}

impl Tally {
    /// Prints the tally (shown with `--nocapture`; `scripts/test/fuzz.sh` collects these lines).
    pub fn report(&self, target: &str) {
        println!(
            "fuzz {target}: {} cases, {} accepted, {} rejected with an error, peak {:.1} MiB",
            self.accepted + self.rejected,
            self.accepted,
            self.rejected,
            self.peak as f64 / (1 << 20) as f64
        );
    }
}

/// Runs one case of a reader: `read` returns `Ok` or a typed error (a panic fails the case);
/// the case fails when it takes longer than [`MAX_CASE`] or when the peak of live bytes during
/// it exceeds `BASE_ALLOWANCE + SIZE_FACTOR · max(input_len, decoded_len(value))`, where
/// `decoded_len` is the size of what an accepted input decodes to (0 for an error).
pub fn check<T, E: std::fmt::Display>(
    tally: &std::cell::RefCell<Tally>,
    input_len: usize,
    read: impl FnOnce() -> Result<T, E>,
    decoded_len: impl FnOnce(&T) -> usize,
) -> Result<Result<T, E>, TestCaseError> {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    // Far above the allowance, so that moderate excesses are reported (and shrunk) as failing
    // cases and only absurd requests abort.
    REFUSE_ABOVE.store(
        base + 4 * (BASE_ALLOWANCE + SIZE_FACTOR * input_len) + (1 << 30),
        Ordering::Relaxed,
    );
    let start = Instant::now();
    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(read));
    let elapsed = start.elapsed();
    REFUSE_ABOVE.store(usize::MAX, Ordering::Relaxed);
    let peak = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    let out = match out {
        Ok(out) => out,
        Err(panic) => {
            let message = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            return Err(TestCaseError::fail(format!(
                "the reader panicked: {message}"
            )));
        }
    };
    let decoded = out.as_ref().map_or(0, decoded_len);
    let cap = BASE_ALLOWANCE + SIZE_FACTOR * input_len.max(decoded);
    let mut t = tally.borrow_mut();
    t.peak = t.peak.max(peak);
    match &out {
        Ok(_) => t.accepted += 1,
        Err(_) => t.rejected += 1,
    }
    prop_assert!(
        peak <= cap,
        "peak of {peak} live bytes, more than {cap} for {input_len} bytes of input ({})",
        match &out {
            Ok(_) => "accepted".to_string(),
            Err(e) => format!("rejected: {e}"),
        }
    );
    prop_assert!(elapsed <= MAX_CASE, "the case took {elapsed:?}");
    Ok(out)
}

/// One byte-level edit of a file (positions and lengths are taken modulo the file's size).
#[derive(Clone, Debug)]
pub enum Edit {
    /// Flip one bit.
    FlipBit(usize, u8),
    /// Overwrite a byte with a value that parsers treat specially.
    SetByte(usize, u8),
    /// Cut the file here.
    Truncate(usize),
    /// Insert random bytes.
    Insert(usize, Vec<u8>),
    /// Remove a range.
    Delete(usize, usize),
    /// Repeat a range right after itself.
    Duplicate(usize, usize),
}

/// A random edit; `SetByte` picks from the values that end, start or overflow things.
pub fn edit() -> impl Strategy<Value = Edit> {
    let special = prop_oneof![
        Just(0u8),
        Just(0xff),
        Just(0x7f),
        Just(0x80),
        Just(b'<'),
        Just(b'>'),
        Just(b'"'),
        Just(b'\n'),
        Just(b'9'),
        Just(b'-'),
        any::<u8>()
    ];
    prop_oneof![
        3 => (any::<usize>(), 0u8..8).prop_map(|(p, b)| Edit::FlipBit(p, b)),
        2 => (any::<usize>(), special).prop_map(|(p, v)| Edit::SetByte(p, v)),
        1 => any::<usize>().prop_map(Edit::Truncate),
        1 => (any::<usize>(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(p, b)| Edit::Insert(p, b)),
        1 => (any::<usize>(), 1usize..64).prop_map(|(p, n)| Edit::Delete(p, n)),
        1 => (any::<usize>(), 1usize..64).prop_map(|(p, n)| Edit::Duplicate(p, n)),
    ]
}

/// Applies `edits` in order.
pub fn apply(mut bytes: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for e in edits {
        let n = bytes.len();
        if n == 0 {
            if let Edit::Insert(_, b) = e {
                bytes.extend_from_slice(b);
            }
            continue;
        }
        match e {
            Edit::FlipBit(p, b) => bytes[p % n] ^= 1 << b,
            Edit::SetByte(p, v) => bytes[p % n] = *v,
            Edit::Truncate(p) => bytes.truncate(p % n),
            Edit::Insert(p, b) => {
                let at = p % (n + 1);
                bytes.splice(at..at, b.iter().copied());
            }
            Edit::Delete(p, len) => {
                let at = p % n;
                bytes.drain(at..(at + len).min(n));
            }
            Edit::Duplicate(p, len) => {
                let at = p % n;
                let piece = bytes[at..(at + len).min(n)].to_vec();
                let end = at + piece.len();
                bytes.splice(end..end, piece);
            }
        }
    }
    bytes
}

/// `original` with 1 to `max_edits` random edits.
pub fn mutated(original: Vec<u8>, max_edits: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(edit(), 1..=max_edits)
        .prop_map(move |edits| apply(original.clone(), &edits))
}

/// A unique scratch directory for one test binary's files.
pub fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-fuzz-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch directory");
    dir
}

/// JSON values of every kind, nested a little.
pub fn json_value() -> impl Strategy<Value = serde_json::Value> {
    let leaf = prop_oneof![
        Just(serde_json::Value::Null),
        any::<bool>().prop_map(serde_json::Value::from),
        any::<i64>().prop_map(serde_json::Value::from),
        any::<u64>().prop_map(serde_json::Value::from),
        prop::sample::select(vec![0.0, -1.0, 1e12, 1e300, -0.0, 0.5, 1e-300])
            .prop_map(serde_json::Value::from),
        "[a-z_]{0,12}".prop_map(serde_json::Value::from),
    ];
    leaf.prop_recursive(3, 16, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(serde_json::Value::from),
            prop::collection::btree_map("[a-z_]{1,10}", inner, 0..4)
                .prop_map(|m| serde_json::Value::Object(m.into_iter().collect())),
        ]
    })
}
