//! One job swept in shards (on a cluster, one array task each) and merged exactly.
//!
//! The depth images are a min and a max over posed triangles, and the reach an OR over them, so
//! the sweep splits over poses with no loss: shard I of N sweeps its share of every part's poses
//! ([`crate::input::posed::SweepInput::shard_windows`], balanced by posed triangles) on the whole job's grid, radius
//! and rounding term, and the merge takes the min, max and OR of the shards' encoded buffers,
//! which is bit for bit what one sweep of all poses leaves (atomic min and max are
//! order-independent).
//!
//! A shard writes two files into its folder: `shard-IIII-of-NNNN.bin`, the data, and then
//! `shard-IIII-of-NNNN.json`, its [`Manifest`] (the job, the inputs' hashes, the grid, which
//! poses, the data's length and hash). A manifest therefore exists only for a finished shard,
//! and the merge refuses any set of manifests that is not exactly one job's N shards.

use std::ops::Range;
use std::path::PathBuf;

use super::{build, output_paths, prepare, Prepared, RunOptions, Swept};
use crate::depth::DepthImages;
use crate::error::InputError;
use crate::input::grid::Accuracy;
use crate::io::shard_files::{
    self, decode_into, encode_data, find_manifests, fnv1a64_hex, read_data, read_manifest, JobSpec,
    Manifest, ShardId,
};
use crate::sweep::backend::Backend;
use crate::sweep::Observer;
use crate::voxels::VoxelBits;

/// What [`sweep_shard`] did.
pub enum ShardOutcome {
    Swept(Box<Manifest>),
    /// A finished shard of the same job was there already (its manifest path).
    AlreadyDone(PathBuf),
}

/// Sweep shard `shard` of the job `opts` describes into `opts.out_dir`. A finished shard of the
/// same job (same inputs and options) there is kept and the sweep skipped; one of another job
/// is an error unless `opts.overwrite`.
pub fn sweep_shard(
    opts: &RunOptions,
    shard: ShardId,
    backend: &Backend,
    observer: &dyn Observer,
) -> anyhow::Result<ShardOutcome> {
    let spec = opts.spec()?;
    let dir = &opts.out_dir;
    let manifest_path = dir.join(format!("{}.json", shard.stem()));
    if manifest_path.exists() {
        match read_manifest(&manifest_path).and_then(|m| read_data(&manifest_path, &m).map(|_| m)) {
            Ok(old) if old.job == spec && old.shard == shard => {
                return Ok(ShardOutcome::AlreadyDone(manifest_path))
            }
            Ok(old) if !opts.overwrite => {
                let why = if old.job.same_inputs(&spec) {
                    format!(
                        "other options ({})",
                        spec.differences(&old.job, "this run has")
                    )
                } else {
                    "other inputs".to_string()
                };
                return Err(InputError::new(
                    &manifest_path,
                    format!("a finished shard of another job is here: it was swept with {why}"),
                    "give each job its own --out folder, or pass --overwrite to replace it",
                )
                .into());
            }
            Ok(_) => {}
            // Unreadable or damaged: sweep again over it.
            Err(e) => tracing::warn!("{e:#}; sweeping shard {} again", shard.stem()),
        }
    }
    // The whole job, as `run` would prepare it, then restricted to this shard's poses. The
    // memory check is the merge's business: a shard holds only the images (and the reach).
    let whole = build(
        &RunOptions {
            check_memory: false,
            ..opts.clone()
        },
        output_paths(opts)?,
    )?;
    let windows = whole.input.shard_windows(shard.index - 1, shard.count);
    let job_posed_triangles = whole.input.posed_triangles();
    let job = Prepared {
        input: whole.input.restricted(windows.clone()),
        ..whole
    };
    tracing::info!(
        "shard {}/{}: {} of the job's poses, {} posed triangles",
        shard.index,
        shard.count,
        crate::sweep::total_poses(&job.input),
        job.input.posed_triangles()
    );
    let swept = super::sweep(&job, backend, observer)?;
    let data = encode_data(&swept.images, swept.reach.as_ref());
    let data_name = format!("{}.bin", shard.stem());
    let manifest = Manifest {
        format: shard_files::FORMAT.into(),
        version: shard_files::VERSION,
        sweptvol_version: env!("CARGO_PKG_VERSION").into(),
        shard,
        job: spec,
        grid: job.input.grid,
        radius_bits: job.input.radius.to_bits(),
        rounding: job.input.rounding,
        windows: windows.iter().map(|w| [w.start, w.end]).collect(),
        poses: crate::sweep::total_poses(&job.input),
        posed_triangles: job.input.posed_triangles(),
        job_posed_triangles,
        reach: swept.reach.is_some(),
        data_bytes: data.len() as u64,
        data_hash: fnv1a64_hex(&data),
        data: data_name.clone(),
        backend: swept.backend,
        sweep_seconds: swept.seconds,
    };
    shard_files::write(dir, &manifest, &data)?;
    Ok(ShardOutcome::Swept(Box::new(manifest)))
}

