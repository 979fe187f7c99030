//! Mutation fuzzing of every reader of user files, on stable Rust: valid seeds (the bundled
//! .glb, a .gltf with a data URI, trajectory CSVs in both forms, job.json, a depth EXR) are
//! mutated with a fixed-seed generator (byte flips, cuts, splices, repeats and hostile tokens)
//! and each result is parsed. A reader may refuse (that is the point) but must not panic and
//! must answer each input within `LIMIT`.
//!
//! The test runs `SWEPTVOL_FUZZ_ITERS` inputs per reader (default 1,500: a few seconds); the
//! longer run is the same test with more, e.g.
//! `SWEPTVOL_FUZZ_ITERS=100000 cargo test --release --test fuzz_readers -- --nocapture`.

mod common;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::time::{Duration, Instant};

use common::Rng;

/// The longest any one parse may take (a hang, not a speed target: valid seeds parse in ms).
const LIMIT: Duration = Duration::from_secs(5);

/// Tokens that have broken parsers: non-finite and huge numbers, empty and nested containers,
/// NUL, separators, signs and exponent markers.
const TOKENS: &[&[u8]] = &[
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"1e309",
    b"-1e309",
    b"1e-320",
    b"4294967295",
    b"18446744073709551616",
    b"-1",
    b"0",
    b"-0",
    b"{}",
    b"[]",
    b"[[[[[[[[",
    b"null",
    b"\"\"",
    b"\0",
    b",",
    b",,,,",
    b"\n",
    b"\r\n",
    b"#",
    b"\"",
    b"e",
    b"E+",
    b"0x10",
    b"9999999999",
];

fn iterations() -> usize {
    std::env::var("SWEPTVOL_FUZZ_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1500)
}

/// One mutation of `seed`: 1 to 4 edits.
fn mutate(rng: &mut Rng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..1 + rng.u64(..4) {
        let len = v.len().max(1) as u64;
        let at = rng.u64(..len) as usize;
        let last = v.len().saturating_sub(1);
        match rng.u64(..7) {
            0 if !v.is_empty() => v[at.min(last)] ^= 1 << rng.u64(..8),
            1 if !v.is_empty() => v[at.min(last)] = rng.u64(..256) as u8,
            2 => v.truncate(at),
            3 => {
                let end = (at + 1 + rng.u64(..64) as usize).min(v.len());
                v.drain(at.min(end)..end);
            }
            4 => {
                let t = TOKENS[rng.usize(..TOKENS.len())];
                let at = at.min(v.len());
                v.splice(at..at, t.iter().copied());
            }
            5 => {
                // Replace a run of digits by a token, where the mutation point lands in one.
                let at = at.min(v.len());
                let end = (at..v.len())
                    .find(|&i| !v[i].is_ascii_digit())
                    .unwrap_or(v.len());
                let t = TOKENS[rng.usize(..TOKENS.len())];
                v.splice(at..end, t.iter().copied());
            }
            _ => {
                // Repeat a slice (length fields now disagree with the data).
                let end = (at + 1 + rng.u64(..256) as usize).min(v.len());
                let piece = v[at.min(end)..end].to_vec();
                let to = rng.usize(..=v.len());
                v.splice(to..to, piece);
            }
        }
    }
    v
}

/// Parse mutations of each seed with `parse` on a worker thread, so that a parse that never
/// returns fails the test after `LIMIT` instead of hanging it; panics name the reader, the
/// iteration and the input's bytes (saved for reproduction).
fn fuzz(
    name: &str,
    seeds: &[Vec<u8>],
    rng_seed: u64,
    parse: impl Fn(&[u8]) -> bool + Send + 'static,
) {
    use std::sync::mpsc;
    let dir = std::env::temp_dir();
    let mut rng = Rng::with_seed(rng_seed);
    let (mut accepted, mut slowest) = (0usize, Duration::ZERO);
    let n = iterations();
    let (to_worker, inputs) = mpsc::channel::<Vec<u8>>();
    let (to_test, outcomes) = mpsc::channel();
    std::thread::spawn(move || {
        for input in inputs {
            let t = Instant::now();
            let outcome = catch_unwind(AssertUnwindSafe(|| parse(&input)));
            if to_test.send((outcome.ok(), t.elapsed())).is_err() {
                break;
            }
        }
    });
    for i in 0..n {
        let seed = &seeds[i % seeds.len()];
        let input = mutate(&mut rng, seed);
        let keep = |input: &[u8]| {
            let p = dir.join(format!("sweptvol-fuzz-{name}-{i}.bin"));
            std::fs::write(&p, input).unwrap();
            p
        };
        to_worker.send(input.clone()).unwrap();
        match outcomes.recv_timeout(LIMIT) {
            Ok((Some(ok), took)) => {
                accepted += ok as usize;
                slowest = slowest.max(took);
                let saved = || keep(&input).display().to_string();
                assert!(
                    took < LIMIT,
                    "{name}: input {i} took {took:?}; saved as {}",
                    saved()
                );
            }
            Ok((None, _)) => panic!(
                "{name}: input {i} panicked the reader; saved as {}",
                keep(&input).display()
            ),
            Err(_) => panic!(
                "{name}: input {i} did not return within {LIMIT:?}; saved as {}",
                keep(&input).display()
            ),
        }
    }
    eprintln!("fuzz {name}: {n} inputs, {accepted} accepted, 0 panics, slowest {slowest:?}");
    assert!(
        accepted < n,
        "{name}: every mutation was accepted, so nothing was mutated"
    );
    assert!(
        accepted > 0,
        "{name}: no mutation was accepted: the seeds or the reader call are broken"
    );
}

fn examples() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"))
}

