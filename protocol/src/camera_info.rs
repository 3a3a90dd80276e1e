//! ROS `camera_info` YAML, as written by ROS `camera_calibration`.
//!
//! Only the intrinsics and the `plumb_bob` distortion make a [`CameraModel`];
//! `camera_name`, the rectification and the projection matrices are checked for
//! shape when present and otherwise ignored.

use std::fmt::{self, Write as _};
use std::path::{Path, PathBuf};

use serde::Deserialize;
use serde::de::{Deserializer, Visitor};

use crate::camera::{CameraError, CameraModel};

/// Why a camera_info YAML was refused.
#[derive(Debug, thiserror::Error)]
pub enum CameraInfoError {
    #[error("camera_info is not valid YAML of the expected shape: {0}")]
    Yaml(String),
    #[error("camera_info has no `{key}`")]
    MissingKey { key: String },
    #[error("camera_info `{key}` value {value:?} is not a number")]
    NotANumber { key: String, value: String },
    #[error("camera_info `{key}` = {value} is not a non-negative integer")]
    NotAnInteger { key: String, value: f64 },
    #[error("camera_info `{key}` is {rows}x{cols} with {len} values; expected {expected}")]
    MatrixSize { key: &'static str, rows: u32, cols: u32, len: usize, expected: String },
    #[error("camera_info `camera_matrix` {0:?} is not of the form [fx 0 cx; 0 fy cy; 0 0 1]")]
    NotPinhole([f64; 9]),
    #[error(
        "unsupported distortion model {model:?} with coefficients {coefficients:?} \
         (plumb_bob with 5, or rational_polynomial whose k4..k6 are zero)"
    )]
    UnsupportedDistortion { model: String, coefficients: Vec<f64> },
    #[error("camera_info describes an invalid camera: {0}")]
    Camera(CameraError),
    #[error("cannot read {}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{}: {error}", path.display())]
    InFile { path: PathBuf, error: Box<CameraInfoError> },
}

/// A YAML scalar as written, so that a non-number can be named in the error.
enum Scalar {
    Number(f64),
    Other(String),
}

