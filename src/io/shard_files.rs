//! The shard files: what one shard of a job writes and the merge reads. A shard writes
//! `shard-IIII-of-NNNN.bin`, the data ([`encode_data`]), and then `shard-IIII-of-NNNN.json`,
//! its [`Manifest`] (the job, the inputs' hashes, the grid, which poses, the data's length and
//! hash): a manifest exists only for a finished shard. The sweep and the merge that use them
//! are `pipeline::shard`'s.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::depth::{self, DepthImages};
use crate::error::InputError;
use crate::input::grid::Grid;
use crate::io::atomic;
use crate::job::JobOptions;
use crate::voxels::VoxelBits;

/// The manifest's `format`: what a reader checks first.
pub const FORMAT: &str = "sweptvol-shard";
/// Version of the manifest and data layout; a merge refuses any other (2: the job's options as
/// `JobOptions`).
pub const VERSION: u32 = 2;
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
    /// The spec of a job on `generator` and `trajectory` (made absolute and hashed).
    pub fn hashing(
        generator: &Path,
        trajectory: &Path,
        options: JobOptions,
        check_memory: bool,
    ) -> anyhow::Result<JobSpec> {
        let abs = |p: &Path| -> anyhow::Result<PathBuf> {
            fs::canonicalize(p).map_err(|e| {
                InputError::new(p, format!("cannot open it: {e}"), "check the path").into()
            })
        };
        let (generator, trajectory) = (abs(generator)?, abs(trajectory)?);
        Ok(JobSpec {
            generator_hash: hash_generator(&generator, &options.package_dir)?,
            trajectory_hash: hash_file(&trajectory)?,
            generator,
            trajectory,
            options,
            check_memory,
        })
    }

    /// The options, as JSON, in which `other` differs: `accuracy {"resolution":40} where
    /// {ours} {"resolution":32}`.
    pub fn differences(&self, other: &JobSpec, ours: &str) -> String {
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

    pub fn same_inputs(&self, other: &JobSpec) -> bool {
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

/// Write a finished shard into `dir`: the data first, then the manifest, so that a manifest
/// always names finished data. Returns the manifest's path.
pub fn write(dir: &Path, manifest: &Manifest, data: &[u8]) -> anyhow::Result<PathBuf> {
    fs::create_dir_all(dir).map_err(|e| {
        InputError::new(
            dir,
            format!("could not create the shard folder: {e}"),
            "check that the folder can be made",
        )
    })?;
    atomic::write_atomic(&dir.join(&manifest.data), data)?;
    let path = dir.join(format!("{}.json", manifest.shard.stem()));
    atomic::write_atomic(&path, &serde_json::to_vec_pretty(manifest)?)?;
    Ok(path)
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
pub fn read_data(manifest_path: &Path, m: &Manifest) -> anyhow::Result<Vec<u8>> {
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

/// The data file: `MAGIC` (`SVSHARD1`), then per axis the encoded (D⁻, D⁺) pairs in pixel order as u32
/// LE, then, where the job floods, the reach's words (u64 LE) run-length coded: a u64 header
/// `kind << 62 | length` with kind 0 (length zero words), 1 (length all-ones words) or 2
/// (length literal words following).
pub fn encode_data(images: &DepthImages, reach: Option<&VoxelBits>) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    for img in &images.images {
        out.reserve(8 * img.min.len());
        for (lo, hi) in img.min.iter().zip(&img.max) {
            out.extend_from_slice(&depth::encode(*lo).to_le_bytes());
            out.extend_from_slice(&depth::encode(*hi).to_le_bytes());
        }
    }
    if let Some(reach) = reach {
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
pub fn decode_into(
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

/// [`hash_file`] of a generator; for a robot description, FNV-1a 64 of the URDF's bytes and
/// then, per mesh file it names (in the order read, `package_dirs` resolving
/// `package://` paths), a zero byte, the file's path, a zero byte and its bytes: a mesh changed
/// between the shards or before the merge changes the hash as the URDF's own edits do.
pub fn hash_generator(path: &Path, package_dirs: &[PathBuf]) -> anyhow::Result<String> {
    if !crate::io::urdf::is_robot(path) {
        return hash_file(path);
    }
    let robot = crate::io::urdf::read_robot(path, package_dirs)?;
    let read = |p: &Path| {
        fs::read(p)
            .map_err(|e| InputError::new(p, format!("cannot read it: {e}"), "check the path"))
    };
    let mut bytes = read(path)?;
    for file in &robot.files {
        bytes.push(0);
        bytes.extend_from_slice(file.as_os_str().as_encoded_bytes());
        bytes.push(0);
        bytes.extend(read(file)?);
    }
    Ok(fnv1a64_hex(&bytes))
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
            let data = encode_data(&images, None);
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
            let data = encode_data(&DepthImages::empty(grid), Some(&bits));
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
