//! Trajectory CSV in: one pose per row, either a row-major 4x4 affine matrix
//! (`m00..m33`) or a translation plus unit quaternion (`tx,ty,tz,qw,qx,qy,qz`).
//!
//! Rules: `#` lines (after optional whitespace) and blank lines are skipped
//! everywhere; the first other line is the header; names are lowercase and
//! fields are trimmed; a UTF-8 BOM and `\r\n` are accepted; quotes let a `node`
//! name hold a comma (a quoted field cannot span lines). Optional columns:
//! `frame` or `time` (a finite number), `node` (a non-empty glTF node name).
//! Errors name the file, the real 1-based line, the column and a fix.

use std::path::Path;

use glam::{DMat3, DMat4, DQuat, DVec3};

use crate::error::InputError;
use crate::input::model::{Pose, Trajectory};

/// Matrix-form columns: `m{row}{col}` of M (p' = M·p), row-major.
const MATRIX: [&str; 16] = [
    "m00", "m01", "m02", "m03", "m10", "m11", "m12", "m13", "m20", "m21", "m22", "m23", "m30",
    "m31", "m32", "m33",
];
/// Pose-form columns: translation, then the unit quaternion w first; M = T(t)·R(q).
const POSE: [&str; 7] = ["tx", "ty", "tz", "qw", "qx", "qy", "qz"];
/// Optional columns, accepted with either form.
const OPTIONAL: [&str; 3] = ["frame", "time", "node"];

/// How far a quaternion's norm may be from 1 before it is rejected rather than normalized.
const QUAT_TOLERANCE: f64 = 1e-3;

const FORMS: &str = "write the header in one of two forms: matrix form \
    `m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33` (row-major 4x4) \
    or pose form `tx,ty,tz,qw,qx,qy,qz` (translation and unit quaternion, w first); \
    either may add a `frame` or `time` column and a `node` column";

#[derive(Debug, Clone, Copy)]
enum Form {
    Matrix,
    Pose,
}

/// What one header column holds.
#[derive(Debug, Clone, Copy)]
enum Kind {
    /// Index into `MATRIX` or `POSE`, whichever is the header's form.
    Value(usize),
    Frame,
    Node,
}

/// The parsed header: the form and, per field, its name and meaning.
struct Header {
    form: Form,
    columns: Vec<(&'static str, Kind)>,
}

/// Reads a trajectory CSV file and parses it with [`parse_trajectory`].
pub fn read_trajectory(path: &Path) -> Result<Trajectory, InputError> {
    let bytes = std::fs::read(path).map_err(|e| {
        InputError::new(
            path,
            format!("cannot read the trajectory file: {e}"),
            "check that the path is right and the file is readable",
        )
    })?;
    let text = String::from_utf8(bytes).map_err(|e| {
        let valid = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        let line = 1 + valid.iter().filter(|&&b| b == b'\n').count() as u64;
        InputError::new(
            path,
            "the file is not UTF-8 text",
            "save the trajectory as a plain UTF-8 CSV file",
        )
        .at_line(line)
    })?;
    parse_trajectory(path, &text)
}

/// Parses trajectory CSV text; `path` is only used in error messages.
pub fn parse_trajectory(path: &Path, text: &str) -> Result<Trajectory, InputError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut rows = text
        .lines()
        .zip(1u64..)
        .map(|(text, line)| (line, text.trim()))
        .filter(|(_, text)| !text.is_empty() && !text.starts_with('#'));

    let Some((header_line, header_text)) = rows.next() else {
        return Err(InputError::new(
            path,
            "the trajectory file has no header row",
            FORMS,
        ));
    };
    let header = parse_header(path, header_line, &fields(path, header_line, header_text)?)?;

    let poses = rows
        .map(|(line, text)| parse_row(path, line, &header, &fields(path, line, text)?))
        .collect::<Result<Vec<_>, _>>()?;
    if poses.is_empty() {
        return Err(InputError::new(
            path,
            "the trajectory has a header but no pose rows",
            "add at least one pose row below the header",
        )
        .at_line(header_line));
    }
    let has_node_column = header.columns.iter().any(|(_, k)| matches!(k, Kind::Node));
    Ok(Trajectory {
        poses,
        has_node_column,
        rows: crate::input::model::Rows::World,
    })
}

