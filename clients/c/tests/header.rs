//! `include/outlet_client.h` is what cbindgen makes of `src/lib.rs` now: the
//! committed header can never go stale. Run with `OUTLET_BLESS=1` to rewrite it.

use std::path::Path;

#[test]
fn committed_header_matches_the_generated_one() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("reading cbindgen.toml");
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_config(config)
        .with_src(crate_dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen could not generate the header")
        .write(&mut generated);
    let generated = String::from_utf8(generated).expect("the header is UTF-8");

    let path = crate_dir.join("include/outlet_client.h");
    if std::env::var_os("OUTLET_BLESS").is_some() {
        std::fs::write(&path, &generated).expect("writing the header");
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "{} is stale: it differs from what cbindgen makes of src/lib.rs.\n\
         Regenerate it with\n    OUTLET_BLESS=1 cargo test -p outlet-client-c --test header\n\
         and commit it.\n--- generated ---\n{generated}",
        path.display()
    );
}
