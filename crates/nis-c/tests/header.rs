//! The committed header `include/nis.h` is what cbindgen makes of the crate now; with
//! `NIS_UPDATE_HEADER=1` this test writes it instead.

use std::path::Path;

#[test]
fn committed_header_is_up_to_date() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).unwrap();
    // cbindgen writes no string constants: the version string is added here, from the crate's.
    config.after_includes = Some(format!(
        "\n/**\n * The version as a string, \"MAJOR.MINOR.PATCH\".\n */\n#define NIS_VERSION_STRING \"{}\"",
        nis_c::NIS_VERSION_STRING
    ));
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_crate(crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen parses the crate")
        .write(&mut generated);
    let generated = String::from_utf8(generated).unwrap();
    let path = crate_dir.join("include/nis.h");
    if std::env::var_os("NIS_UPDATE_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "include/nis.h is out of date: run NIS_UPDATE_HEADER=1 cargo test --release -p nis-c --test header"
    );
}
