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

use std::collections::BTreeMap;
use std::fs;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::{build, output_paths, prepare, Prepared, RunOptions, Swept};
use crate::depth::{self, DepthImages};
use crate::error::InputError;
use crate::input::grid::{Accuracy, Grid};
use crate::io::atomic;
use crate::job::JobOptions;
use crate::sweep::backend::Backend;
use crate::sweep::Observer;
use crate::voxels::VoxelBits;

/// The manifest's `format`: what a reader checks first.
const FORMAT: &str = "sweptvol-shard";
/// Version of the manifest and data layout; a merge refuses any other (2: the job's options as
/// `JobOptions`).
const VERSION: u32 = 2;
/// First bytes of a shard's data file.
const MAGIC: &[u8; 8] = b"SVSHARD1";

/// Most shards one job may have: the manifests' names (`shard-IIII-of-NNNN`) sort by index
/// below 10,000, and `cluster submit --shards` takes the same range.
pub const MAX_SHARDS: u32 = 9999;

/// Shard `index` (1-based) of `count`: `--shard 3/8`, SLURM's `$SLURM_ARRAY_TASK_ID/8` with
/// `--array=1-8`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardId {
    pub index: u32,
    pub count: u32,
}

impl FromStr for ShardId {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: write I/N with 1 <= I <= N <= {MAX_SHARDS}, such as 3/8");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count) = (
            i.trim().parse::<u32>().map_err(|_| bad())?,
            n.trim().parse::<u32>().map_err(|_| bad())?,
        );
        if index == 0 || index > count || count > MAX_SHARDS {
            return Err(bad());
        }
        Ok(ShardId { index, count })
    }
}

impl ShardId {
    /// `shard-0003-of-0008`: sorts in index order for any count below 10,000.
    pub fn stem(&self) -> String {
        format!("shard-{:04}-of-{:04}", self.index, self.count)
    }
}

/// Everything of a `run` that a shard's images and the merged outputs depend on, as given:
/// the merge re-reads the inputs from these paths (a shared filesystem) and checks the hashes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobSpec {
    /// Absolute paths of the inputs, and FNV-1a 64 of their bytes (hex).
    pub generator: PathBuf,
    pub generator_hash: String,
    pub trajectory: PathBuf,
    pub trajectory_hash: String,
    /// The job's options, the typed value job.json and the command line share (the accuracy
    /// spelled out; no backend: each shard records its own).
    pub options: JobOptions,
    pub check_memory: bool,
}

impl JobSpec {
    /// The spec of `opts`, hashing its inputs (the paths made absolute).
    pub fn of(opts: &RunOptions) -> anyhow::Result<JobSpec> {
        let abs = |p: &Path| -> anyhow::Result<PathBuf> {
            fs::canonicalize(p).map_err(|e| {
                InputError::new(p, format!("cannot open it: {e}"), "check the path").into()
            })
        };
        let (generator, trajectory) = (abs(&opts.generator)?, abs(&opts.trajectory)?);
        Ok(JobSpec {
            generator_hash: hash_file(&generator)?,
            trajectory_hash: hash_file(&trajectory)?,
            generator,
            trajectory,
            options: opts.job_options(None),
            check_memory: opts.check_memory,
        })
    }

    /// The run these shards make up, writing to `out_dir`.
    pub fn run_options(&self, out_dir: PathBuf, overwrite: bool) -> RunOptions {
        let mut run = RunOptions::of_job(
            &self.options,
            self.generator.clone(),
            self.trajectory.clone(),
            out_dir,
            Accuracy::DEFAULT, // unused: the options spell the accuracy out
        );
        run.overwrite = overwrite;
        run.check_memory = self.check_memory;
        run
    }

    /// The options, as JSON, in which `other` differs: `accuracy {"resolution":40} where
    /// {ours} {"resolution":32}`.
    fn differences(&self, other: &JobSpec, ours: &str) -> String {
        let (a, b) = (json_fields(self), json_fields(other));
        let list: Vec<String> = a
            .iter()
            .filter(|(k, _)| !k.starts_with("generator") && !k.starts_with("trajectory"))
            .filter(|(k, v)| b.get(*k) != Some(v))
            .map(|(k, v)| {
                let w = b.get(k).map_or("nothing".into(), |w| w.to_string());
                format!("{k} {w} where {ours} {v}")
            })
            .collect();
        list.join(", ")
    }

    fn same_inputs(&self, other: &JobSpec) -> bool {
        (
            &self.generator,
            &self.generator_hash,
            &self.trajectory,
            &self.trajectory_hash,
        ) == (
            &other.generator,
            &other.generator_hash,
            &other.trajectory,
            &other.trajectory_hash,
        )
    }
}