/// Splits one line into trimmed fields. A field may be double-quoted to hold a
/// comma (`""` is a quote inside it); whitespace around the quotes is ignored.
fn fields(path: &Path, line: u64, text: &str) -> Result<Vec<String>, InputError> {
    let err = |message: String, fix: &str| InputError::new(path, message, fix).at_line(line);
    let mut fields = Vec::new();
    let mut rest = text;
    loop {
        let start = rest.trim_start();
        let (field, after) = if let Some(quoted) = start.strip_prefix('"') {
            let mut field = String::new();
            let mut chars = quoted.char_indices();
            let end = loop {
                match chars.next() {
                    None => {
                        return Err(err(
                            format!("field {} has an unterminated quote", fields.len() + 1),
                            "close the quoted field with a double quote (write \"\" for a quote inside it)",
                        ))
                    }
                    Some((i, '"')) if quoted[i + 1..].starts_with('"') => {
                        field.push('"');
                        chars.next();
                    }
                    Some((i, '"')) => break i + 1,
                    Some((_, c)) => field.push(c),
                }
            };
            let after = quoted[end..].trim_start();
            if !after.is_empty() && !after.starts_with(',') {
                return Err(err(
                    format!(
                        "field {} has text after its closing quote",
                        fields.len() + 1
                    ),
                    "put the whole field inside the double quotes",
                ));
            }
            (field, after)
        } else {
            let end = start.find(',').unwrap_or(start.len());
            (start[..end].trim_end().to_owned(), &start[end..])
        };
        fields.push(field);
        match after.strip_prefix(',') {
            Some(next) => rest = next,
            None => return Ok(fields),
        }
    }
}

