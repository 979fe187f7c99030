//! SLURM's side of a cluster job: the two batch scripts (an array of shard sweeps, and the
//! merge that depends on them) and the calls to `sbatch`, `squeue` and `scancel`. SLURM does
//! the scheduling, retrying and dependency tracking; sweptvol only writes files SLURM runs.

use std::path::Path;
use std::process::Command;

use anyhow::{bail, Context};

use crate::io::shard_files::ShardId;

/// Marker files the scripts leave in the shard folder (read by `cluster status` and the watcher).
pub const MERGE_EXIT: &str = "merge.exit";
pub const FAILED_SUFFIX: &str = "failed";

/// Quote `s` for bash: single quotes, each `'` written as `'\''`.
pub fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

fn command_line(binary: &Path, args: &[String]) -> String {
    std::iter::once(quote(&binary.to_string_lossy()))
        .chain(args.iter().map(|a| quote(a)))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The array job: task I sweeps shard I/`count` (`sweep_args` hold everything but `--shard`:
/// `sweep --job FILE`).
/// A task that fails other than for its input (exit 2) asks SLURM to requeue it, at most
/// `retries` times; after the last try it leaves `shard-IIII-of-NNNN.failed` saying why. sbatch
/// gives the array, job name and log files on its command line ([`sbatch`]).
pub fn sweep_script(
    binary: &Path,
    sweep_args: &[String],
    shard_dir: &Path,
    count: u32,
    retries: u32,
) -> String {
    let dir = quote(&shard_dir.to_string_lossy());
    let pattern = ShardId { index: 1, count }
        .stem()
        .replacen("0001", "%04d", 1);
    format!(
        r#"#!/bin/bash
# Written by `sweptvol cluster submit`: array task I sweeps shard I of {count} of one job into
# the shard folder; a failed try (other than bad input, exit 2) is requeued {retries} times at most.
set -u
task="$SLURM_ARRAY_TASK_ID"
try=$((${{SLURM_RESTART_COUNT:-0}} + 1))
failed="$(printf '%s/{pattern}.{FAILED_SUFFIX}' {dir} "$task")"
rm -f "$failed"
# Threads as many as SLURM gave the task (--cpus-per-task), where it says.
[ -n "${{SLURM_CPUS_PER_TASK:-}}" ] && export RAYON_NUM_THREADS="$SLURM_CPUS_PER_TASK"
echo "sweptvol: shard $task/{count} on $(hostname), try $try of {tries}"
{command} --shard "$task/{count}"
rc=$?
if [ "$rc" -ne 0 ] && [ "$rc" -ne 2 ] && [ "$try" -le {retries} ]; then
    echo "sweptvol: shard $task/{count} failed (exit $rc): requeueing it" >&2
    scontrol requeue "${{SLURM_ARRAY_JOB_ID}}_$task" && sleep 600
fi
if [ "$rc" -ne 0 ]; then
    printf 'exit %s after %s tries on %s; log: %s/logs/sweep-%s.log\n' "$rc" "$try" "$(hostname)" \
        {dir} "$task" > "$failed.tmp" && mv "$failed.tmp" "$failed"
fi
exit "$rc"
"#,
        tries = retries + 1,
        command = command_line(binary, sweep_args),
    )
}

/// The merge job: `sweptvol mesh` over the shard folder, its exit code left in `merge.exit`.
pub fn merge_script(binary: &Path, mesh_args: &[String], shard_dir: &Path) -> String {
    let exit = quote(&shard_dir.join(MERGE_EXIT).to_string_lossy());
    format!(
        r#"#!/bin/bash
# Written by `sweptvol cluster submit`: merges the job's shards once every one has succeeded
# (sbatch gives --dependency=afterok on its command line) and writes the outputs.
set -u
{command}
rc=$?
echo "$rc" > {exit}.tmp && mv {exit}.tmp {exit}
exit "$rc"
"#,
        command = command_line(binary, mesh_args),
    )
}

/// `sbatch --parsable ARGS SCRIPT`: the job id it prints.
pub fn sbatch(args: &[String], script: &Path) -> anyhow::Result<String> {
    let out = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .arg(script)
        .output()
        .context(
            "could not run sbatch: is SLURM's client installed and on PATH on this machine?",
        )?;
    if !out.status.success() {
        bail!(
            "sbatch {} {} failed ({}): {}",
            args.join(" "),
            script.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    // `--parsable` prints "id" or "id;cluster".
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_digit()) {
        bail!("sbatch printed no job id: {text:?}");
    }
    Ok(id)
}

/// SLURM's state of each job or array task in `ids` that it still knows (`squeue`), as
/// (id, state, reason): `("12_3", "RUNNING", "None")`. Empty when it knows none of them.
pub fn queue_states(ids: &[String]) -> anyhow::Result<Vec<(String, String, String)>> {
    let out = Command::new("squeue")
        .args(["-h", "-o", "%i|%T|%r", "-j", &ids.join(",")])
        .output()
        .context("could not run squeue")?;
    if !out.status.success() {
        // squeue refuses ids it has forgotten (finished and purged): none is queued.
        return Ok(Vec::new());
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut f = l.split('|');
            Some((
                f.next()?.into(),
                f.next()?.into(),
                f.next().unwrap_or("").into(),
            ))
        })
        .collect())
}

/// `scancel` the jobs (finished shards stay on disk; a new submission skips them).
pub fn cancel(ids: &[String]) -> anyhow::Result<()> {
    let status = Command::new("scancel")
        .args(ids)
        .status()
        .context("could not run scancel")?;
    if !status.success() {
        bail!("scancel {} failed ({status})", ids.join(" "));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quoting_survives_bash() {
        for s in ["plain", "with space", "it's", "$HOME `x` \"q\"", "a'b'c"] {
            let out = Command::new("bash")
                .args(["-c", &format!("printf %s {}", quote(s))])
                .output()
                .unwrap();
            assert_eq!(String::from_utf8_lossy(&out.stdout), s);
        }
    }
}
