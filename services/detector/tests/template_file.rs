//! Template files: a truncated, corrupted or too-new file is refused with an
//! error that names the file and says what is wrong; inputs the fuzzer found
//! (`fuzz/`, target `template`) stay fixed.

use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::template::{TEMPLATE_FORMAT_VERSION, Template, TemplateError};
use std::path::{Path, PathBuf};

const REGRESSIONS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fuzz_regressions/template");
/// Header: magic (8), version (4), payload length (8), CRC-32 (4).
const HEADER_LEN: usize = 24;

/// A small but complete template file (2x2 crops, one PCA dimension).
fn tiny() -> Vec<u8> {
    std::fs::read(Path::new(REGRESSIONS).join("tiny-valid.template")).expect("fixture")
}

/// A scratch directory of this test process.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("outlet-template-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Writes `bytes` to `dir/name` and reads it as a template: the error and its message.
fn read_error(dir: &Path, name: &str, bytes: &[u8]) -> (TemplateError, String) {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write");
    let err = Template::read(&path).expect_err("must be refused");
    let message = err.to_string();
    assert!(message.contains(&path.display().to_string()), "the message names the file: {message}");
    (err, message)
}

#[test]
fn the_fixture_reads_and_writes_back_identically() {
    let template = Template::from_bytes(&tiny(), "tiny-valid.template").expect("a valid template");
    assert_eq!(template.name, "tiny");
    assert_eq!(template.to_bytes().expect("encode"), tiny());
    let dir = scratch("roundtrip");
    let path = dir.join("copy.template");
    template.write(&path).expect("write");
    assert_eq!(Template::read(&path).expect("read back"), template);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn truncated_file_is_named_and_says_how_much_is_missing() {
    let bytes = tiny();
    let dir = scratch("truncated");
    // Cut anywhere: in the magic, the header, the payload; empty.
    for len in [0, 5, 8, 12, 20, HEADER_LEN, HEADER_LEN + 1, bytes.len() / 2, bytes.len() - 1] {
        let (err, msg) = read_error(&dir, "cut.template", &bytes[..len]);
        assert!(matches!(err, TemplateError::Truncated { .. }), "{len} bytes: {msg}");
        assert!(msg.contains("truncated") && msg.contains(&format!("{len} of ")), "{len} bytes: {msg}");
    }
    let (_, msg) = read_error(&dir, "half.template", &bytes[..bytes.len() / 2]);
    assert!(msg.contains(&format!("of {} bytes", bytes.len())), "the full size is given: {msg}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn corrupted_file_fails_its_checksum() {
    let bytes = tiny();
    let dir = scratch("corrupted");
    for at in [HEADER_LEN, HEADER_LEN + 7, bytes.len() / 2, bytes.len() - 1] {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x10;
        let (err, msg) = read_error(&dir, "flipped.template", &damaged);
        assert!(matches!(err, TemplateError::Checksum { .. }), "byte {at}: {msg}");
        assert!(msg.contains("corrupted") && msg.contains("checksum"), "{msg}");
    }
    // A damaged checksum field is the same finding.
    let mut damaged = bytes.clone();
    damaged[20] ^= 0x01;
    let (err, _) = read_error(&dir, "crc.template", &damaged);
    assert!(matches!(err, TemplateError::Checksum { .. }));
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn too_new_file_names_its_version_and_ours() {
    let dir = scratch("version");
    for version in [TEMPLATE_FORMAT_VERSION + 1, 7, u32::MAX] {
        let mut bytes = tiny();
        bytes[8..12].copy_from_slice(&version.to_le_bytes());
        let (err, msg) = read_error(&dir, "new.template", &bytes);
        assert!(matches!(err, TemplateError::TooNew { found, .. } if found == version), "{msg}");
        assert!(msg.contains(&format!("format version {version}")), "{msg}");
        assert!(msg.contains(&format!("reads up to {TEMPLATE_FORMAT_VERSION}")), "{msg}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn other_files_are_not_templates() {
    let dir = scratch("other");
    for bytes in [&b"ply\nformat ascii 1.0\n"[..], b"OUTLETTQ and more bytes than a header", &[0u8; 64]] {
        let (err, msg) = read_error(&dir, "other.template", bytes);
        assert!(matches!(err, TemplateError::NotATemplate { .. }), "{msg}");
        assert!(msg.contains("not an outlet template file"), "{msg}");
    }
    let missing = dir.join("missing.template");
    let err = Template::read(&missing).expect_err("no such file");
    assert!(matches!(err, TemplateError::Io { .. }) && err.to_string().contains("missing.template"), "{err}");
    let _ = std::fs::remove_dir_all(dir);
}

/// What the fuzzer found, fixed: each input must be refused or loaded without
/// a panic, and what loads must detect.
#[test]
fn fuzz_regressions_are_refused_or_loaded_without_panic() {
    let mut seen = 0;
    for entry in std::fs::read_dir(REGRESSIONS).expect("regression directory") {
        let path = entry.expect("entry").path();
        let bytes = std::fs::read(&path).expect("read");
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_owned();
        seen += 1;
        match Template::from_bytes(&bytes, &name) {
            Ok(template) => {
                assert_eq!(name, "tiny-valid.template", "{name} must be refused");
                let detector = Detector::new(template, DetectorParams::default());
                let image = image::RgbImage::from_fn(40, 30, |x, y| image::Rgb([((x * 7) ^ (y * 5)) as u8; 3]));
                let _ = detector.detect(&image, None);
            }
            Err(err) => {
                let msg = err.to_string();
                assert!(msg.contains(&name), "{msg}");
                match name.as_str() {
                    // A length field near u64::MAX overflowed the expected size.
                    "header-length-overflow" => {
                        assert!(matches!(err, TemplateError::Truncated { expected: u64::MAX, .. }), "{msg}")
                    }
                    // A NaN in the PCA mean (valid checksum) loaded, and broke every distance.
                    "nan-in-pca-mean.template" => {
                        assert!(matches!(err, TemplateError::Invalid { .. }) && msg.contains("not finite"), "{msg}")
                    }
                    // An infinite scale range made `scale_ladder` loop without end.
                    "infinite-scale-range.template" => {
                        assert!(matches!(err, TemplateError::Invalid { .. }) && msg.contains("test scales"), "{msg}")
                    }
                    other => panic!("{other}: {msg}"),
                }
            }
        }
    }
    assert!(seen >= 4, "the regression inputs are there");
}