/// The shards in `dirs` checked as one complete job and merged, with the whole job prepared
/// to write into `out_dir` (`name` overrides the job's output name): ready for `finish`.
pub fn merge(
    dirs: &[PathBuf],
    out_dir: PathBuf,
    name: Option<String>,
    overwrite: bool,
) -> anyhow::Result<(Prepared, Swept)> {
    let set = ShardSet::read(dirs)?;
    let first = &set.shards[0].1;
    let mut opts = RunOptions::of_spec(&first.job, out_dir, overwrite);
    if name.is_some() {
        opts.job.name = name;
    }
    // The inputs must be those the shards swept.
    let now = opts.spec()?;
    for (path, was, is) in [
        (
            &opts.generator,
            &first.job.generator_hash,
            &now.generator_hash,
        ),
        (
            &opts.trajectory,
            &first.job.trajectory_hash,
            &now.trajectory_hash,
        ),
    ] {
        if was != is {
            let what = if crate::io::urdf::is_robot(path) {
                "changed since the shards were swept, or a mesh file it names did (the hash covers them)"
            } else {
                "changed since the shards were swept (its hash differs)"
            };
            return Err(
                InputError::new(path, what, "sweep the shards again, or restore the file").into(),
            );
        }
    }
    let job = prepare(&opts)?;
    let input = &job.input;
    for (path, m) in &set.shards {
        let windows: Vec<Range<u64>> = input.shard_windows(m.shard.index - 1, m.shard.count);
        let ours: Vec<[u64; 2]> = windows.iter().map(|w| [w.start, w.end]).collect();
        let differs: Vec<&str> = [
            (m.grid != input.grid, "grid"),
            (m.radius_bits != input.radius.to_bits(), "radius"),
            (m.rounding != input.rounding, "rounding term"),
            (m.windows != ours, "share of the poses"),
            (m.reach != job.classify.flood, "reach"),
        ]
        .into_iter()
        .filter_map(|(d, what)| d.then_some(what))
        .collect();
        if !differs.is_empty() {
            return Err(InputError::new(
                path,
                format!(
                    "its {} differ from what this sweptvol ({}) derives from the same inputs and options (the shard's: sweptvol {})",
                    differs.join(", "),
                    env!("CARGO_PKG_VERSION"),
                    m.sweptvol_version
                ),
                "sweep every shard and merge with one sweptvol build",
            )
            .into());
        }
    }
    let mut encoded = crate::sweep::empty_encoded(input);
    let dims = input.grid.dims.map(|d| d as usize);
    let mut reach = job.classify.flood.then(|| VoxelBits::new(dims));
    let mut backends: Vec<String> = Vec::new();
    let mut seconds = 0.0;
    for (path, m) in &set.shards {
        let data = read_data(path, m)?;
        // Depths lie within the rendered radius of the grid along their axis (grid units).
        let limits = [0, 1, 2].map(|a| {
            let margin = input.radius + 1.0;
            (-margin, input.grid.dims[a] as f32 + margin)
        });
        decode_into(&data, &mut encoded, reach.as_mut(), limits).map_err(|e| {
            InputError::new(
                &path.with_file_name(&m.data),
                e,
                "sweep the shard again with this sweptvol",
            )
        })?;
        if !backends.contains(&m.backend) {
            backends.push(m.backend.clone());
        }
        seconds += m.sweep_seconds;
    }
    for (path, m) in &set.copies {
        read_data(path, m).map_err(|e| match e.downcast::<InputError>() {
            Ok(mut e) => {
                e.fix = format!(
                    "remove this copy of shard {} (another folder holds it whole), or sweep it again",
                    m.shard.index
                );
                e.into()
            }
            Err(e) => e,
        })?;
    }
    let images = DepthImages::from_encoded(input.grid, encoded);
    let swept = Swept {
        images,
        reach,
        backend: format!("{} shards: {}", set.count, backends.join("; ")),
        seconds,
    };
    Ok((job, swept))
}