fn parse_header(path: &Path, line: u64, record: &[String]) -> Result<Header, InputError> {
    let err = |message: String| InputError::new(path, message, FORMS).at_line(line);
    let mut columns: Vec<(&'static str, Kind)> = Vec::new();
    for (index, name) in record.iter().enumerate() {
        let Some((name, kind)) = lookup(name) else {
            let fix = "rename or remove the column (names are lowercase and case-sensitive)";
            let accepted = accepted_names();
            return Err(if name.is_empty() {
                let message = format!(
                    "column {} has an empty name (a stray comma?); accepted names are {accepted}",
                    index + 1
                );
                InputError::new(path, message, fix).at_line(line)
            } else {
                let message = format!(
                    "unknown column \"{name}\" (column {}); accepted names are {accepted}",
                    index + 1
                );
                InputError::new(path, message, fix)
                    .at_line(line)
                    .in_column(name.as_str())
            });
        };
        if let Some(first) = columns.iter().position(|(n, _)| *n == name) {
            return Err(InputError::new(
                path,
                format!(
                    "duplicate column \"{name}\" (columns {} and {})",
                    first + 1,
                    index + 1
                ),
                "keep only one column of each name",
            )
            .at_line(line)
            .in_column(name));
        }
        if matches!(kind, Kind::Frame) && columns.iter().any(|(_, k)| matches!(k, Kind::Frame)) {
            return Err(InputError::new(
                path,
                "the header has both a frame and a time column",
                "keep only one of frame or time",
            )
            .at_line(line)
            .in_column(name));
        }
        columns.push((name, kind));
    }

    let missing = |names: &[&'static str]| -> Vec<&'static str> {
        let present = |n: &&str| columns.iter().any(|(c, _)| c == n);
        names.iter().copied().filter(|n| !present(n)).collect()
    };
    let (missing_matrix, missing_pose) = (missing(&MATRIX), missing(&POSE));
    let form = match (
        missing_matrix.len() < MATRIX.len(),
        missing_pose.len() < POSE.len(),
    ) {
        (true, true) => {
            return Err(err(
                "the header is ambiguous: it mixes matrix-form (m00..m33) and pose-form \
                 (tx..qz) columns; use one form only"
                    .into(),
            ))
        }
        (true, false) if missing_matrix.is_empty() => Form::Matrix,
        (false, true) if missing_pose.is_empty() => Form::Pose,
        (true, false) => {
            return Err(err(format!(
                "the header is missing matrix-form column(s) {}",
                missing_matrix.join(", ")
            )))
        }
        (false, true) => {
            return Err(err(format!(
                "the header is missing pose-form column(s) {}",
                missing_pose.join(", ")
            )))
        }
        (false, false) => {
            return Err(err(format!(
                "the header has no pose columns (found: {})",
                record.join(", ")
            )))
        }
    };
    Ok(Header { form, columns })
}

/// The accepted column name equal to `name`, and what it holds.
fn lookup(name: &str) -> Option<(&'static str, Kind)> {
    if let Some(i) = MATRIX.iter().position(|&m| m == name) {
        return Some((MATRIX[i], Kind::Value(i)));
    }
    if let Some(i) = POSE.iter().position(|&p| p == name) {
        return Some((POSE[i], Kind::Value(i)));
    }
    match name {
        "frame" => Some(("frame", Kind::Frame)),
        "time" => Some(("time", Kind::Frame)),
        "node" => Some(("node", Kind::Node)),
        _ => None,
    }
}

fn accepted_names() -> String {
    [&MATRIX[..], &POSE[..], &OPTIONAL[..]].concat().join(", ")
}

fn parse_row(
    path: &Path,
    line: u64,
    header: &Header,
    record: &[String],
) -> Result<Pose, InputError> {
    if record.len() != header.columns.len() {
        return Err(InputError::new(
            path,
            format!(
                "the row has {} fields but the header has {}",
                record.len(),
                header.columns.len()
            ),
            "write exactly one value per header column; check for missing or extra commas",
        )
        .at_line(line));
    }
    let mut values = [0.0; 16];
    let (mut frame, mut node) = (None, None);
    for (&(name, kind), cell) in header.columns.iter().zip(record) {
        match kind {
            Kind::Value(i) => values[i] = number(path, line, name, cell)?,
            Kind::Frame => frame = Some(number(path, line, name, cell)?),
            Kind::Node if cell.is_empty() => {
                return Err(InputError::new(
                    path,
                    "empty node name",
                    "name the glTF node this row moves, or drop the node column to move the whole scene",
                )
                .at_line(line)
                .in_column(name))
            }
            Kind::Node => node = Some(cell.to_owned()),
        }
    }
    let matrix = match header.form {
        Form::Matrix => affine(path, line, &values)?,
        Form::Pose => rigid(path, line, &values)?,
    };
    Ok(Pose {
        line,
        frame,
        node,
        matrix,
    })
}

/// Parses a finite f64 from one cell.
fn number(path: &Path, line: u64, column: &str, cell: &str) -> Result<f64, InputError> {
    let (message, fix) = match cell.parse::<f64>() {
        Ok(x) if x.is_finite() => return Ok(x),
        _ if cell.is_empty() => (
            "empty cell".to_owned(),
            "write a number in every column of every pose row",
        ),
        Ok(_) => (
            format!("\"{cell}\" is not a finite number"),
            "replace it with a finite number (nan and inf are not allowed)",
        ),
        Err(_) => (
            format!("\"{cell}\" is not a number"),
            "write a plain decimal number such as 0.25 or -1.5e-3",
        ),
    };
    Err(InputError::new(path, message, fix)
        .at_line(line)
        .in_column(column))
}

/// Matrix form: `m` is M row-major; the last row must be 0 0 0 1 and the 3x3 part invertible.
fn affine(path: &Path, line: u64, m: &[f64; 16]) -> Result<DMat4, InputError> {
    for (i, want) in [(12, 0.0), (13, 0.0), (14, 0.0), (15, 1.0)] {
        if m[i] != want {
            return Err(InputError::new(
                path,
                format!("{} is {} but must be {want}", MATRIX[i], m[i]),
                "the last row of an affine matrix is 0 0 0 1 (m30,m31,m32,m33 = 0,0,0,1); \
                 projective poses are not supported",
            )
            .at_line(line)
            .in_column(MATRIX[i]));
        }
    }
    // `from_cols_array` reads columns, so row-major entries give M transposed.
    let matrix = DMat4::from_cols_array(m).transpose();
    let linear = DMat3::from_mat4(matrix);
    let det = linear.determinant();
    let scale = linear.x_axis.length() * linear.y_axis.length() * linear.z_axis.length();
    if scale == 0.0 || det.abs() <= 1e-12 * scale {
        return Err(InputError::new(
            path,
            format!("singular matrix: the 3x3 part has determinant {det}"),
            "make the upper-left 3x3 (m00..m22) invertible: no zero row or column, \
             no two parallel columns (a zero scale flattens the part)",
        )
        .at_line(line)
        .in_column("m00..m22"));
    }
    Ok(matrix)
}

/// Pose form: `v` is tx,ty,tz,qw,qx,qy,qz; a quaternion within 1e-3 of unit norm is normalized.
fn rigid(path: &Path, line: u64, v: &[f64; 16]) -> Result<DMat4, InputError> {
    let q = DQuat::from_xyzw(v[4], v[5], v[6], v[3]);
    let norm = q.length();
    if !norm.is_finite() || (norm - 1.0).abs() > QUAT_TOLERANCE {
        return Err(InputError::new(
            path,
            format!("bad quaternion: its norm is {norm}, not 1"),
            "write a unit quaternion, w first (qw,qx,qy,qz), e.g. 1,0,0,0 for no rotation; \
             norms within 1e-3 of 1 are normalized",
        )
        .at_line(line)
        .in_column("qw..qz"));
    }
    Ok(DMat4::from_rotation_translation(
        q / norm,
        DVec3::new(v[0], v[1], v[2]),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MATRIX_HEADER: &str = "m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33";
    const IDENTITY_ROW: &str = "1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1";

    fn parse(text: &str) -> Result<Trajectory, InputError> {
        parse_trajectory(Path::new("traj.csv"), text)
    }

    fn parse_err(text: &str) -> InputError {
        parse(text).expect_err("expected an error")
    }

    /// Asserts line and column, that message+fix mention every word, and the Display form.
    fn check(e: &InputError, line: u64, column: Option<&str>, words: &[&str]) {
        assert_eq!(e.line, Some(line), "{e}");
        assert_eq!(e.column.as_deref(), column, "{e}");
        let text = format!("{} {}", e.message, e.fix);
        for w in words {
            assert!(text.contains(w), "{w:?} not in: {e}");
        }
        let shown = e.to_string();
        assert!(shown.starts_with(&format!("traj.csv:{line}: ")), "{shown}");
        assert!(!e.fix.is_empty());
    }

    /// A matrix-form row from 16 row-major entries.
    fn matrix_row(m: [f64; 16]) -> String {
        m.map(|x| x.to_string()).join(",")
    }

    fn matrix_file(m: [f64; 16]) -> String {
        format!("{MATRIX_HEADER}\n{}\n", matrix_row(m))
    }

    #[test]
    fn matrix_translation_moves_origin() {
        let t = parse(&format!(
            "{MATRIX_HEADER}\n1,0,0,1,0,1,0,2,0,0,1,3,0,0,0,1\n"
        ))
        .unwrap();
        assert_eq!(t.poses.len(), 1);
        let p = &t.poses[0];
        assert_eq!(
            p.matrix.transform_point3(DVec3::ZERO),
            DVec3::new(1.0, 2.0, 3.0)
        );
        assert_eq!((p.line, p.frame, p.node.clone()), (2, None, None));
        assert!(!t.has_node_column);
    }

    #[test]
    fn matrix_entries_are_row_major() {
        let mut m = [
            2.0, 0.5, 0.0, 7.0, 0.0, 3.0, 0.25, 8.0, 1.0, 0.0, 4.0, 9.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let p = &parse(&matrix_file(m)).unwrap().poses[0];
        for r in 0..4 {
            for c in 0..4 {
                assert_eq!(p.matrix.row(r)[c], m[4 * r + c], "m{r}{c}");
            }
        }
        // p' = M·p: (1,1,1) -> row sums.
        assert_eq!(
            p.matrix.transform_point3(DVec3::ONE),
            DVec3::new(9.5, 11.25, 14.0)
        );
        // Columns may come in any order.
        m.swap(0, 1);
        let shuffled = MATRIX_HEADER.replacen("m00,m01", "m01,m00", 1);
        let q = &parse(&format!("{shuffled}\n{}\n", matrix_row(m)))
            .unwrap()
            .poses[0];
        assert_eq!(q.matrix, p.matrix);
    }

    #[test]
    fn any_invertible_affine_is_accepted() {
        let cases = [
            // uniform tiny scale: relative test, not absolute
            [
                1e-6, 0.0, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            // shear
            [
                1.0, 5.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            // reflection
            [
                -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            // non-uniform scale
            [
                3.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
        ];
        for m in cases {
            parse(&matrix_file(m)).unwrap();
        }
    }

    #[test]
    fn pose_form_is_translation_times_rotation() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let t = parse(&format!("tx,ty,tz,qw,qx,qy,qz\n1,2,3,{h},0,0,{h}\n")).unwrap();
        let m = t.poses[0].matrix;
        // 90° about z: (1,0,0) -> (0,1,0), then translated.
        assert!(m.transform_vector3(DVec3::X).abs_diff_eq(DVec3::Y, 1e-12));
        assert!(m
            .transform_point3(DVec3::X)
            .abs_diff_eq(DVec3::new(1.0, 3.0, 3.0), 1e-12));
        assert_eq!(m.transform_point3(DVec3::ZERO), DVec3::new(1.0, 2.0, 3.0));
    }

    #[test]
    fn nearly_unit_quaternion_is_normalized() {
        let t = parse("tx,ty,tz,qw,qx,qy,qz\n0,0,0,1.0009,0,0,0\n").unwrap();
        let m = t.poses[0].matrix;
        assert!(m.abs_diff_eq(DMat4::IDENTITY, 1e-12), "{m}");
    }

    #[test]
    fn comments_blank_lines_crlf_bom_and_whitespace() {
        let text = "\u{feff}# made by hand\r\n\r\n   # indented comment\r\n \
                    tx , ty,tz ,qw,qx,qy,qz\r\n\r\n# between\r\n 1 , 2,3,1,0,0,0 \r\n\t\r\n4,5,6,1,0,0,0";
        let t = parse(text).unwrap();
        let lines: Vec<u64> = t.poses.iter().map(|p| p.line).collect();
        assert_eq!(lines, [7, 9]);
        assert_eq!(
            t.poses[1].matrix.transform_point3(DVec3::ZERO),
            DVec3::new(4.0, 5.0, 6.0)
        );
    }

    #[test]
    fn error_lines_count_skipped_lines() {
        let e = parse_err("# a\n\ntx,ty,tz,qw,qx,qy,qz\n# b\n0,0,0,1,0,0,0\n\n0,x,0,1,0,0,0\n");
        check(&e, 7, Some("ty"), &["\"x\" is not a number"]);
    }

    #[test]
    fn frame_and_time_columns() {
        let t = parse("frame,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n2.5,0,0,0,1,0,0,0\n").unwrap();
        let frames: Vec<_> = t.poses.iter().map(|p| p.frame).collect();
        assert_eq!(frames, [Some(0.0), Some(2.5)]);
        let t = parse(&format!("{MATRIX_HEADER},time\n{IDENTITY_ROW},-1e-3\n")).unwrap();
        assert_eq!(t.poses[0].frame, Some(-1e-3));
    }

    #[test]
    fn node_column() {
        let t = parse(
            "node,tx,ty,tz,qw,qx,qy,qz\narm,0,0,0,1,0,0,0\n\"gripper, left\",1,0,0,1,0,0,0\n",
        )
        .unwrap();
        assert!(t.has_node_column);
        let nodes: Vec<_> = t.poses.iter().map(|p| p.node.as_deref()).collect();
        assert_eq!(nodes, [Some("arm"), Some("gripper, left")]);
    }

    #[test]
    fn quoted_fields() {
        let f = |text: &str| fields(Path::new("traj.csv"), 1, text).unwrap();
        assert_eq!(
            f(" a , \"b, c\" ,,\"say \"\"hi\"\"\""),
            ["a", "b, c", "", "say \"hi\""]
        );
        assert_eq!(f("\" padded \" ,x,"), [" padded ", "x", ""]);
        let e = parse_err("node,tx,ty,tz,qw,qx,qy,qz\n\"arm,0,0,0,1,0,0,0\n");
        check(
            &e,
            2,
            None,
            &[
                "field 1 has an unterminated quote",
                "close the quoted field",
            ],
        );
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz,node\n0,0,0,1,0,0,0,\"arm\"x\n");
        check(
            &e,
            2,
            None,
            &[
                "field 8 has text after its closing quote",
                "inside the double quotes",
            ],
        );
    }

    #[test]
    fn empty_node_is_an_error() {
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz,node\n0,0,0,1,0,0,0,arm\n0,0,0,1,0,0,0,\n");
        check(
            &e,
            3,
            Some("node"),
            &["name the glTF node this row moves", "drop the node column"],
        );
    }

    #[test]
    fn empty_file_and_header_only() {
        for text in ["", "\u{feff}", "# only a comment\n\n  \n"] {
            let e = parse_err(text);
            assert_eq!((e.line, e.column.as_deref()), (None, None));
            assert!(e.message.contains("no header"), "{e}");
            assert!(e.fix.contains("tx,ty,tz,qw,qx,qy,qz") && e.fix.contains("m00"));
        }
        let e = parse_err("# c\ntx,ty,tz,qw,qx,qy,qz\n# nothing else\n");
        check(&e, 2, None, &["add at least one pose row below the header"]);
    }

    #[test]
    fn header_missing_columns() {
        let e = parse_err(&format!(
            "{}\n{IDENTITY_ROW}\n",
            &MATRIX_HEADER[..MATRIX_HEADER.len() - 4]
        ));
        check(
            &e,
            1,
            None,
            &[
                "missing matrix-form",
                "m33",
                "tx,ty,tz,qw,qx,qy,qz",
                "m00,m01",
            ],
        );
        let e = parse_err("tx,ty,tz,qw,qx,qy\n0,0,0,1,0,0\n");
        check(
            &e,
            1,
            None,
            &["missing pose-form", "qz", "m00,m01", "tx,ty,tz,qw,qx,qy,qz"],
        );
        let e = parse_err("\n\nframe,node\n1,a\n");
        check(
            &e,
            3,
            None,
            &["no pose columns", "frame, node", "m00,m01", "tx,ty,tz"],
        );
    }

    #[test]
    fn header_mixing_forms_is_ambiguous() {
        let e = parse_err(&format!("{MATRIX_HEADER},tx,ty,tz,qw,qx,qy,qz\n"));
        check(&e, 1, None, &["ambiguous", "one form"]);
        let e = parse_err("m00,tx,ty,tz,qw,qx,qy,qz\n");
        check(&e, 1, None, &["ambiguous"]);
    }

    #[test]
    fn header_duplicate_and_unknown_columns() {
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz,ty\n");
        check(
            &e,
            1,
            Some("ty"),
            &["duplicate", "columns 2 and 8", "only one"],
        );
        let e = parse_err(&format!("{}\n", MATRIX_HEADER.replace("m01", "m0l")));
        check(
            &e,
            1,
            Some("m0l"),
            &["unknown column \"m0l\"", "m01", "qz", "frame"],
        );
        let e = parse_err("TX,ty,tz,qw,qx,qy,qz\n");
        check(&e, 1, Some("TX"), &["unknown column", "case-sensitive"]);
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz,\n");
        check(&e, 1, None, &["column 8 has an empty name"]);
        let e = parse_err("frame,tx,ty,tz,qw,qx,qy,qz,time\n");
        check(
            &e,
            1,
            Some("time"),
            &["both a frame and a time", "only one of frame or time"],
        );
    }

    #[test]
    fn bad_numbers() {
        let head = "tx,ty,tz,qw,qx,qy,qz,frame\n";
        for (row, column, words) in [
            (
                "0,0,nan,1,0,0,0,0",
                "tz",
                ["\"nan\" is not a finite number", "finite"],
            ),
            (
                "0,0,0,1,0,0,0,inf",
                "frame",
                ["\"inf\" is not a finite number", "finite"],
            ),
            (
                "0,0,0,1,-inf,0,0,0",
                "qx",
                ["not a finite number", "nan and inf"],
            ),
            (
                "0,0,0,1,0,0,0,1e999",
                "frame",
                ["not a finite number", "finite"],
            ),
            ("0, ,0,1,0,0,0,0", "ty", ["empty cell", "every column"]),
            (
                "abc,0,0,1,0,0,0,0",
                "tx",
                ["\"abc\" is not a number", "decimal number"],
            ),
            (
                "0,0,0,1,0,0,0,1.5s",
                "frame",
                ["\"1.5s\" is not a number", "decimal"],
            ),
        ] {
            let e = parse_err(&format!("{head}0,0,0,1,0,0,0,0\n{row}\n"));
            check(&e, 3, Some(column), &words);
        }
    }

    #[test]
    fn wrong_field_count() {
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0\n");
        check(&e, 2, None, &["6 fields", "header has 7"]);
        let e = parse_err(&format!("{MATRIX_HEADER}\n{IDENTITY_ROW},0\n"));
        check(&e, 2, None, &["17 fields", "header has 16", "extra commas"]);
    }

    #[test]
    fn last_row_must_be_0001() {
        let mut m = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5, 0.0, 2.0,
        ];
        let e = parse_err(&matrix_file(m));
        check(
            &e,
            2,
            Some("m31"),
            &["m31 is 0.5", "last row of an affine matrix is 0 0 0 1"],
        );
        m[13] = 0.0;
        let e = parse_err(&matrix_file(m));
        check(&e, 2, Some("m33"), &["m33 is 2 but must be 1", "0 0 0 1"]);
    }

    #[test]
    fn singular_matrices() {
        let cases = [
            // zero column (m01 = m11 = m21 = 0)
            [
                1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            // two parallel columns
            [
                1.0, 2.0, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            // all zero
            [0.0; 16],
            // nearly parallel columns (a tiny but clean scale is fine, see above)
            [
                1.0, 1.0, 0.0, 0.0, 0.0, 1e-13, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
        ];
        for mut m in cases {
            m[15] = 1.0;
            let e = parse_err(&format!("# c\n{MATRIX_HEADER}\n{}\n", matrix_row(m)));
            check(&e, 3, Some("m00..m22"), &["singular matrix", "invertible"]);
        }
    }

    #[test]
    fn bad_quaternions() {
        for (q, norm) in [
            ("0.5,0,0,0", "0.5"),
            ("0,0,0,0", "0"),
            ("1,1,0,0", "1.414"),
            ("1.002,0,0,0", "1.002"),
        ] {
            let e = parse_err(&format!("tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0,0\n1,2,3,{q}\n"));
            check(
                &e,
                3,
                Some("qw..qz"),
                &[
                    "bad quaternion",
                    &format!("norm is {norm}"),
                    "unit quaternion",
                    "w first",
                ],
            );
        }
        // Finite entries whose norm overflows.
        let e = parse_err("tx,ty,tz,qw,qx,qy,qz\n0,0,0,1e300,1e300,0,0\n");
        check(&e, 2, Some("qw..qz"), &["norm is inf"]);
    }

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/csv")
            .join(name)
    }

    #[test]
    fn reads_fixture_files() {
        let t = read_trajectory(&fixture("matrix_form.csv")).unwrap();
        assert_eq!(t.poses.len(), 3);
        assert!(!t.has_node_column);
        assert_eq!(
            t.poses[2].matrix.transform_point3(DVec3::ZERO),
            DVec3::new(0.2, 0.0, 0.0)
        );
        let t = read_trajectory(&fixture("pose_form_nodes.csv")).unwrap();
        assert!(t.has_node_column);
        assert_eq!(t.poses.len(), 4);
        assert_eq!(t.poses[3].node.as_deref(), Some("gripper, left"));
        assert_eq!(t.poses[3].frame, Some(1.0));
    }

    #[test]
    fn read_errors_name_the_file() {
        let missing = fixture("no_such_file.csv");
        let e = read_trajectory(&missing).unwrap_err();
        assert_eq!((e.file.as_path(), e.line), (missing.as_path(), None));
        assert!(
            e.to_string().contains("no_such_file.csv: cannot read"),
            "{e}"
        );

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("latin1.csv");
        std::fs::write(&path, b"tx,ty,tz,qw,qx,qy,qz,node\n0,0,0,1,0,0,0,gr\xfcn\n").unwrap();
        let e = read_trajectory(&path).unwrap_err();
        assert_eq!(e.line, Some(2));
        assert!(
            e.message.contains("not UTF-8") && e.fix.contains("UTF-8"),
            "{e}"
        );
    }
}
