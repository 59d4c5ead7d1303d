//! The C and Fortran programs, compiled against the static library and run: the C examples
//! (`examples/quickstart.c`, the docs' example, also linked against the shared library with an
//! rpath; `examples/camel.c`), the C test of the error paths (`tests/c/errors.c`), the header
//! under a C++ compiler, and the Fortran example (`examples/fortran/`) when `gfortran` is on
//! PATH.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

/// `target/<profile>`, where cargo put `libnis_c.a` when it built this test.
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    // target/<profile>/deps/c_programs-<hash>
    exe.parent().unwrap().parent().unwrap().to_path_buf()
}

fn crate_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The static library cargo built with this test: in `deps/` (where rustc writes it) or uplifted
/// beside it, whichever is newer (cargo does not uplift again a file deleted after a fresh build).
fn static_lib() -> PathBuf {
    let dir = lib_dir();
    [dir.join("libnis_c.a"), dir.join("deps/libnis_c.a")]
        .into_iter()
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max()
        .map(|(_, p)| p)
        .unwrap_or_else(|| {
            panic!(
                "no libnis_c.a in {}: cargo builds it with the tests (crate-type staticlib)",
                dir.display()
            )
        })
}

/// The shared library cargo built with this test (`deps/` or uplifted, the newer, as
/// [`static_lib`]); `None` when cargo built none.
fn shared_lib() -> Option<PathBuf> {
    let dir = lib_dir();
    [dir.join("libnis_c.so"), dir.join("deps/libnis_c.so")]
        .into_iter()
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max()
        .map(|(_, p)| p)
}

/// Says on the terminal that a test skipped a part: straight to stderr, since the harness
/// captures `println!` and hides it for a passing test.
fn skipped(message: &str) {
    let _ = writeln!(std::io::stderr(), "skipped: {message}");
}

fn on_path(tool: &str) -> bool {
    Command::new(tool).arg("--version").output().is_ok()
}

/// Runs a command, panicking with its output unless it succeeds; returns its stdout.
fn run(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Compiles C sources into an executable linked with the static library.
fn compile_c(sources: &[PathBuf], name: &str) -> PathBuf {
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    run(Command::new("cc")
        .args([
            "-std=c11",
            "-O2",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-D_DEFAULT_SOURCE",
        ])
        .arg("-I")
        .arg(crate_dir().join("include"))
        .args(sources)
        .arg(static_lib())
        .args(["-lm", "-lpthread", "-ldl", "-o"])
        .arg(&exe));
    exe
}

#[test]
fn c_quickstart_example_integrates_to_one() {
    let exe = compile_c(&[crate_dir().join("examples/quickstart.c")], "quickstart");
    let out = run(&mut Command::new(&exe));
    println!("{out}");
    assert!(out.contains("quickstart: ok"), "{out}");
}

/// The README and the guide show `examples/quickstart.c` as it is (from its first `#include`
/// on), so the program they show is the one compiled above.
#[test]
fn docs_show_the_quickstart_example_as_compiled() {
    let source = std::fs::read_to_string(crate_dir().join("examples/quickstart.c")).unwrap();
    let program = &source[source.find("#include").unwrap()..];
    for doc in ["../../README.md", "../../docs/guide/02-integrate.md"] {
        let text = std::fs::read_to_string(crate_dir().join(doc)).unwrap();
        assert!(
            text.contains(&format!("```c\n{program}```")),
            "{doc} must show examples/quickstart.c from its first #include on, unchanged"
        );
    }
}

/// The docs' route to the shared library: `-L dir -lnis_c -Wl,-rpath,dir`, run without
/// LD_LIBRARY_PATH.
#[test]
fn c_quickstart_links_the_shared_library_with_an_rpath() {
    let Some(lib) = shared_lib() else {
        skipped("no libnis_c.so beside the test (cargo builds it with crate-type cdylib)");
        return;
    };
    let dir = lib.parent().unwrap();
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("quickstart_shared");
    let mut rpath = std::ffi::OsString::from("-Wl,-rpath,");
    rpath.push(dir);
    run(Command::new("cc")
        .args(["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(crate_dir().join("include"))
        .arg(crate_dir().join("examples/quickstart.c"))
        .arg("-L")
        .arg(dir)
        .arg(rpath)
        .args(["-lnis_c", "-lm", "-o"])
        .arg(&exe));
    let out = run(Command::new(&exe).env_remove("LD_LIBRARY_PATH"));
    assert!(out.contains("quickstart: ok"), "{out}");
}

#[test]
fn c_camel_example_matches_the_exact_value() {
    let exe = compile_c(&[crate_dir().join("examples/camel.c")], "camel");
    let out = run(&mut Command::new(&exe));
    println!("{out}");
    assert!(out.contains("camel: ok"), "{out}");
}

#[test]
fn c_error_paths_report_their_codes() {
    let exe = compile_c(&[crate_dir().join("tests/c/errors.c")], "errors");
    let out = run(&mut Command::new(&exe));
    println!("{out}");
    assert!(out.contains(", 0 failed"), "{out}");
    // No leak on any path, where valgrind is installed (memcheck; only definite leaks count,
    // since the thread pool's threads stay reachable until exit by design).
    if on_path("valgrind") {
        run(Command::new("valgrind")
            .args([
                "--quiet",
                "--error-exitcode=9",
                "--leak-check=full",
                "--errors-for-leak-kinds=definite",
                "--show-leak-kinds=definite",
            ])
            .arg(&exe));
    } else {
        skipped("valgrind not on PATH: the leak check of the error paths");
    }
}

#[test]
fn header_compiles_as_cpp() {
    if !on_path("c++") {
        skipped("c++ not on PATH: the header under C++");
        return;
    }
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("header_cpp");
    run(Command::new("c++")
        .args(["-std=c++17", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(crate_dir().join("include"))
        .arg(crate_dir().join("tests/c/header.cpp"))
        .arg(static_lib())
        .args(["-lm", "-lpthread", "-ldl", "-o"])
        .arg(&exe));
    let out = run(&mut Command::new(&exe));
    assert!(out.contains("c++: ok"), "{out}");
}

#[test]
fn fortran_example_with_save_state_integrates() {
    if !on_path("gfortran") {
        skipped("gfortran not on PATH: the Fortran example (scripts/setup/install-system-deps.sh installs it)");
        return;
    }
    let dir = crate_dir().join("examples/fortran");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fortran");
    std::fs::create_dir_all(&out_dir).unwrap();
    let exe = out_dir.join("gauss");
    run(Command::new("gfortran")
        .args(["-O2", "-Wall", "-Werror", "-std=f2008", "-J"])
        .arg(&out_dir)
        .arg(dir.join("nis.f90"))
        .arg(dir.join("gauss.f90"))
        .arg(static_lib())
        .args(["-lm", "-lpthread", "-ldl", "-o"])
        .arg(&exe));
    let out = run(&mut Command::new(&exe));
    println!("{out}");
    assert!(out.contains("fortran: ok"), "{out}");
}