#[test]
fn gltf_reader_never_panics_or_hangs() {
    let dir = tempfile::tempdir().unwrap();
    let glb = std::fs::read(examples().join("bunny.glb")).unwrap();
    // A small .gltf with its buffer as a data URI (one triangle, a node matrix).
    let gltf = br#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
"nodes":[{"name":"tri","mesh":0,"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,0.5,0,0,1]}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0},"mode":4}]}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0.5]}],
"bufferViews":[{"buffer":0,"byteLength":36}],
"buffers":[{"byteLength":36,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAA/"}]}"#
        .to_vec();
    let path = dir.path().join("fuzz.gltf");
    sweptvol::io::gltf_in::parse_generator(&path, &gltf).expect("the .gltf seed is valid");
    sweptvol::io::gltf_in::parse_generator(&path, &glb).expect("the .glb seed is valid");
    fuzz("gltf", &[glb, gltf], 0x91f_0001, move |bytes| {
        sweptvol::io::gltf_in::parse_generator(&path, bytes).is_ok()
    });
}

#[test]
fn trajectory_reader_never_panics_or_hangs() {
    let vibration = std::fs::read_to_string(examples().join("bunny-vibration.csv")).unwrap();
    let head: String = vibration
        .lines()
        .take(12)
        .map(|l| format!("{l}\n"))
        .collect();
    let matrix = "frame,node,m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n\
                  0,part,1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n\
                  1,part,1,0,0,0.5,0,1,0,0,0,0,1,0,0,0,0,1\n";
    let pose = "time,tx,ty,tz,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0.5,0.01,0,0,0.9999875,0,0.0049999,0\n";
    let path = Path::new("fuzz.csv");
    for seed in [&head, matrix, pose] {
        sweptvol::io::trajectory::parse_trajectory(path, seed).expect("the CSV seeds are valid");
    }
    let seeds = [head.clone(), matrix.into(), pose.into()].map(String::into_bytes);
    fuzz("csv", &seeds, 0xc5f_0002, move |bytes| {
        // The reader takes text: invalid UTF-8 is refused before it (read_trajectory's job).
        match std::str::from_utf8(bytes) {
            Ok(text) => sweptvol::io::trajectory::parse_trajectory(path, text).is_ok(),
            Err(_) => false,
        }
    });
}

#[test]
fn job_options_reader_never_panics_or_hangs() {
    let seeds = [
        br#"{"resolution": 256}"#.to_vec(),
        br#"{"tolerance": 0.01, "backend": "cpu", "name": "part", "target_triangles": 5000, "keep_start_mesh": true}"#.to_vec(),
        br#"{"resolution": 64, "delta": 0.1, "epsilon": 0.03}"#.to_vec(),
    ];
    let path = Path::new("job.json");
    for s in &seeds {
        sweptvol::watch::protocol::parse_job_options(path, s)
            .expect("the job.json seeds are valid");
    }
    fuzz("job.json", &seeds, 0x10b_0003, move |bytes| {
        sweptvol::watch::protocol::parse_job_options(path, bytes).is_ok()
    });
}

#[test]
fn depth_exr_reader_never_panics_or_hangs() {
    use sweptvol::depth::DepthImages;
    use sweptvol::input::grid::Grid;
    use sweptvol::io::exr_depth::{read_depth_exr, write_depth_exr, ExtraMeta, Side};

    let dir = tempfile::tempdir().unwrap();
    let grid = Grid {
        origin: [0.0; 3],
        h: 0.1,
        dims: [6, 5, 4],
    };
    let mut images = DepthImages::empty(grid);
    for (k, img) in images.images.iter_mut().enumerate() {
        for i in (0..img.min.len()).step_by(2) {
            (img.min[i], img.max[i]) = (1.0 + k as f32, 3.5);
        }
    }
    let extra = ExtraMeta {
        delta: 0.25,
        rounding: 1e-6,
    };
    let seed_path = dir.path().join("seed.exr");
    write_depth_exr(&seed_path, &images, 0, Side::Min, &extra).unwrap();
    read_depth_exr(&seed_path).expect("the EXR seed is valid");
    let seed = std::fs::read(&seed_path).unwrap();
    let path = dir.path().join("fuzz.exr");
    fuzz("exr", &[seed], 0xe4f_0004, move |bytes| {
        std::fs::write(&path, bytes).unwrap();
        read_depth_exr(&path).is_ok()
    });
}
