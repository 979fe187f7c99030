//! The swept-volume mesh in the formats the next tools of a clearance workflow read: binary STL
//! (slicers, CAD import), binary little-endian PLY and OBJ. Same vertices (f32 world positions,
//! as in the .glb), same outward-wound triangles; written through `atomic::Staged` like every
//! other output.

use crate::input::grid::Grid;
use crate::io::gltf_out::world_positions;
use crate::job::MeshFormat;
use crate::mesh::Mesh;

impl MeshFormat {
    /// The file's bytes for `mesh` (grid units) in world coordinates.
    pub fn bytes(self, mesh: &Mesh, grid: &Grid, name: &str) -> Vec<u8> {
        let (positions, _) = world_positions(mesh, grid);
        match self {
            MeshFormat::Stl => stl(&positions, &mesh.triangles, name),
            MeshFormat::Ply => ply(&positions, &mesh.triangles, name),
            MeshFormat::Obj => obj(&positions, &mesh.triangles, name),
        }
    }
}

/// Header text without line breaks (it goes into one header line or comment).
fn one_line(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect()
}

fn stl(p: &[[f32; 3]], tris: &[[u32; 3]], name: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(84 + 50 * tris.len());
    // An 80-byte header that must not start with "solid" (ASCII STL readers would take it).
    let mut header = format!("sweptvol binary STL: {}", one_line(name)).into_bytes();
    header.resize(80, b' ');
    out.extend_from_slice(&header);
    out.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        let [a, b, c] = t.map(|i| glam::Vec3::from(p[i as usize]).as_dvec3());
        let n = (b - a).cross(c - a).normalize_or_zero().as_vec3();
        for v in [
            n.to_array(),
            p[t[0] as usize],
            p[t[1] as usize],
            p[t[2] as usize],
        ] {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    out
}

fn ply(p: &[[f32; 3]], tris: &[[u32; 3]], name: &str) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment sweptvol swept volume: {}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        one_line(name),
        p.len(),
        tris.len()
    );
    let mut out = header.into_bytes();
    out.reserve(12 * p.len() + 13 * tris.len());
    for v in p {
        for x in v {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for t in tris {
        out.push(3);
        for i in t {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

fn obj(p: &[[f32; 3]], tris: &[[u32; 3]], name: &str) -> Vec<u8> {
    use std::fmt::Write;
    let mut s = format!(
        "# sweptvol swept volume: {}\no swept_volume\n",
        one_line(name)
    );
    // `{}` prints an f32 as the shortest decimal that reads back to the same f32.
    for v in p {
        let _ = writeln!(s, "v {} {} {}", v[0], v[1], v[2]);
    }
    for t in tris {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// A unit cube of voxels at grid (1, 2, 3), h = 0.5, origin (-1, 0, 1).
    fn cube() -> (Mesh, Grid) {
        let set = crate::mesh::classify::DenseSet::from_list([3, 4, 5], &[[1, 2, 3]]);
        let grid = Grid {
            origin: [-1.0, 0.0, 1.0],
            h: 0.5,
            dims: [3, 4, 5],
        };
        (crate::mesh::extract::extract(&set), grid)
    }

    fn f32s(b: &[u8]) -> Vec<f32> {
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    #[test]
    fn stl_reads_back_with_outward_normals() {
        let (mesh, grid) = cube();
        let b = MeshFormat::Stl.bytes(&mesh, &grid, "cube");
        assert!(!b.starts_with(b"solid"));
        let n = u32::from_le_bytes(b[80..84].try_into().unwrap()) as usize;
        assert_eq!((n, b.len()), (12, 84 + 50 * 12));
        let centre = grid.to_world(DVec3::new(1.5, 2.5, 3.5));
        for f in 0..n {
            let rec = f32s(&b[84 + 50 * f..84 + 50 * f + 48]);
            let normal = DVec3::new(rec[0] as f64, rec[1] as f64, rec[2] as f64);
            let v0 = DVec3::new(rec[3] as f64, rec[4] as f64, rec[5] as f64);
            assert!((normal.length() - 1.0).abs() < 1e-6);
            assert!(normal.dot(v0 - centre) > 0.0, "facet {f} faces inward");
            for k in 0..3 {
                let p = DVec3::new(
                    rec[3 + 3 * k] as f64,
                    rec[4 + 3 * k] as f64,
                    rec[5 + 3 * k] as f64,
                );
                assert!((p - centre).abs().max_element() == 0.25, "{p}");
            }
        }
    }

    #[test]
    fn ply_and_obj_read_back_to_the_same_vertices_and_triangles() {
        let (mesh, grid) = cube();
        let (want, _) = world_positions(&mesh, &grid);

        let b = MeshFormat::Ply.bytes(&mesh, &grid, "cube");
        let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let header = std::str::from_utf8(&b[..end]).unwrap();
        assert!(header.contains("element vertex 8\n") && header.contains("element face 12\n"));
        let verts = f32s(&b[end..end + 12 * 8]);
        assert_eq!(verts, want.concat());
        let faces = &b[end + 96..];
        assert_eq!(faces.len(), 13 * 12);
        for (f, t) in faces.chunks_exact(13).zip(&mesh.triangles) {
            assert_eq!(f[0], 3);
            let idx: Vec<u32> = f[1..]
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
                .collect();
            assert_eq!(idx, t.to_vec());
        }

        let text = String::from_utf8(MeshFormat::Obj.bytes(&mesh, &grid, "cube\nx")).unwrap();
        let v: Vec<[f32; 3]> = text
            .lines()
            .filter_map(|l| l.strip_prefix("v "))
            .map(|l| {
                let x: Vec<f32> = l.split(' ').map(|s| s.parse().unwrap()).collect();
                [x[0], x[1], x[2]]
            })
            .collect();
        assert_eq!(v, want);
        let f: Vec<[u32; 3]> = text
            .lines()
            .filter_map(|l| l.strip_prefix("f "))
            .map(|l| {
                let x: Vec<u32> = l
                    .split(' ')
                    .map(|s| s.parse::<u32>().unwrap() - 1)
                    .collect();
                [x[0], x[1], x[2]]
            })
            .collect();
        assert_eq!(f, mesh.triangles);
        assert_eq!(text.lines().next(), Some("# sweptvol swept volume: cube x"));
    }
}
