//! Triangle meshes of a robot description's links: STL (binary or ASCII) and Wavefront OBJ
//! (`v` and `f` lines; polygons as fans; other lines ignored). glTF goes through `gltf_in`.
//! Positions stay as the file's f32 values; errors name the file and the line or triangle.

use std::path::Path;

use crate::error::InputError;

/// Positions and triangles (indices into the positions).
pub type Mesh = (Vec<[f32; 3]>, Vec<[u32; 3]>);

const FIX_STL: &str = "export the mesh again as binary or ASCII STL";

/// Read an STL file: binary when its size is 84 + 50 × the triangle count of its header,
/// else ASCII (`vertex x y z` lines, three per facet).
pub fn read_stl(path: &Path, bytes: &[u8]) -> Result<Mesh, InputError> {
    if bytes.len() >= 84 {
        let count = u32::from_le_bytes(bytes[80..84].try_into().expect("4 bytes")) as usize;
        if Some(bytes.len()) == count.checked_mul(50).and_then(|n| n.checked_add(84)) {
            let mut positions = Vec::with_capacity(3 * count);
            for t in 0..count {
                let at = 84 + 50 * t + 12; // after the normal
                for v in 0..3 {
                    let p: [f32; 3] = std::array::from_fn(|c| {
                        let o = at + 12 * v + 4 * c;
                        f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"))
                    });
                    if !p.iter().all(|x| x.is_finite()) {
                        return Err(InputError::new(
                            path,
                            format!("triangle {t} has a coordinate that is not a finite number"),
                            FIX_STL,
                        ));
                    }
                    positions.push(p);
                }
            }
            return Ok(fan_free(positions));
        }
    }
    let text = std::str::from_utf8(bytes).map_err(|_| {
        InputError::new(
            path,
            "neither binary STL (its size does not match the triangle count) nor ASCII STL text",
            FIX_STL,
        )
    })?;
    if !text.trim_start().starts_with("solid") {
        return Err(InputError::new(
            path,
            "not an STL file: ASCII STL starts with \"solid\", and the size does not match a binary STL",
            FIX_STL,
        ));
    }
    let mut positions = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("vertex") {
            continue;
        }
        positions.push(three_numbers(path, i as u64 + 1, words)?);
    }
    if positions.len() % 3 != 0 {
        return Err(InputError::new(
            path,
            format!("{} vertex lines: not three per facet", positions.len()),
            FIX_STL,
        ));
    }
    Ok(fan_free(positions))
}

/// Triangles of consecutive position triples.
fn fan_free(positions: Vec<[f32; 3]>) -> Mesh {
    let triangles = (0..positions.len() as u32 / 3)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    (positions, triangles)
}

fn three_numbers<'a>(
    path: &Path,
    line: u64,
    mut words: impl Iterator<Item = &'a str>,
) -> Result<[f32; 3], InputError> {
    let mut p = [0f32; 3];
    for x in &mut p {
        *x = words
            .next()
            .and_then(|w| w.parse::<f32>().ok())
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                InputError::new(
                    path,
                    "a vertex needs three finite numbers",
                    "fix the vertex line",
                )
                .at_line(line)
            })?;
    }
    Ok(p)
}

/// Read a Wavefront OBJ file's vertices and faces (1-based or negative indices, `v/vt/vn`
/// forms); faces of n corners become n - 2 triangles.
pub fn read_obj(path: &Path, bytes: &[u8]) -> Result<Mesh, InputError> {
    let text = std::str::from_utf8(bytes).map_err(|_| {
        InputError::new(
            path,
            "not an OBJ text file (not UTF-8)",
            "export the mesh again as OBJ",
        )
    })?;
    let (mut positions, mut triangles) = (Vec::new(), Vec::new());
    for (i, line) in text.lines().enumerate() {
        let line_no = i as u64 + 1;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => positions.push(three_numbers(path, line_no, words)?),
            Some("f") => {
                let corners = words
                    .map(|w| {
                        let first = w.split('/').next().unwrap_or_default();
                        let k: i64 = first.parse().map_err(|_| {
                            InputError::new(path, format!("face corner {w:?} is not a vertex index"), "fix the face line").at_line(line_no)
                        })?;
                        let n = positions.len() as i64;
                        let index = if k < 0 { n + k } else { k - 1 };
                        if !(0..n).contains(&index) {
                            return Err(InputError::new(
                                path,
                                format!("face corner {k} names no vertex read so far ({n} vertices)"),
                                "fix the face line: OBJ indices start at 1 and refer to earlier v lines",
                            )
                            .at_line(line_no));
                        }
                        Ok(index as u32)
                    })
                    .collect::<Result<Vec<u32>, _>>()?;
                if corners.len() < 3 {
                    return Err(InputError::new(
                        path,
                        "a face needs at least three corners",
                        "fix the face line",
                    )
                    .at_line(line_no));
                }
                for k in 1..corners.len() - 1 {
                    triangles.push([corners[0], corners[k], corners[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Ok((positions, triangles))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_and_ascii_stl_and_obj_read_the_same_triangle() {
        let p = Path::new("m");
        let mut bin = vec![0u8; 80];
        bin.extend(1u32.to_le_bytes());
        bin.extend([0f32; 3].iter().flat_map(|x| x.to_le_bytes()));
        for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]] {
            bin.extend(v.iter().flat_map(|x| x.to_le_bytes()));
        }
        bin.extend([0u8; 2]);
        let (pos, tri) = read_stl(p, &bin).unwrap();
        assert_eq!((pos[2], tri), ([0.0, 2.0, 0.0], vec![[0, 1, 2]]));
        let ascii = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 2 0\nendloop\nendfacet\nendsolid\n";
        assert_eq!(read_stl(p, ascii.as_bytes()).unwrap().0, pos);
        let obj = "# x\nv 0 0 0\nv 1 0 0\nv 0 2 0\nv 1 2 0\nf 1/1/1 2 -1 3\n";
        let (pos, tri) = read_obj(p, obj.as_bytes()).unwrap();
        assert_eq!(pos.len(), 4);
        assert_eq!(tri, vec![[0, 1, 3], [0, 3, 2]]);
    }

    #[test]
    fn bad_meshes_are_refused_by_line() {
        let p = Path::new("m");
        assert!(read_stl(p, b"hello").is_err());
        let e = read_stl(p, b"solid x\nvertex 0 0 nan\n").unwrap_err();
        assert_eq!(e.line, Some(2));
        let e = read_obj(p, b"v 0 0 0\nf 1 2 3\n").unwrap_err();
        assert_eq!(e.line, Some(2));
        assert!(e.message.contains("names no vertex"), "{e}");
    }
}