/// The spec's fields as JSON, the options' own fields among them (`resolution`, not `options`).
fn json_fields(spec: &JobSpec) -> BTreeMap<String, serde_json::Value> {
    let mut out = BTreeMap::new();
    if let Ok(serde_json::Value::Object(m)) = serde_json::to_value(spec) {
        for (k, v) in m {
            match v {
                serde_json::Value::Object(options) if k == "options" => out.extend(options),
                v => {
                    out.insert(k, v);
                }
            }
        }
    }
    out
}

/// What a finished shard wrote: its job, which poses it swept, and its data file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub sweptvol_version: String,
    pub shard: ShardId,
    pub job: JobSpec,
    /// The whole job's grid, and the radius (f32 bits, grid units) and rounding term (grid
    /// units) every shard renders with: equal in every shard of one job.
    pub grid: Grid,
    pub radius_bits: u32,
    pub rounding: f64,
    /// Per part, the pose indices (rows and sub-poses) this shard swept: [start, end).
    pub windows: Vec<[u64; 2]>,
    pub poses: u64,
    pub posed_triangles: u64,
    /// Posed triangles of the whole job (all shards).
    pub job_posed_triangles: u64,
    /// Whether the data holds the reach (the job floods).
    pub reach: bool,
    /// The data file (beside the manifest), its length in bytes and FNV-1a 64 (hex).
    pub data: String,
    pub data_bytes: u64,
    pub data_hash: String,
    pub backend: String,
    pub sweep_seconds: f64,
}

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
    let spec = JobSpec::of(opts)?;
    let dir = &opts.out_dir;
    let manifest_path = dir.join(format!("{}.json", shard.stem()));
    if manifest_path.exists() {
        match read_manifest(&manifest_path).and_then(|m| check_data(&manifest_path, &m).map(|_| m))
        {
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
    let data = encode_data(&swept);
    fs::create_dir_all(dir)
        .with_context(|| format!("could not create the shard folder {}", dir.display()))?;
    let data_name = format!("{}.bin", shard.stem());
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
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
    // The data first, then the manifest: a manifest always names finished data.
    atomic::write_atomic(&dir.join(&data_name), &data)?;
    atomic::write_atomic(&manifest_path, &serde_json::to_vec_pretty(&manifest)?)?;
    Ok(ShardOutcome::Swept(Box::new(manifest)))
}

/// Every `shard-*.json` in `dirs`, in file-name order.
pub fn find_manifests(dirs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for dir in dirs {
        let entries = fs::read_dir(dir).map_err(|e| {
            InputError::new(
                dir,
                format!("cannot read the shard folder: {e}"),
                "give the --out folder of `sweptvol sweep --shard`",
            )
        })?;
        let mut here: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("shard-") && n.ends_with(".json"))
            })
            .collect();
        here.sort();
        out.extend(here);
    }
    Ok(out)
}

/// Read and check one manifest (format and version; not its data).
pub fn read_manifest(path: &Path) -> anyhow::Result<Manifest> {
    let bytes = fs::read(path).map_err(|e| {
        InputError::new(
            path,
            format!("cannot read it: {e}"),
            "check the shard folder",
        )
    })?;
    let m: Manifest = serde_json::from_slice(&bytes).map_err(|e| {
        InputError::new(
            path,
            format!("not a sweptvol shard manifest: {e}"),
            "remove it, or sweep the shard again (`sweptvol sweep --shard I/N`)",
        )
    })?;
    if m.format != FORMAT || m.version != VERSION {
        return Err(InputError::new(
            path,
            format!(
                "a shard in format {:?} version {} (sweptvol {}); this sweptvol reads {FORMAT:?} version {VERSION}",
                m.format, m.version, m.sweptvol_version
            ),
            "sweep the shards again with this sweptvol",
        )
        .into());
    }
    Ok(m)
}