/// One job's complete set of shards, read from their folders and checked against each other.
pub struct ShardSet {
    pub count: u32,
    /// (manifest path, manifest) in index order.
    pub shards: Vec<(PathBuf, Manifest)>,
    /// Further copies of those shards (the same data hash), in name order: their data is
    /// checked too, so a corrupt copy is found whichever folder comes first.
    pub copies: Vec<(PathBuf, Manifest)>,
}

impl ShardSet {
    pub fn read(dirs: &[PathBuf]) -> anyhow::Result<ShardSet> {
        let progress = ShardProgress::read(dirs)?;
        if let Some((path, why)) = progress.foreign.first() {
            return Err(InputError::new(
                path,
                why.clone(),
                "remove it, or merge from the right folder",
            )
            .into());
        }
        if !progress.missing.is_empty() {
            let (p, m) = &progress.done[0];
            let n = progress.missing.len();
            return Err(InputError::new(
                p.parent().unwrap_or(p),
                format!(
                    "{} missing (no shard-IIII-of-{:04}.json {})",
                    if n == 1 {
                        format!("shard {} of {}", progress.missing[0], m.shard.count)
                    } else {
                        format!(
                            "{n} shards of {}: {}",
                            m.shard.count,
                            index_ranges(&progress.missing)
                        )
                    },
                    m.shard.count,
                    // The error names the first folder; others are listed once.
                    if dirs.len() == 1 {
                        "there".to_string()
                    } else {
                        let all: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
                        format!("in {}", all.join(", "))
                    }
                ),
                format!(
                    "wait for them, or run `sweptvol sweep --shard I/{} ...` for each with the job's options",
                    m.shard.count
                ),
            )
            .into());
        }
        Ok(ShardSet {
            count: progress.done[0].1.shard.count,
            shards: progress.done,
            copies: progress.copies,
        })
    }
}

/// Shard indices (ascending) as ranges, `1-5, 7, 9-12`, at most `LISTED_RANGES` (12) of them
/// and then how many indices the rest hold: a message stays a line at any shard count.
pub fn index_ranges(indices: &[u32]) -> String {
    let mut ranges: Vec<(u32, u32)> = Vec::new();
    for &i in indices {
        match ranges.last_mut() {
            Some((_, hi)) if *hi + 1 == i => *hi = i,
            _ => ranges.push((i, i)),
        }
    }
    let shown: Vec<String> = ranges
        .iter()
        .take(LISTED_RANGES)
        .map(|&(lo, hi)| match hi - lo {
            0 => lo.to_string(),
            1 => format!("{lo}, {hi}"),
            _ => format!("{lo}-{hi}"),
        })
        .collect();
    let rest: u32 = ranges
        .iter()
        .skip(LISTED_RANGES)
        .map(|(lo, hi)| hi - lo + 1)
        .sum();
    let mut out = shown.join(", ");
    if rest > 0 {
        out += &format!(" and {rest} more");
    }
    out
}

/// Ranges [`index_ranges`] spells out before it counts the rest.
const LISTED_RANGES: usize = 12;

/// What the manifests in some folders say of one job: which shards are done, which missing,
/// and any manifest that belongs elsewhere.
pub struct ShardProgress {
    /// Finished shards of the job, (manifest, contents) in index order.
    pub done: Vec<(PathBuf, Manifest)>,
    /// Indices (1-based) with no manifest.
    pub missing: Vec<u32>,
    /// Manifests of shards already in `done` with the same data hash.
    pub copies: Vec<(PathBuf, Manifest)>,
    /// Manifests of another job or shard set, or unreadable, and why.
    pub foreign: Vec<(PathBuf, String)>,
}

