//! The depth images survive the trip through EXR files: read back by sweptvol they are still
//! conservative (outward rounding), and an independent reader (the reference OpenEXR library,
//! through Python) sees the same values bit for bit and the same metadata.

mod common;

use std::path::Path;
use std::process::Command;

use common::{check_samples, posed_grid_triangles, Rng};
use glam::{DMat4, DVec3};
use sweptvol::input::grid::{Accuracy, Overrides};
use sweptvol::input::model::Trajectory;
use sweptvol::input::motion::Motion;
use sweptvol::input::posed;
use sweptvol::io::exr_depth::{self, ExtraMeta, Side};
use sweptvol::io::gltf_in;
use sweptvol::sweep::{cpu, Silent};

#[test]
fn exr_round_trip_is_outward_and_independently_readable() {
    let generator = gltf_in::read_generator(Path::new("examples/bunny.glb")).unwrap();
    let poses: Vec<DMat4> = (0..6)
        .map(|k| {
            DMat4::from_translation(DVec3::new(0.3 * k as f64, 0.0, -0.2 * k as f64))
                * DMat4::from_rotation_y(0.1 * k as f64)
        })
        .collect();
    let traj = Trajectory::whole_scene(&poses);
    let input = posed::build(
        &generator,
        Path::new("bunny.glb"),
        &traj,
        Path::new("t.csv"),
        Accuracy::Resolution(40),
        Overrides::default(),
        Motion::Discrete,
    )
    .unwrap();
    let images = cpu::sweep(&input, &Silent).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let extra = ExtraMeta {
        delta: input.params.delta,
        rounding: input.rounding * input.grid.h,
    };
    let files = exr_depth::write_all(dir.path(), "bunny", &images, &extra).unwrap();

    // sweptvol's own reader: outward, close, and still conservative on sampled points.
    let (back, back_extra) = exr_depth::read_all(dir.path(), "bunny").unwrap();
    assert_eq!(back.grid, images.grid);
    assert_eq!(back_extra.delta, extra.delta);
    for (b, o) in back.images.iter().zip(&images.images) {
        for i in 0..o.min.len() {
            assert_eq!(b.is_empty_at(i), o.is_empty_at(i));
            if !o.is_empty_at(i) {
                assert!(
                    b.min[i] <= o.min[i] && b.max[i] >= o.max[i],
                    "not outward at {i}"
                );
                assert!(
                    o.min[i] - b.min[i] < 1e-4 && b.max[i] - o.max[i] < 1e-4,
                    "drifted at {i}"
                );
            }
        }
    }
    let tris = posed_grid_triangles(&generator, &poses, &input);
    assert!(check_samples(&input, &back, &tris, &mut Rng::with_seed(5)) > 10_000);

    // The independent reader.
    let Some(python) = common::test_python("OpenEXR, numpy", "the independent EXR reader") else {
        return;
    };
    for (k, path) in files.iter().enumerate() {
        let (axis, side) = (k / 2, if k % 2 == 0 { Side::Min } else { Side::Max });
        let out = Command::new(&python)
            .arg("tests/exr_independent_read.py")
            .arg(path)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(j["channels"], serde_json::json!(["Y", "Z"]));
        assert_eq!(j["dtypes"]["Z"], "float32");
        assert_eq!(j["dtypes"]["Y"], "float32");
        let (meta, z) = exr_depth::read_depth_exr(path).unwrap();
        assert_eq!(
            (j["width"].as_u64().unwrap(), j["height"].as_u64().unwrap()),
            (meta.width as u64, meta.height as u64)
        );
        let bits: Vec<u32> = j["z_bits"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u32)
            .collect();
        assert_eq!(
            bits,
            z.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{}: Z differs",
            path.display()
        );
        let empty = images.images[axis].min.len() - images.images[axis].hit_count();
        assert_eq!(j["inf_count"].as_u64().unwrap() as usize, empty);
        let their: serde_json::Value = serde_json::from_str(j["meta"].as_str().unwrap()).unwrap();
        assert_eq!(their["axis"], ["x", "y", "z"][axis]);
        assert_eq!(their["side"], side.name());
        for key in [
            "pixel00_centre",
            "column_step",
            "row_step",
            "voxel_size",
            "camera_plane",
        ] {
            let ours = serde_json::to_value(&meta).unwrap();
            let (a, b) = (&their[key], &ours[key]);
            let close = |x: &serde_json::Value, y: &serde_json::Value| {
                (x.as_f64().unwrap() - y.as_f64().unwrap()).abs()
                    <= 1e-12 * (1.0 + y.as_f64().unwrap().abs())
            };
            let ok = match (a.as_array(), b.as_array()) {
                (Some(xa), Some(ya)) => xa.iter().zip(ya).all(|(x, y)| close(x, y)),
                _ => close(a, b),
            };
            assert!(ok, "{key}: python {a} vs rust {b}");
        }
        assert_eq!(j["attributes"]["sweptvol:axis"], ["x", "y", "z"][axis]);
        assert!(j["attributes"]["sweptvol:voxelSize"].as_f64().unwrap() > 0.0);
    }
}