/// The data file of `manifest` (at `manifest_path`), checked against its length and hash.
fn check_data(manifest_path: &Path, m: &Manifest) -> anyhow::Result<Vec<u8>> {
    let path = manifest_path.with_file_name(&m.data);
    let again = format!(
        "sweep it again: `sweptvol sweep --shard {}/{} --overwrite ...` with the job's options",
        m.shard.index, m.shard.count
    );
    let bytes = fs::read(&path).map_err(|e| {
        InputError::new(&path, format!("cannot read the shard's data: {e}"), &again)
    })?;
    if bytes.len() as u64 != m.data_bytes {
        return Err(InputError::new(
            &path,
            format!(
                "truncated or overwritten: {} bytes where the manifest says {}",
                bytes.len(),
                m.data_bytes
            ),
            again,
        )
        .into());
    }
    if fnv1a64_hex(&bytes) != m.data_hash {
        return Err(InputError::new(
            &path,
            "its content does not match the manifest's hash",
            again,
        )
        .into());
    }
    Ok(bytes)
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
    let mut opts = first.job.run_options(out_dir, overwrite);
    if name.is_some() {
        opts.job.name = name;
    }
    // The inputs must be those the shards swept.
    let now = JobSpec::of(&opts)?;
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
            return Err(InputError::new(
                path,
                "changed since the shards were swept (its hash differs)",
                "sweep the shards again, or restore the file",
            )
            .into());
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
        let data = check_data(path, m)?;
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
        check_data(path, m).map_err(|e| match e.downcast::<InputError>() {
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

/// The data file: [`MAGIC`], then per axis the encoded (D⁻, D⁺) pairs in pixel order as u32
/// LE, then, where the job floods, the reach's words (u64 LE) run-length coded: a u64 header
/// `kind << 62 | length` with kind 0 (length zero words), 1 (length all-ones words) or 2
/// (length literal words following).
fn encode_data(swept: &Swept) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    for img in &swept.images.images {
        out.reserve(8 * img.min.len());
        for (lo, hi) in img.min.iter().zip(&img.max) {
            out.extend_from_slice(&depth::encode(*lo).to_le_bytes());
            out.extend_from_slice(&depth::encode(*hi).to_le_bytes());
        }
    }
    if let Some(reach) = &swept.reach {
        let words = reach.words_raw();
        let mut i = 0;
        while i < words.len() {
            let w = words[i];
            let run =
                |pred: &dyn Fn(u64) -> bool| words[i..].iter().take_while(|&&x| pred(x)).count();
            let (kind, len) = if w == 0 {
                (0u64, run(&|x| x == 0))
            } else if w == u64::MAX {
                (1, run(&|x| x == u64::MAX))
            } else {
                (2, run(&|x| x != 0 && x != u64::MAX))
            };
            out.extend_from_slice(&(kind << 62 | len as u64).to_le_bytes());
            if kind == 2 {
                for x in &words[i..i + len] {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
            i += len;
        }
    }
    out
}

/// Merge one shard's data into the encoded buffers (min of D⁻, max of D⁺) and the reach (OR).
/// Every pixel must be empty (both sentinels) or hold finite depths D⁻ <= D⁺ within its axis's
/// `limits` (grid units), as a sweep writes them: a corrupt value would reach the classifier.
fn decode_into(
    data: &[u8],
    encoded: &mut [Vec<u32>; 3],
    reach: Option<&mut VoxelBits>,
    limits: [(f32, f32); 3],
) -> Result<(), String> {
    let rest = data
        .strip_prefix(MAGIC.as_slice())
        .ok_or("not a sweptvol shard data file (bad magic)")?;
    let depth_bytes: usize = encoded.iter().map(|e| 4 * e.len()).sum();
    if rest.len() < depth_bytes {
        return Err(format!(
            "{} bytes of depth images where the grid needs {depth_bytes}",
            rest.len()
        ));
    }
    let (images, mut tail) = rest.split_at(depth_bytes);
    let mut values = images
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")));
    for (axis, enc) in encoded.iter_mut().enumerate() {
        let (least, most) = limits[axis];
        for (pixel, pair) in enc.chunks_exact_mut(2).enumerate() {
            let (lo, hi) = (
                values.next().unwrap_or(u32::MAX),
                values.next().unwrap_or(0),
            );
            if (lo, hi) != (crate::depth::EMPTY_MIN, crate::depth::EMPTY_MAX) {
                let (a, b) = (crate::depth::decode(lo), crate::depth::decode(hi));
                let fits = |x: f32| x.is_finite() && x >= least && x <= most;
                if !(fits(a) && fits(b) && a <= b) {
                    return Err(format!(
                        "pixel {pixel} of the {} image holds depths ({a}, {b}), outside the grid's {least}..{most} (grid units) or out of order",
                        crate::depth::AXIS_NAMES[axis]
                    ));
                }
            }
            pair[0] = pair[0].min(lo);
            pair[1] = pair[1].max(hi);
        }
    }
    let Some(reach) = reach else {
        return if tail.is_empty() {
            Ok(())
        } else {
            Err("data after the depth images".into())
        };
    };
    let words = reach.words_raw_mut();
    let mut i = 0;
    let next = |tail: &mut &[u8]| -> Option<u64> {
        let (head, rest) = tail.split_first_chunk::<8>()?;
        *tail = rest;
        Some(u64::from_le_bytes(*head))
    };
    while !tail.is_empty() {
        let header = next(&mut tail).ok_or("a cut reach header")?;
        let (kind, len) = (header >> 62, (header & ((1 << 62) - 1)) as usize);
        if len > words.len() - i {
            return Err("the reach runs past the grid".into());
        }
        match kind {
            0 => {}
            1 => words[i..i + len].iter_mut().for_each(|w| *w = u64::MAX),
            2 => {
                for w in &mut words[i..i + len] {
                    *w |= next(&mut tail).ok_or("cut reach words")?;
                }
            }
            _ => return Err("a bad reach header".into()),
        }
        i += len;
    }
    if i != words.len() {
        return Err(format!(
            "the reach covers {i} of the grid's {} words",
            words.len()
        ));
    }
    Ok(())
}

/// FNV-1a 64 of a file's bytes, as 16 hex digits.
pub fn hash_file(path: &Path) -> anyhow::Result<String> {
    let bytes = fs::read(path)
        .map_err(|e| InputError::new(path, format!("cannot read it: {e}"), "check the path"))?;
    Ok(fnv1a64_hex(&bytes))
}

/// FNV-1a 64: detects a changed or damaged file (not an adversary).
pub fn fnv1a64_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_ids_parse_and_refuse() {
        assert_eq!("3/8".parse::<ShardId>(), Ok(ShardId { index: 3, count: 8 }));
        for bad in ["0/4", "5/4", "3", "a/b", "-1/4", "1/0"] {
            assert!(bad.parse::<ShardId>().is_err(), "{bad}");
        }
        assert_eq!(
            ShardId {
                index: 3,
                count: 12
            }
            .stem(),
            "shard-0003-of-0012"
        );
    }

    /// The reach's run-length code gives back the words it was given, merged by OR.
    /// Issue 30, defect 6: depths that no sweep writes (NaN, -1e30, infinite, beyond the grid,
    /// D⁻ > D⁺) are refused at merge, naming the pixel; a sweep's own depths pass.
    #[test]
    fn corrupt_depths_are_refused_at_merge() {
        let grid = Grid {
            origin: [0.0; 3],
            h: 1.0,
            dims: [6, 5, 4],
        };
        let limits = [0, 1, 2].map(|a| (-3.0, grid.dims[a] as f32 + 3.0));
        let with = |lo: f32, hi: f32| {
            let mut images = DepthImages::empty(grid);
            images.images[1].min[3] = lo;
            images.images[1].max[3] = hi;
            let swept = Swept {
                images,
                reach: None,
                backend: String::new(),
                seconds: 0.0,
            };
            let data = encode_data(&swept);
            let mut encoded = [0, 1, 2].map(|a| {
                let (w, h) = depth::image_size(&grid, a);
                (0..w * h)
                    .flat_map(|_| [crate::depth::EMPTY_MIN, crate::depth::EMPTY_MAX])
                    .collect::<Vec<u32>>()
            });
            decode_into(&data, &mut encoded, None, limits)
        };
        assert!(with(1.0, 2.5).is_ok());
        for (lo, hi) in [
            (f32::NAN, 2.0),
            (1.0, f32::NAN),
            (-1e30, 2.0),
            (1.0, f32::INFINITY),
            (1.0, 9.5),
            (3.0, 2.0),
        ] {
            let e = with(lo, hi).expect_err("corrupt depths merged");
            assert!(e.contains("pixel 3 of the y image"), "{e}");
        }
    }

    #[test]
    fn reach_round_trips() {
        let mut rng = fastrand::Rng::with_seed(7);
        let dims = [130usize, 7, 5];
        let mut cuts = 0;
        for case in 0..50 {
            let mut bits = VoxelBits::new(dims);
            for w in bits.words_raw_mut() {
                *w = match rng.u8(0..4) {
                    0 => 0,
                    1 => u64::MAX,
                    _ if case % 5 == 0 => 0,
                    _ => rng.u64(..),
                };
            }
            let grid = Grid {
                origin: [0.0; 3],
                h: 1.0,
                dims: [130, 7, 5],
            };
            let swept = Swept {
                images: DepthImages::empty(grid),
                reach: Some(bits.clone()),
                backend: String::new(),
                seconds: 0.0,
            };
            let data = encode_data(&swept);
            let mut encoded = [0, 1, 2].map(|a| {
                let (w, h) = depth::image_size(&grid, a);
                vec![0u32; 2 * (w * h) as usize]
            });
            let mut into = VoxelBits::new(dims);
            let wide = [(-1e6, 1e6); 3];
            decode_into(&data, &mut encoded, Some(&mut into), wide).unwrap();
            assert_eq!(into.words_raw(), bits.words_raw());
            // Cut anywhere in the reach: an error, never a silent partial merge.
            let depth_end = MAGIC.len() + encoded.iter().map(|e| 4 * e.len()).sum::<usize>();
            for cut in [depth_end + 1, data.len() - 1, data.len() - 8] {
                if cut > depth_end && cut < data.len() {
                    let mut into = VoxelBits::new(dims);
                    let cut = &data[..cut];
                    assert!(decode_into(cut, &mut encoded, Some(&mut into), wide).is_err());
                    cuts += 1;
                }
            }
        }
        assert!(cuts > 50, "only {cuts} cut data files were tried");
    }
}