impl ShardProgress {
    /// The job is the one most manifests belong to (the first in name order on a tie).
    pub fn read(dirs: &[PathBuf]) -> anyhow::Result<ShardProgress> {
        let paths = find_manifests(dirs)?;
        if paths.is_empty() {
            return Err(InputError::new(
                &dirs[0],
                "no shard manifests (shard-IIII-of-NNNN.json) here",
                "give the --out folder of `sweptvol sweep --shard`, after at least one shard finished",
            )
            .into());
        }
        let mut read = Vec::new();
        let mut foreign = Vec::new();
        for p in paths {
            match read_manifest(&p) {
                Ok(m) => read.push((p, m)),
                Err(e) => foreign.push((p, format!("{e:#}"))),
            }
        }
        // Group the manifests by (job, count) in one pass; the largest group is the job.
        let mut groups: Vec<(&JobSpec, u32, usize)> = Vec::new();
        for (_, m) in &read {
            match groups
                .iter_mut()
                .find(|(j, c, _)| **j == m.job && *c == m.shard.count)
            {
                Some(g) => g.2 += 1,
                None => groups.push((&m.job, m.shard.count, 1)),
            }
        }
        // max_by_key keeps the last of equals: reversed, ties go to the first in name order.
        let reference = groups
            .iter()
            .rev()
            .max_by_key(|g| g.2)
            .map(|(j, c, _)| ((*j).clone(), *c));
        let Some((job, count)) = reference else {
            let (p, why) = &foreign[0];
            return Err(InputError::new(p, why.clone(), "sweep the shards again").into());
        };
        let mut done: Vec<(PathBuf, Manifest)> = Vec::new();
        let mut copies = Vec::new();
        for (p, m) in read {
            match fit(&job, count, &m, &done) {
                Fit::Done => done.push((p, m)),
                Fit::Copy => copies.push((p, m)),
                Fit::Foreign(why) => foreign.push((p, why)),
            }
        }
        done.sort_by_key(|(_, m)| m.shard.index);
        let missing = (1..=count)
            .filter(|i| !done.iter().any(|(_, m)| m.shard.index == *i))
            .collect();
        Ok(ShardProgress {
            done,
            missing,
            copies,
            foreign,
        })
    }
}

/// How one manifest fits the job a set of manifests is taken to be.
enum Fit {
    /// A shard of the job, the first with its index.
    Done,
    /// A copy of a shard already taken (the same data): counts once.
    Copy,
    /// Of another job, other options, another split, or its index twice with other data.
    Foreign(String),
}

fn fit(job: &JobSpec, count: u32, m: &Manifest, done: &[(PathBuf, Manifest)]) -> Fit {
    if !m.job.same_inputs(job) {
        return Fit::Foreign(format!(
            "a shard of another job: its inputs are {} ({}) and {} ({}), the others' {} ({}) and {} ({})",
            m.job.generator.display(),
            m.job.generator_hash,
            m.job.trajectory.display(),
            m.job.trajectory_hash,
            job.generator.display(),
            job.generator_hash,
            job.trajectory.display(),
            job.trajectory_hash
        ));
    }
    if m.job != *job {
        return Fit::Foreign(format!(
            "a shard of the same inputs swept with other options ({})",
            job.differences(&m.job, "the others have")
        ));
    }
    if m.shard.count != count {
        return Fit::Foreign(format!(
            "shard {} of {}, where the others are of {count}",
            m.shard.index, m.shard.count
        ));
    }
    match done.iter().find(|(_, d)| d.shard.index == m.shard.index) {
        None => Fit::Done,
        Some((_, d)) if d.data_hash == m.data_hash => Fit::Copy,
        Some((q, _)) => Fit::Foreign(format!(
            "shard {} of {count} appears twice with different data (also {})",
            m.shard.index,
            q.display()
        )),
    }
}

impl RunOptions {
    /// The run a job's shards make up, writing to `out_dir`.
    pub fn of_spec(spec: &JobSpec, out_dir: PathBuf, overwrite: bool) -> RunOptions {
        let mut run = RunOptions::of_job(
            &spec.options,
            spec.generator.clone(),
            spec.trajectory.clone(),
            out_dir,
            Accuracy::DEFAULT, // unused: the options spell the accuracy out
        );
        run.overwrite = overwrite;
        run.check_memory = spec.check_memory;
        run
    }

    /// This run's job as the shard manifests record it (the inputs hashed; no backend: each
    /// shard records its own).
    pub fn spec(&self) -> anyhow::Result<JobSpec> {
        let mut options = self.job_options(None);
        // Obstacles are read at the merge, maybe elsewhere: absolute, as the inputs.
        for a in options.against.iter_mut().chain(&mut options.package_dir) {
            *a = std::fs::canonicalize(&*a).map_err(|e| {
                InputError::new(a, format!("cannot open it: {e}"), "check the path")
            })?;
        }
        JobSpec::hashing(
            &self.generator,
            &self.trajectory,
            options,
            self.check_memory,
        )
    }
}