impl<'de> Deserialize<'de> for Scalar {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct ScalarVisitor;
        impl Visitor<'_> for ScalarVisitor {
            type Value = Scalar;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number")
            }
            fn visit_f64<E>(self, v: f64) -> Result<Scalar, E> {
                Ok(Scalar::Number(v))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Scalar, E> {
                Ok(Scalar::Number(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Scalar, E> {
                Ok(Scalar::Number(v as f64))
            }
            fn visit_bool<E>(self, v: bool) -> Result<Scalar, E> {
                Ok(Scalar::Other(v.to_string()))
            }
            fn visit_str<E>(self, v: &str) -> Result<Scalar, E> {
                Ok(Scalar::Other(v.to_owned()))
            }
            fn visit_unit<E>(self) -> Result<Scalar, E> {
                Ok(Scalar::Other("null".to_owned()))
            }
            fn visit_none<E>(self) -> Result<Scalar, E> {
                Ok(Scalar::Other("null".to_owned()))
            }
        }
        deserializer.deserialize_any(ScalarVisitor)
    }
}

#[derive(Deserialize)]
struct RawMatrix {
    rows: Option<Scalar>,
    cols: Option<Scalar>,
    data: Option<Vec<Scalar>>,
}

/// The file as written; every key optional so that a missing one is named.
#[derive(Deserialize)]
struct RawCameraInfo {
    image_width: Option<Scalar>,
    image_height: Option<Scalar>,
    camera_matrix: Option<RawMatrix>,
    distortion_model: Option<String>,
    distortion_coefficients: Option<RawMatrix>,
    rectification_matrix: Option<RawMatrix>,
    projection_matrix: Option<RawMatrix>,
}

fn number(scalar: Option<&Scalar>, key: impl Fn() -> String) -> Result<f64, CameraInfoError> {
    match scalar {
        Some(Scalar::Number(v)) => Ok(*v),
        Some(Scalar::Other(value)) => Err(CameraInfoError::NotANumber { key: key(), value: value.clone() }),
        None => Err(CameraInfoError::MissingKey { key: key() }),
    }
}

fn integer(scalar: Option<&Scalar>, key: impl Fn() -> String) -> Result<u32, CameraInfoError> {
    let value = number(scalar, &key)?;
    if value >= 0.0 && value <= u32::MAX as f64 && value.fract() == 0.0 {
        Ok(value as u32)
    } else {
        Err(CameraInfoError::NotAnInteger { key: key(), value })
    }
}

impl RawMatrix {
    /// The data, checked against `rows`/`cols` and, when given, a required shape.
    fn values(&self, key: &'static str, shape: Option<(u32, u32)>) -> Result<Vec<f64>, CameraInfoError> {
        let rows = integer(self.rows.as_ref(), || format!("{key}.rows"))?;
        let cols = integer(self.cols.as_ref(), || format!("{key}.cols"))?;
        let data = self.data.as_ref().ok_or_else(|| CameraInfoError::MissingKey { key: format!("{key}.data") })?;
        let data: Vec<f64> = data
            .iter()
            .enumerate()
            .map(|(i, s)| number(Some(s), || format!("{key}.data[{i}]")))
            .collect::<Result<_, _>>()?;
        let shape_ok = shape.is_none_or(|s| s == (rows, cols));
        if !shape_ok || rows as u64 * cols as u64 != data.len() as u64 {
            let expected = match shape {
                Some((r, c)) => format!("{r}x{c} with {} values", r * c),
                None => "rows*cols values".to_owned(),
            };
            return Err(CameraInfoError::MatrixSize { key, rows, cols, len: data.len(), expected });
        }
        Ok(data)
    }
}

/// plumb_bob `[k1, k2, p1, p2, k3]` from the model name and its coefficients.
fn plumb_bob(model: Option<&str>, coefficients: Vec<f64>) -> Result<[f64; 5], CameraInfoError> {
    if coefficients.is_empty() {
        return Ok([0.0; 5]); // an undistorted camera
    }
    let (head, extra) = coefficients.split_at(coefficients.len().min(5));
    let accepted = match model.unwrap_or("plumb_bob") {
        "plumb_bob" => extra.is_empty(),
        // k4..k6 all zero is plumb_bob written in the rational form.
        "rational_polynomial" => extra.iter().all(|&k| k == 0.0),
        _ => false,
    };
    match <[f64; 5]>::try_from(head) {
        Ok(k) if accepted => Ok(k),
        _ => Err(CameraInfoError::UnsupportedDistortion { model: model.unwrap_or("").to_owned(), coefficients }),
    }
}

/// Reads a camera from the text of a camera_info YAML.
pub fn parse_camera_info(text: &str) -> Result<CameraModel, CameraInfoError> {
    let raw: RawCameraInfo =
        serde_saphyr::from_str(text).map_err(|e| CameraInfoError::Yaml(e.without_snippet().to_string()))?;
    let width = integer(raw.image_width.as_ref(), || "image_width".to_owned())?;
    let height = integer(raw.image_height.as_ref(), || "image_height".to_owned())?;
    let k = raw
        .camera_matrix
        .as_ref()
        .ok_or_else(|| CameraInfoError::MissingKey { key: "camera_matrix".to_owned() })?
        .values("camera_matrix", Some((3, 3)))?;
    let k: [f64; 9] = k.try_into().unwrap_or([f64::NAN; 9]); // 9 values, checked above
    if [k[1], k[3], k[6], k[7], k[8]] != [0.0, 0.0, 0.0, 0.0, 1.0] {
        return Err(CameraInfoError::NotPinhole(k));
    }
    if let Some(r) = &raw.rectification_matrix {
        r.values("rectification_matrix", Some((3, 3)))?;
    }
    if let Some(p) = &raw.projection_matrix {
        p.values("projection_matrix", Some((3, 4)))?;
    }
    let model = raw.distortion_model.as_deref().filter(|m| !m.is_empty());
    let coefficients = match &raw.distortion_coefficients {
        Some(d) => d.values("distortion_coefficients", None)?,
        None => Vec::new(),
    };
    let distortion = plumb_bob(model, coefficients)?;
    CameraModel::new(width, height, [k[0], k[4], k[2], k[5]], distortion).map_err(CameraInfoError::Camera)
}

/// Reads a camera from a camera_info YAML file; errors name the file.
pub fn read_camera_info(path: &Path) -> Result<CameraModel, CameraInfoError> {
    let text = std::fs::read_to_string(path).map_err(|error| CameraInfoError::Io { path: path.to_owned(), error })?;
    parse_camera_info(&text).map_err(|error| CameraInfoError::InFile { path: path.to_owned(), error: Box::new(error) })
}

/// The camera as a ROS camera_info YAML: identity rectification and
/// `P = [fx 0 cx 0; 0 fy cy 0; 0 0 1 0]`. Numbers round-trip exactly.
pub fn write_camera_info(camera: &CameraModel, camera_name: &str) -> String {
    let &CameraModel { width, height, fx, fy, cx, cy, distortion } = camera;
    let mut out = format!("image_width: {width}\nimage_height: {height}\ncamera_name: {}\n", yaml_string(camera_name));
    write_matrix(&mut out, "camera_matrix", 3, &[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]);
    out.push_str("distortion_model: plumb_bob\n");
    write_matrix(&mut out, "distortion_coefficients", 1, &distortion);
    write_matrix(&mut out, "rectification_matrix", 3, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    write_matrix(&mut out, "projection_matrix", 3, &[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]);
    out
}

fn write_matrix(out: &mut String, key: &str, rows: usize, data: &[f64]) {
    // `{}` of f64 is the shortest exact form and never uses an exponent, which
    // YAML 1.1 readers (PyYAML) would take for a string.
    let cols = data.len() / rows;
    let data = data.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(", ");
    let _ = write!(out, "{key}:\n  rows: {rows}\n  cols: {cols}\n  data: [{data}]\n");
}

/// A name written plain when YAML would read it back as that string, else quoted.
fn yaml_string(name: &str) -> String {
    let plain = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
        && name.chars().all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
        && !["true", "false", "yes", "no", "on", "off", "null", "y", "n"].contains(&name.to_ascii_lowercase().as_str());
    if plain { name.to_owned() } else { serde_json::Value::from(name).to_string() } // JSON strings are YAML
}

#[cfg(test)]
mod tests {
    use super::*;

    const WILLOW: &str = include_str!("../tests/data/willow-2x2.camera.yaml");

    fn willow_with(from: &str, to: &str) -> String {
        assert!(WILLOW.contains(from), "{from:?} not in the fixture");
        WILLOW.replacen(from, to, 1)
    }

    #[test]
    fn reads_willow_calibration() {
        let cam = parse_camera_info(WILLOW).expect("valid file");
        assert_eq!((cam.width, cam.height), (1567, 1070));
        assert_eq!(cam.fx, 1474.9071860700753);
        assert_eq!(cam.fy, 1483.676600963029);
        assert_eq!((cam.cx, cam.cy), (823.7045939542494, 682.4225889903155));
        assert_eq!(cam.distortion[0], -0.3966072841182623);
        assert_eq!(cam.distortion[4], 0.0);
    }

    #[derive(Deserialize)]
    struct Named {
        camera_name: String,
    }

    #[test]
    fn written_yaml_reads_back_exactly() {
        let cams = [
            parse_camera_info(WILLOW).expect("valid file"),
            CameraModel::default_vga(),
            CameraModel::new(
                7,
                3,
                [1.0 + 1e-13, 9_999_999.123_456_7, -0.0, 1.0 / 3.0],
                [1e-300, -2.5e-17, 0.0, 9_999.999_999_999_9, -1.0],
            )
            .expect("valid camera"),
        ];
        for cam in cams {
            for name in ["narrow_stereo", "", "true", "a: b", "1.5", "it's \"q\"\n"] {
                let text = write_camera_info(&cam, name);
                assert_eq!(parse_camera_info(&text).expect(&text), cam, "{text}");
                let named: Named = serde_saphyr::from_str(&text).expect("valid YAML");
                assert_eq!(named.camera_name, name);
            }
        }
    }

    #[test]
    fn written_yaml_has_the_ros_layout() {
        let text = write_camera_info(&parse_camera_info(WILLOW).expect("valid file"), "prosilica_ge1660c");
        assert_eq!(text.trim_end(), WILLOW.trim_end().replace("0.0]", "0]"));
    }

    #[test]
    fn absent_or_empty_distortion_is_zero() {
        let empty = willow_with(
            "cols: 5\n  data: [-0.3966072841182623, 0.2100337319203109, -0.002809223122968944, -0.005147669775217029, 0.0]",
            "cols: 0\n  data: []",
        );
        assert_eq!(parse_camera_info(&empty).expect("empty").distortion, [0.0; 5]);
        let start = WILLOW.find("distortion_model").expect("model");
        let end = WILLOW.find("rectification_matrix").expect("rectification");
        let absent = format!("{}{}", &WILLOW[..start], &WILLOW[end..]);
        assert_eq!(parse_camera_info(&absent).expect("absent").distortion, [0.0; 5]);
    }

    #[test]
    fn rational_polynomial_with_zero_extras_is_plumb_bob() {
        let text = willow_with("plumb_bob", "rational_polynomial")
            .replace("cols: 5", "cols: 8")
            .replace("0.0]", "0.0, 0, 0, 0]");
        let cam = parse_camera_info(&text).expect("zero k4..k6");
        assert_eq!(cam.distortion[1], 0.2100337319203109);
        let err = parse_camera_info(&text.replace("0, 0, 0]", "0, 0.01, 0]")).expect_err("k5 != 0");
        assert!(matches!(err, CameraInfoError::UnsupportedDistortion { .. }), "{err}");
        assert!(err.to_string().contains("rational_polynomial"), "{err}");
    }

    fn error_of(text: &str) -> (CameraInfoError, String) {
        let err = parse_camera_info(text).expect_err("must be refused");
        let message = err.to_string();
        (err, message)
    }

    #[test]
    fn yaml_syntax_error_is_reported() {
        let (err, msg) = error_of("image_width: [1, 2\nimage_height: 3");
        assert!(matches!(err, CameraInfoError::Yaml(_)), "{msg}");
        assert!(msg.contains("line 1") && !msg.contains('\n'), "{msg}");
    }

    #[test]
    fn missing_key_is_named() {
        let (err, msg) = error_of(&willow_with("image_height: 1070\n", ""));
        assert!(matches!(err, CameraInfoError::MissingKey { .. }), "{msg}");
        assert!(msg.contains("image_height"), "{msg}");
        let (_, msg) = error_of(&willow_with("  rows: 3\n", ""));
        assert!(msg.contains("camera_matrix.rows"), "{msg}");
    }

    #[test]
    fn non_numeric_value_is_named() {
        let (err, msg) = error_of(&willow_with("0.2100337319203109", "abc"));
        assert!(matches!(err, CameraInfoError::NotANumber { .. }), "{msg}");
        assert!(msg.contains("distortion_coefficients.data[1]") && msg.contains("abc"), "{msg}");
    }

    #[test]
    fn fractional_size_is_refused() {
        let (err, msg) = error_of(&willow_with("1567", "1567.5"));
        assert!(matches!(err, CameraInfoError::NotAnInteger { .. }), "{msg}");
        assert!(msg.contains("image_width") && msg.contains("1567.5"), "{msg}");
    }

    #[test]
    fn wrong_matrix_size_is_named() {
        let (err, msg) = error_of(&willow_with(", 0, 0, 1]", ", 0, 0]"));
        assert!(matches!(err, CameraInfoError::MatrixSize { key: "camera_matrix", len: 8, .. }), "{msg}");
        assert!(msg.contains("camera_matrix") && msg.contains("8 values"), "{msg}");
        let (err, msg) = error_of(&willow_with("cols: 4", "cols: 3"));
        assert!(matches!(err, CameraInfoError::MatrixSize { key: "projection_matrix", .. }), "{msg}");
    }

    #[test]
    fn skewed_camera_matrix_is_refused() {
        let (err, msg) = error_of(&willow_with("1474.9071860700753, 0,", "1474.9071860700753, 0.5,"));
        assert!(matches!(err, CameraInfoError::NotPinhole(_)), "{msg}");
        assert!(msg.contains("camera_matrix"), "{msg}");
    }

    #[test]
    fn unknown_distortion_model_is_refused() {
        let (err, msg) = error_of(&willow_with("plumb_bob", "equidistant"));
        assert!(matches!(err, CameraInfoError::UnsupportedDistortion { .. }), "{msg}");
        assert!(msg.contains("equidistant"), "{msg}");
        let (_, msg) = error_of(&willow_with("cols: 5", "cols: 4").replace(", 0.0]", "]"));
        assert!(msg.contains("plumb_bob"), "{msg}");
    }

    #[test]
    fn invalid_camera_is_refused() {
        let (err, msg) = error_of(&willow_with("[1474.9071860700753", "[-1474.9071860700753"));
        assert!(matches!(err, CameraInfoError::Camera(CameraError::BadFocalLength { .. })), "{msg}");
        assert!(msg.contains("focal length"), "{msg}");
    }

    #[test]
    fn file_errors_name_the_file() {
        let dir = std::env::temp_dir().join(format!("outlet-camera-info-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let missing = dir.join("missing.yaml");
        let err = read_camera_info(&missing).expect_err("no such file");
        assert!(matches!(err, CameraInfoError::Io { .. }) && err.to_string().contains("missing.yaml"), "{err}");
        let bad = dir.join("bad.yaml");
        std::fs::write(&bad, "image_width: 3\n").expect("write");
        let err = read_camera_info(&bad).expect_err("incomplete");
        assert!(matches!(err, CameraInfoError::InFile { .. }), "{err}");
        assert!(err.to_string().contains("bad.yaml") && err.to_string().contains("image_height"), "{err}");
        let good = dir.join("good.yaml");
        std::fs::write(&good, WILLOW).expect("write");
        assert_eq!(read_camera_info(&good).expect("valid"), parse_camera_info(WILLOW).expect("valid"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn never_panics_on_damaged_yaml() {
        let bytes = WILLOW.as_bytes();
        for end in 0..bytes.len() {
            let _ = parse_camera_info(&String::from_utf8_lossy(&bytes[..end]));
        }
        for (i, flip) in (0..bytes.len()).flat_map(|i| [0x01u8, 0x20, 0x80].map(|f| (i, f))) {
            let mut damaged = bytes.to_vec();
            damaged[i] ^= flip;
            let _ = parse_camera_info(&String::from_utf8_lossy(&damaged));
        }
    }
}
