//! The memory estimate (`input::memory`) against the peak the real binary reaches: the bundled
//! example at two resolutions, each run's peak resident set read from the kernel
//! (getrusage of the finished child). Alone in its file: the children's peak is the largest
//! of every child this process waited for, so nothing else may run beside it.

use std::process::Command;

use sweptvol::input::grid::Grid;
use sweptvol::input::memory::estimate;

/// The largest resident set of any finished child so far, bytes.
fn children_peak() -> f64 {
    // SAFETY: getrusage writes only the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(
        unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) },
        0
    );
    usage.ru_maxrss as f64 * 1024.0 // kilobytes on Linux
}

#[test]
fn the_estimate_stays_above_the_measured_peak() {
    let dir = tempfile::tempdir().unwrap();
    // Smaller first: the peak read after each run is then that run's own.
    for n in [128, 256] {
        let out = dir.path().join(format!("n{n}"));
        let status = Command::new(env!("CARGO_BIN_EXE_sweptvol"))
            .args(["run", "--generator", "examples/bunny.glb"])
            .args(["--trajectory", "examples/bunny-vibration.csv"])
            .arg("--out")
            .arg(&out)
            .args(["--resolution", &n.to_string()])
            .args(["--motion", "discrete", "--backend", "cpu", "--quiet"])
            .env("RUST_LOG", "warn")
            .status()
            .expect("run sweptvol");
        assert!(status.success(), "n = {n}: {status}");
        let peak = children_peak();
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join("bunny-vibration.report.json")).unwrap(),
        )
        .unwrap();
        let grid: Grid = serde_json::from_value(report["grid"].clone()).unwrap();
        let flood = report["classification"]["method"] == "flood";
        let estimated = estimate(&grid, false, flood);
        println!(
            "n = {n}: measured peak {:.0} MB, estimated {:.0} MB",
            peak / 1e6,
            estimated / 1e6
        );
        assert!(
            estimated >= peak,
            "n = {n}: estimate {estimated:.3e} B below the measured peak {peak:.3e} B"
        );
    }
}
