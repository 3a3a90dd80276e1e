//! PLY point clouds: the `x`, `y`, `z` of the `vertex` element (camera frame, metres).
//!
//! Reads `ascii`, `binary_little_endian` and `binary_big_endian` 1.0 with any
//! scalar or list properties; writes float `x y z` vertices only.
//!
//! Why not a crate (checked 2026-12, issue 16): `ply-rs` 0.1.3 is unmaintained since
//! 2020, builds `skeptic` as a build dependency and panics (`unwrap`) in its header
//! grammar. Its maintained fork `ply-rs-bw` 4.0 reads our binary little-endian float
//! and double clouds and refused every damaged file we tried without a panic (an
//! element count past `u64`, 4e9 vertices with no data, a negative list count, a
//! truncated cloud), at about our speed with a struct of its own (8.5 ms against
//! 6.7 ms for 640x480 points; 132 ms with its default map per vertex). But it reads
//! no `nan` or `NaN` in an ascii file: an organized cloud's points without depth are
//! NaN (the simulated camera's are), and `write_ply_ascii` writes them so, so it could
//! not read back our own ascii clouds; a cloud without `z` comes back as points at
//! z = 0 unless each caller checks which properties were set; and it would add `peg`,
//! `indexmap` and `byteorder` for 280 lines that parse only `x y z`, are fuzzed
//! (FUZZING.md) and give errors with the line and the token.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Why a PLY file was refused.
#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    #[error("not a PLY file: it does not start with a `ply` line")]
    NotPly,
    #[error("bad PLY header line {line} {text:?}: {reason}")]
    BadHeader { line: usize, text: String, reason: &'static str },
    #[error("unsupported PLY format {0:?}: ascii, binary_little_endian or binary_big_endian 1.0 are read")]
    UnsupportedFormat(String),
    #[error("PLY header has no `element vertex`")]
    MissingVertexElement,
    #[error("PLY vertex element has no scalar `{0}` property")]
    MissingCoordinate(&'static str),
    #[error("PLY data is truncated: expected {expected} vertices, got {got}")]
    Truncated { expected: usize, got: usize },
    #[error("PLY `{element}` row has a list of {count} items")]
    BadListCount { element: String, count: f64 },
    #[error("bad number {token:?} on PLY line {line}")]
    BadNumber { line: usize, token: String },
    #[error("cannot read {}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{}: {error}", path.display())]
    InFile { path: PathBuf, error: Box<PlyError> },
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Property {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<(String, Property)>,
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Format {
    Ascii,
    Binary { big_endian: bool },
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Lines in the header, so that ASCII errors give file line numbers.
    lines: usize,
    body_start: usize,
}

fn parse_header(bytes: &[u8]) -> Result<Header, PlyError> {
    let mut lines = bytes.split_inclusive(|&b| b == b'\n');
    let magic = lines.next().map(|l| l.trim_ascii_end());
    if magic != Some(b"ply".as_slice()) {
        return Err(PlyError::NotPly);
    }
    let (mut format, mut elements) = (None, Vec::<Element>::new());
    let mut body_start = bytes.iter().position(|&b| b == b'\n').map_or(bytes.len(), |i| i + 1);
    for (index, raw) in lines.enumerate() {
        let line = index + 2;
        body_start += raw.len();
        let text = String::from_utf8_lossy(raw.trim_ascii());
        let bad = |reason| PlyError::BadHeader { line, text: text.to_string(), reason };
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words.as_slice() {
            [] | ["comment" | "obj_info", ..] => {}
            ["format", name, version] => {
                format = Some(match (*name, *version) {
                    ("ascii", "1.0") => Format::Ascii,
                    ("binary_little_endian", "1.0") => Format::Binary { big_endian: false },
                    ("binary_big_endian", "1.0") => Format::Binary { big_endian: true },
                    _ => return Err(PlyError::UnsupportedFormat(format!("{name} {version}"))),
                })
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| bad("element count is not a non-negative integer"))?;
                elements.push(Element { name: name.to_string(), count, properties: Vec::new() });
            }
            ["property", kind @ .., name] => {
                let property = match kind {
                    [ty] => Scalar::parse(ty).map(Property::Scalar),
                    ["list", count, item] => Scalar::parse(count)
                        .filter(|c| !matches!(c, Scalar::F32 | Scalar::F64))
                        .zip(Scalar::parse(item))
                        .map(|(count, item)| Property::List { count, item }),
                    _ => None,
                }
                .ok_or_else(|| bad("unknown property type"))?;
                let element = elements.last_mut().ok_or_else(|| bad("property before any element"))?;
                element.properties.push((name.to_string(), property));
            }
            ["end_header"] => {
                let format = format.ok_or_else(|| bad("no format line before end_header"))?;
                return Ok(Header { format, elements, lines: line, body_start });
            }
            _ => return Err(bad("not a PLY header keyword")),
        }
    }
    Err(PlyError::BadHeader { line: 0, text: String::new(), reason: "the header ends without end_header" })
}

/// The data after the header, read one value at a time.
enum Body<'a> {
    Ascii { tokens: Box<dyn Iterator<Item = (usize, &'a str)> + 'a> },
    Binary { bytes: &'a [u8], big_endian: bool },
}

impl Body<'_> {
    /// The next value of type `ty`, or `None` at the end of the data.
    fn value(&mut self, ty: Scalar) -> Result<Option<f64>, PlyError> {
        match self {
            Body::Ascii { tokens } => {
                let Some((line, token)) = tokens.next() else {
                    return Ok(None);
                };
                // float is parsed as f32 so that a written f32 reads back exactly.
                let value = match ty {
                    Scalar::F32 => token.parse::<f32>().map(f64::from),
                    _ => token.parse::<f64>(),
                };
                value.map(Some).map_err(|_| PlyError::BadNumber { line, token: token.to_owned() })
            }
            Body::Binary { bytes, big_endian } => {
                let Some((chunk, rest)) = bytes.split_at_checked(ty.size()) else {
                    return Ok(None);
                };
                *bytes = rest;
                let be = *big_endian;
                macro_rules! decode {
                    ($t:ty) => {{
                        let b = chunk.try_into().unwrap_or_default(); // `chunk` has exactly this size
                        (if be { <$t>::from_be_bytes(b) } else { <$t>::from_le_bytes(b) }) as f64
                    }};
                }
                Ok(Some(match ty {
                    Scalar::I8 => decode!(i8),
                    Scalar::U8 => decode!(u8),
                    Scalar::I16 => decode!(i16),
                    Scalar::U16 => decode!(u16),
                    Scalar::I32 => decode!(i32),
                    Scalar::U32 => decode!(u32),
                    Scalar::F32 => decode!(f32),
                    Scalar::F64 => decode!(f64),
                }))
            }
        }
    }

    /// Reads one row of an element into `row` (list properties read as NaN);
    /// `false` when the data ends before the row does.
    fn row(&mut self, element: &Element, row: &mut Vec<f64>) -> Result<bool, PlyError> {
        row.clear();
        for (_, property) in &element.properties {
            match *property {
                Property::Scalar(ty) => match self.value(ty)? {
                    Some(v) => row.push(v),
                    None => return Ok(false),
                },
                Property::List { count, item } => {
                    let Some(n) = self.value(count)? else {
                        return Ok(false);
                    };
                    if !(n >= 0.0 && n.fract() == 0.0) {
                        return Err(PlyError::BadListCount { element: element.name.clone(), count: n });
                    }
                    // Each item takes at least one byte or token, so this ends with the data.
                    for _ in 0..n as u64 {
                        if self.value(item)?.is_none() {
                            return Ok(false);
                        }
                    }
                    row.push(f64::NAN);
                }
            }
        }
        Ok(true)
    }
}

/// The vertices of a PLY file. NaN vertices are kept.
pub fn parse_ply(bytes: &[u8]) -> Result<Vec<[f32; 3]>, PlyError> {
    let header = parse_header(bytes)?;
    let data = bytes.get(header.body_start..).unwrap_or_default();
    let split = header.elements.iter().position(|e| e.name == "vertex").unwrap_or(header.elements.len());
    let (skipped, rest) = header.elements.split_at(split);
    let vertex = rest.first().ok_or(PlyError::MissingVertexElement)?;
    let axis = |name: &'static str| {
        vertex
            .properties
            .iter()
            .position(|(n, p)| n == name && matches!(p, Property::Scalar(_)))
            .ok_or(PlyError::MissingCoordinate(name))
    };
    let (x, y, z) = (axis("x")?, axis("y")?, axis("z")?);

    let text; // the ASCII body, borrowed by its tokens
    let (mut body, min_row_bytes) = match header.format {
        Format::Ascii => {
            text = String::from_utf8_lossy(data);
            let first_line = header.lines + 1;
            let tokens = text
                .lines()
                .enumerate()
                .flat_map(move |(i, l)| l.split_ascii_whitespace().map(move |t| (first_line + i, t)));
            (Body::Ascii { tokens: Box::new(tokens) }, 2 * vertex.properties.len())
        }
        Format::Binary { big_endian } => {
            let sizes = vertex.properties.iter().map(|(_, p)| match p {
                Property::Scalar(ty) | Property::List { count: ty, .. } => ty.size(),
            });
            (Body::Binary { bytes: data, big_endian }, sizes.sum())
        }
    };

    let mut row = Vec::new();
    for element in skipped.iter().filter(|e| !e.properties.is_empty()) {
        for _ in 0..element.count {
            if !body.row(element, &mut row)? {
                return Err(PlyError::Truncated { expected: vertex.count, got: 0 });
            }
        }
    }
    // A header may claim more vertices than the data can hold: no allocation from it alone.
    let mut points = Vec::with_capacity(vertex.count.min(data.len() / min_row_bytes.max(1)));
    while points.len() < vertex.count {
        if !body.row(vertex, &mut row)? {
            return Err(PlyError::Truncated { expected: vertex.count, got: points.len() });
        }
        let coordinate = |i: usize| row.get(i).map_or(f32::NAN, |&v| v as f32);
        points.push([coordinate(x), coordinate(y), coordinate(z)]);
    }
    Ok(points)
}

/// Reads the vertices of a PLY file; errors name the file.
pub fn read_ply(path: &Path) -> Result<Vec<[f32; 3]>, PlyError> {
    let bytes = std::fs::read(path).map_err(|error| PlyError::Io { path: path.to_owned(), error })?;
    parse_ply(&bytes).map_err(|error| PlyError::InFile { path: path.to_owned(), error: Box::new(error) })
}

fn header(format: &str, count: usize) -> String {
    format!(
        "ply\nformat {format} 1.0\nelement vertex {count}\n\
         property float x\nproperty float y\nproperty float z\nend_header\n"
    )
}

/// The points as a `binary_little_endian` PLY of float `x y z` vertices.
pub fn write_ply_binary(points: &[[f32; 3]]) -> Vec<u8> {
    let mut out = header("binary_little_endian", points.len()).into_bytes();
    out.reserve(points.len() * 12);
    out.extend(points.iter().flatten().flat_map(|v| v.to_le_bytes()));
    out
}

/// The points as an `ascii` PLY of float `x y z` vertices; NaN is written `NaN`.
pub fn write_ply_ascii(points: &[[f32; 3]]) -> String {
    let mut out = header("ascii", points.len());
    for [x, y, z] in points {
        // `{}` of f32 is the shortest form that reads back to the same value.
        let _ = writeln!(out, "{x} {y} {z}");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn same(a: &[[f32; 3]], b: &[[f32; 3]]) -> bool {
        let bits = |p: &[[f32; 3]]| p.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        bits(a) == bits(b)
    }

    fn cloud() -> Vec<[f32; 3]> {
        vec![
            [0.1, -0.2, 1.5],
            [f32::NAN, f32::NAN, f32::NAN],
            [1e-30, -3.4e38, f32::MIN_POSITIVE],
            [-0.0, 0.0, 123456.79],
            [f32::INFINITY, 1.0 / 3.0, f32::NEG_INFINITY],
        ]
    }

    /// A big-endian cloud with x, y, z of mixed types among other properties,
    /// a list inside the vertex, an element before it and faces after it.
    fn mixed_big_endian() -> Vec<u8> {
        let mut out = b"ply\r\nformat binary_big_endian 1.0\r\ncomment made by hand\r\nobj_info test\r\n\
            element camera 1\r\nproperty uint8 id\r\n\
            element vertex 2\r\nproperty uchar red\r\nproperty double z\r\nproperty float32 x\r\n\
            property list uchar int16 tags\r\nproperty int y\r\n\
            element face 1\r\nproperty list uchar uint vertex_indices\r\nend_header\r\n"
            .to_vec();
        out.push(7);
        for (red, z, x, tags, y) in [(1u8, 2.5f64, -1.25f32, &[3i16, 4][..], 9i32), (2, f64::NAN, 0.5, &[], -4)] {
            out.push(red);
            out.extend(z.to_be_bytes());
            out.extend(x.to_be_bytes());
            out.push(tags.len() as u8);
            out.extend(tags.iter().flat_map(|t| t.to_be_bytes()));
            out.extend(y.to_be_bytes());
        }
        out.extend([3, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 2]);
        out
    }

    #[test]
    fn binary_round_trip_keeps_every_value_including_nan() {
        let points = cloud();
        assert!(same(&parse_ply(&write_ply_binary(&points)).expect("valid"), &points));
        assert!(parse_ply(&write_ply_binary(&[])).expect("empty").is_empty());
    }

    #[test]
    fn ascii_round_trip_keeps_every_value_including_nan() {
        let points = cloud();
        let text = write_ply_ascii(&points);
        assert!(same(&parse_ply(text.as_bytes()).expect("valid"), &points), "{text}");
    }

    #[test]
    fn ascii_nan_tokens_read_as_nan() {
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                    property double z\nend_header\nnan NaN -nan\n";
        let p = parse_ply(text.as_bytes()).expect("valid");
        assert!(p[0].iter().all(|v| v.is_nan()), "{p:?}");
    }

    #[test]
    fn coordinates_are_found_among_other_properties_and_elements() {
        let p = parse_ply(&mixed_big_endian()).expect("valid");
        assert_eq!(p[0], [-1.25, 9.0, 2.5]);
        assert_eq!([p[1][0], p[1][1]], [0.5, -4.0]);
        assert!(p[1][2].is_nan());
        let ascii = "ply\nformat ascii 1.0\ncomment c\nelement vertex 2\nproperty int8 flag\n\
                     property list uint8 float weights\nproperty float64 z\nproperty float y\nproperty float x\n\
                     element face 1\nproperty list uchar int vertex_indices\nend_header\n\
                     1 2 0.5 0.5 3 2 1\n0 0 6\n  5 4\n3 0 1 1\n";
        assert_eq!(parse_ply(ascii.as_bytes()).expect("valid"), [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    }

    #[test]
    fn huge_vertex_count_is_truncated_not_allocated() {
        let mut bytes = write_ply_binary(&[[1.0, 2.0, 3.0]]);
        let at = bytes.windows(8).position(|w| w == b"vertex 1").expect("count");
        bytes.splice(at..at + 8, *b"vertex 1000000000000");
        let err = parse_ply(&bytes).expect_err("truncated");
        assert!(matches!(err, PlyError::Truncated { expected: 1_000_000_000_000, got: 1 }), "{err}");
        assert!(err.to_string().contains("got 1"), "{err}");
    }

    fn error_of(bytes: &[u8]) -> (PlyError, String) {
        let err = parse_ply(bytes).expect_err("must be refused");
        let message = err.to_string();
        (err, message)
    }

    const XYZ: &str = "property float x\nproperty float y\nproperty float z\n";

    #[test]
    fn missing_magic_is_not_ply() {
        let (err, msg) = error_of(b"OFF\n3 1 0\n");
        assert!(matches!(err, PlyError::NotPly), "{msg}");
        assert!(msg.contains("not a PLY"), "{msg}");
    }

    #[test]
    fn bad_header_line_is_quoted() {
        let (err, msg) =
            error_of(format!("ply\nformat ascii 1.0\nelement vertex 1\n{XYZ}property quad w\nend_header\n").as_bytes());
        assert!(matches!(err, PlyError::BadHeader { line: 7, .. }), "{msg}");
        assert!(msg.contains("property quad w") && msg.contains("line 7"), "{msg}");
        let (_, msg) = error_of(b"ply\nformat ascii 1.0\nelement vertex -1\n");
        assert!(msg.contains("element vertex -1"), "{msg}");
        let (_, msg) = error_of(b"ply\nformat ascii 1.0\nelement vertex 1\n");
        assert!(msg.contains("end_header"), "{msg}");
    }

    #[test]
    fn unsupported_format_is_named() {
        let (err, msg) =
            error_of(format!("ply\nformat binary_middle_endian 1.0\nelement vertex 0\n{XYZ}end_header\n").as_bytes());
        assert!(matches!(err, PlyError::UnsupportedFormat(_)), "{msg}");
        assert!(msg.contains("binary_middle_endian"), "{msg}");
    }

    #[test]
    fn missing_vertex_element_is_refused() {
        let (err, msg) = error_of(b"ply\nformat ascii 1.0\nelement face 0\nend_header\n");
        assert!(matches!(err, PlyError::MissingVertexElement), "{msg}");
        assert!(msg.contains("element vertex"), "{msg}");
    }

    #[test]
    fn missing_coordinate_is_named() {
        let (err, msg) = error_of(
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty list uchar float y\nproperty float z\nend_header\n",
        );
        assert!(matches!(err, PlyError::MissingCoordinate("y")), "{msg}");
        assert!(msg.contains("`y`"), "{msg}");
    }

    #[test]
    fn truncated_data_says_how_many_vertices_came() {
        let bytes = write_ply_binary(&cloud());
        let (err, msg) = error_of(&bytes[..bytes.len() - 1]);
        assert!(matches!(err, PlyError::Truncated { expected: 5, got: 4 }), "{msg}");
        assert!(msg.contains("expected 5") && msg.contains("got 4"), "{msg}");
        let text = write_ply_ascii(&cloud());
        let (err, _) = error_of(&text.as_bytes()[..text.len() - 5]);
        assert!(matches!(err, PlyError::Truncated { expected: 5, got: 4 }), "{err}");
    }

    #[test]
    fn bad_ascii_number_gives_its_line() {
        let (err, msg) =
            error_of(format!("ply\nformat ascii 1.0\nelement vertex 2\n{XYZ}end_header\n1 2 3\n4 five 6\n").as_bytes());
        assert!(matches!(err, PlyError::BadNumber { line: 9, .. }), "{msg}");
        assert!(msg.contains("\"five\"") && msg.contains("line 9"), "{msg}");
    }

    #[test]
    fn negative_list_count_is_refused() {
        let text = format!(
            "ply\nformat ascii 1.0\nelement vertex 1\n{XYZ}property list int float w\nend_header\n1 2 3 -2 0 0\n"
        );
        let (err, msg) = error_of(text.as_bytes());
        assert!(matches!(err, PlyError::BadListCount { .. }), "{msg}");
        assert!(msg.contains("vertex") && msg.contains("-2"), "{msg}");
    }

    #[test]
    fn file_errors_name_the_file() {
        let dir = std::env::temp_dir().join(format!("outlet-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let err = read_ply(&dir.join("missing.ply")).expect_err("no such file");
        assert!(matches!(err, PlyError::Io { .. }) && err.to_string().contains("missing.ply"), "{err}");
        let bad = dir.join("bad.ply");
        std::fs::write(&bad, b"solid\n").expect("write");
        let err = read_ply(&bad).expect_err("not ply");
        assert!(matches!(err, PlyError::InFile { .. }), "{err}");
        assert!(err.to_string().contains("bad.ply") && err.to_string().contains("not a PLY"), "{err}");
        let good = dir.join("good.ply");
        std::fs::write(&good, write_ply_binary(&cloud())).expect("write");
        assert!(same(&read_ply(&good).expect("valid"), &cloud()));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn never_panics_on_damaged_files() {
        for bytes in [mixed_big_endian(), write_ply_binary(&cloud()), write_ply_ascii(&cloud()).into_bytes()] {
            for end in 0..bytes.len() {
                let _ = parse_ply(&bytes[..end]);
            }
            for i in 0..bytes.len() {
                for flip in [0x01u8, 0x10, 0x80, 0xff] {
                    let mut damaged = bytes.clone();
                    damaged[i] ^= flip;
                    let _ = parse_ply(&damaged);
                }
            }
        }
    }
}
