//! The `sweptvol` command: a thin shell over the library. Flags become validated options,
//! errors print once with their chain, and the exit code says what kind of failure it was.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use std::io::Write;

use indicatif::{ProgressBar, ProgressStyle};

use sweptvol::cluster;
use sweptvol::error::{self, OptionError, OptionKey};
use sweptvol::input::grid::Accuracy;
use sweptvol::input::motion::Motion;
use sweptvol::io::shard_files::{ShardId, MAX_SHARDS};
use sweptvol::job::{file_stem, JobOptions};
use sweptvol::pipeline::shard;
use sweptvol::pipeline::{self, RunOptions};
use sweptvol::sweep::backend::{Backend, BackendChoice};
use sweptvol::sweep::Observer;
use sweptvol::verify::BoundScope;
use sweptvol::watch::{self, WatchOptions};

#[derive(Parser)]
#[command(
    name = "sweptvol",
    version,
    about = "Conservative swept volumes of triangle meshes"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Sweep a glTF generator along a trajectory CSV and write the six depth images and a report.
    Run(RunArgs),
    /// Sweep one shard of a job (its share of the poses, by posed triangles) into partial depth
    /// images in --out: `run`'s options plus --shard I/N. For a cluster: see `cluster submit`.
    Sweep(SweepArgs),
    /// Merge a job's shards (every shard-*.json of one job in the --from folders, checked
    /// complete and alike) and write what `run` writes: the same bytes.
    Mesh(MeshArgs),
    /// Run a job on a SLURM cluster: `submit` queues its shards and the merge, `status` says
    /// where it stands. Needs a filesystem every node shares and this binary on every node.
    #[command(subcommand)]
    Cluster(ClusterCommand),
    /// Watch a folder for jobs (job folders and dropped .glb + .csv pairs) and run them; see
    /// docs/exchange-protocol.md.
    Watch(WatchArgs),
    /// Check any swept-volume mesh against the generator and trajectory, trusting nothing of the
    /// sweep: containment, deviation, mesh health. Exit 0 pass, 3 certificate failed, 2 bad input.
    Verify(VerifyArgs),
    /// Measure how far a swept volume stays from obstacles: for each obstacle a guaranteed
    /// interval for the true clearance, a verdict (clear, possible contact, contact) and a
    /// clearance map NAME.OBSTACLE.clearance.glb; NAME.clearance.json holds it all. Exit 0,
    /// 3 when --require-clearance is not kept, 2 bad input.
    Clearance(ClearanceArgs),
    /// Print the watched-folder protocol's names (inputs, outputs, job.json keys, states) as
    /// JSON, for clients in other languages such as the Blender add-on.
    Protocol,
}

/// The command line's spelling of the library's choices (the library knows no clap).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum BoundScopeArg {
    /// At every mesh point.
    Everywhere,
    /// At every mesh point that sees out of the swept volume along some axis (the scope of
    /// `run`'s hausdorff_bound: points in pockets hidden from all six axes are accepted).
    AxisVisible,
}

impl From<BoundScopeArg> for BoundScope {
    fn from(b: BoundScopeArg) -> Self {
        match b {
            BoundScopeArg::Everywhere => BoundScope::Everywhere,
            BoundScopeArg::AxisVisible => BoundScope::AxisVisible,
        }
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum ExecutorArg {
    Local,
    Slurm,
}

#[derive(Args)]
struct WatchArgs {
    /// The watched folder (must exist). Nothing outside it is read or written.
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// Process what is waiting, then exit (for cron and CI).
    #[arg(long)]
    once: bool,
    /// Seconds a dropped .glb + .csv pair must stay unchanged before it is taken.
    #[arg(
        long,
        value_name = "SECS",
        default_value_t = 2.0,
        allow_negative_numbers = true
    )]
    settle: f64,
    /// Seconds between full rescans of the folder (a safety net for lost events).
    #[arg(
        long,
        value_name = "SECS",
        default_value_t = 10.0,
        allow_negative_numbers = true
    )]
    rescan: f64,
    /// Jobs run at once (CPU backend only; a GPU runs one job at a time).
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = at_least_one)]
    jobs: usize,
    /// Where sweeps run; the GPU device is acquired once and reused by every job.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    backend: BackendChoice,
    /// Voxels along the longest edge, for jobs whose job.json names neither resolution nor
    /// tolerance, and for drops [default: 256].
    #[arg(long, value_name = "N", conflicts_with = "tolerance")]
    resolution: Option<u32>,
    /// Default stated bound in world units, as `run --tolerance` (instead of --resolution).
    #[arg(long, value_name = "T", allow_negative_numbers = true)]
    tolerance: Option<f64>,
    /// Where jobs run: `local`, here; `slurm`, each job as `cluster submit --shards N` queues it
    /// (the watched folder must be on a filesystem every node shares).
    #[arg(long, value_enum, default_value = "local")]
    executor: ExecutorArg,
    /// With --executor slurm: shards per job.
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=MAX_SHARDS as i64))]
    shards: u32,
    /// With --executor slurm: an sbatch option for every job, as one argument; repeatable.
    #[arg(long, value_name = "OPTION", allow_hyphen_values = true)]
    sbatch: Vec<String>,
    /// With --executor slurm: the sweptvol the nodes run [default: this one].
    #[arg(long, value_name = "FILE")]
    binary: Option<PathBuf>,
    /// With --executor slurm: requeues of a failed shard.
    #[arg(long, value_name = "N", default_value_t = 2)]
    retries: u32,
    /// Inputs of one job larger than this in all are refused before they are parsed.
    #[arg(long, value_name = "BYTES", default_value_t = 2 << 30)]
    max_input_bytes: u64,
    /// Only warnings and errors in the log.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct VerifyArgs {
    /// The generator mesh (or --robot URDF), as given to `run`.
    #[arg(long, visible_alias = "robot", value_name = "FILE")]
    generator: PathBuf,
    /// The poses (or --joints CSV), as given to `run`.
    #[arg(long, visible_alias = "joints", value_name = "FILE")]
    trajectory: PathBuf,
    /// The run's --package-dir folders (for a robot's meshes).
    #[arg(long, value_name = "DIR")]
    package_dir: Vec<PathBuf>,
    /// The mesh to check: any glTF 2.0 file (all triangle primitives, node transforms applied).
    #[arg(long, value_name = "FILE")]
    mesh: PathBuf,
    /// Fail unless the deviation (one-sided Hausdorff distance from the mesh to the swept
    /// volume, upper bound) is at most B world units.
    #[arg(long, value_name = "B", allow_negative_numbers = true)]
    bound: Option<f64>,
    /// Where --bound must hold: everywhere, or axis-visible (mesh points whose six axis rays
    /// all come within B of the swept volume lie in filled pockets and are accepted: the scope
    /// of `run`'s hausdorff_bound).
    #[arg(long, value_enum, default_value_t = BoundScopeArg::Everywhere)]
    bound_scope: BoundScopeArg,
    /// Covering radius of the samples, world units [default: mesh diagonal / 2000]; posed
    /// pieces inside but nearer the mesh than that are split on down to 1/256 of it.
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    spacing: Option<f64>,
    /// Search on after the first posed triangle proven outside the mesh and count every
    /// failure (default: stop there, since the certificate has failed).
    #[arg(long)]
    all_failures: bool,
    /// What to certify between rows: `screw`, every instant of the screw motion from each row
    /// to the next (verify's own interpolation and bound); or `discrete`, the listed poses.
    #[arg(long, value_enum, default_value = "screw")]
    motion: Motion,
    /// The run's --relative-to: the mesh is in this node's frame and the other parts move
    /// relative to it.
    #[arg(long, value_name = "NODE")]
    relative_to: Option<String>,
    /// The run's --rows: `local` reads each row as its node's transform relative to its parent.
    #[arg(long, value_enum, default_value_t)]
    rows: sweptvol::input::model::Rows,
    /// Print the report as JSON on stdout (no progress bar).
    #[arg(long)]
    json: bool,
    /// No progress bar and only warnings and errors in the log.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct ClearanceArgs {
    /// The swept-volume mesh (NAME.swept.glb of `run`).
    #[arg(long, value_name = "FILE")]
    mesh: PathBuf,
    /// Its report (NAME.report.json): the clearance and bound the mesh keeps, and the inputs
    /// whose listed poses can prove a contact.
    #[arg(long, value_name = "FILE")]
    report: PathBuf,
    /// An obstacle file (glTF 2.0): every node with triangles is an obstacle, named after the
    /// node. Repeatable.
    #[arg(long, value_name = "FILE", required = true)]
    against: Vec<PathBuf>,
    /// Exit 3 when an obstacle's guaranteed clearance (the interval's lower end) is below X
    /// world units, or a contact is certain.
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    require_clearance: Option<f64>,
    /// The clearance, world units, at which the map's colours reach green (red is contact)
    /// [default: 10 times the mesh's bound].
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    clearance_scale: Option<f64>,
    /// Where to write NAME.clearance.json and the maps [default: the mesh's folder].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Replace the outputs of an earlier check.
    #[arg(long)]
    overwrite: bool,
    /// Print NAME.clearance.json on stdout instead of the summary.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct RunArgs {
    /// The job as a file instead of the inputs, options and folder below: its inputs, options
    /// and output folder, as `cluster submit` writes it (job.json in the shard folder).
    #[arg(long = "job", value_name = "FILE", conflicts_with_all = ["JobOptions", "bare_names"])]
    job_file: Option<PathBuf>,
    /// The generator mesh: glTF 2.0 (.glb, or .gltf with its buffers beside it); or, as
    /// --robot, a URDF robot description (its rows are then joint values, --joints).
    #[arg(
        long,
        visible_alias = "robot",
        value_name = "FILE",
        required_unless_present = "job_file",
        conflicts_with = "job_file"
    )]
    generator: Option<PathBuf>,
    /// The poses: CSV with m00..m33 or tx,ty,tz,qw,qx,qy,qz columns (see the README); or, as
    /// --joints, a robot's joint CSV: a header time,<joint names>, radians or metres.
    #[arg(
        long,
        visible_alias = "joints",
        value_name = "FILE",
        required_unless_present = "job_file",
        conflicts_with = "job_file"
    )]
    trajectory: Option<PathBuf>,
    /// Output folder (created if missing).
    #[arg(
        long,
        value_name = "DIR",
        required_unless_present = "job_file",
        conflicts_with = "job_file"
    )]
    out: Option<PathBuf>,
    #[command(flatten)]
    job: JobOptions,
    /// Bare output names (swept.glb, report.json), as in a watched job folder: how a watched
    /// job's shards are swept on a cluster.
    #[arg(long, hide = true, conflicts_with = "name")]
    bare_names: bool,
    /// Run even when the memory estimate (from the grid size, made for parts that fill their
    /// box) exceeds what is available; for thin or sparse parts it can be far too high.
    #[arg(long)]
    no_memory_check: bool,
    /// Replace existing outputs.
    #[arg(long)]
    overwrite: bool,
    /// No progress bar and only warnings and errors in the log.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct SweepArgs {
    /// Which shard: I/N, 1 <= I <= N (SLURM: $SLURM_ARRAY_TASK_ID/N with --array=1-N).
    #[arg(long, value_name = "I/N")]
    shard: ShardId,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Subcommand)]
enum ClusterCommand {
    /// Write and submit a SLURM array job of N shard sweeps and a merge that runs once all
    /// succeeded (--dependency=afterok); prints the job ids. Shards already finished for the
    /// same job are not submitted again.
    Submit(Box<SubmitArgs>),
    /// Where a submitted job stands: shards done, missing and failed (from the manifests), the
    /// jobs as SLURM sees them, and the merge.
    Status(StatusArgs),
}

#[derive(Args)]
struct SubmitArgs {
    /// Shards to split the job into (array tasks 1..N).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=MAX_SHARDS as i64))]
    shards: u32,
    /// Where the shards, scripts and logs go [default: OUT/NAME.shards].
    #[arg(long, value_name = "DIR")]
    shard_dir: Option<PathBuf>,
    /// The sweptvol the nodes run [default: this one]; it must be the same path on every node.
    #[arg(long, value_name = "FILE")]
    binary: Option<PathBuf>,
    /// An sbatch option for both jobs, as one argument (--sbatch=--partition=long); repeatable.
    #[arg(long, value_name = "OPTION", allow_hyphen_values = true)]
    sbatch: Vec<String>,
    /// An sbatch option for the shard array only (--sweep-sbatch=--gres=gpu:1).
    #[arg(long, value_name = "OPTION", allow_hyphen_values = true)]
    sweep_sbatch: Vec<String>,
    /// An sbatch option for the merge only (--merge-sbatch=--mem=64G).
    #[arg(long, value_name = "OPTION", allow_hyphen_values = true)]
    merge_sbatch: Vec<String>,
    /// Times SLURM requeues a failed shard before it counts as failed (bad input, exit 2, is
    /// never retried).
    #[arg(long, value_name = "N", default_value_t = 2)]
    retries: u32,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Args)]
struct StatusArgs {
    /// The job's shard folder (`cluster submit --shard-dir`, by default OUT/NAME.shards).
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// Print the status as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct MeshArgs {
    /// Folders holding the job's shards (`sweep --out`); one job's shards may be spread over several.
    #[arg(long, value_name = "DIR", num_args = 1.., required = true)]
    from: Vec<PathBuf>,
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Output file stem [default: the job's --name, else the trajectory's file stem].
    #[arg(long, value_parser = file_stem)]
    name: Option<String>,
    /// Replace existing outputs.
    #[arg(long)]
    overwrite: bool,
    /// No progress bar and only warnings and errors in the log.
    #[arg(long, short)]
    quiet: bool,
}

/// Shows poses done on a terminal progress bar.
struct Bar {
    bar: ProgressBar,
    poses: AtomicU64,
}

impl Observer for Bar {
    fn begin(&self, poses: u64, _posed_triangles: u64) {
        self.poses.store(poses, Ordering::Relaxed);
        self.bar.set_length(poses);
    }
    fn progress(&self, done: u64, total: u64) {
        let poses = self.poses.load(Ordering::Relaxed) as f64;
        self.bar
            .set_position((done as f64 / total.max(1) as f64 * poses).round() as u64);
    }
}

/// The run the arguments ask for (from the job file with --job), and its backend.
fn run_options(args: &RunArgs) -> anyhow::Result<(RunOptions, Option<BackendChoice>)> {
    let (mut run, backend) = match (&args.job_file, &args.generator, &args.trajectory, &args.out) {
        (Some(file), ..) => {
            let job = read_job_file(file)?;
            (RunOptions::of_job_file(&job), job.options.backend)
        }
        (None, Some(g), Some(t), Some(out)) => {
            let run = RunOptions::of_job(
                &args.job,
                g.clone(),
                t.clone(),
                out.clone(),
                Accuracy::DEFAULT,
            );
            (run, args.job.backend)
        }
        _ => unreachable!("clap requires --generator, --trajectory and --out without --job"),
    };
    if args.bare_names {
        run.job.name = Some(String::new());
    }
    run.overwrite = args.overwrite;
    run.check_memory &= !args.no_memory_check;
    Ok((run, backend))
}

/// The backend asked for; a fallback to the CPU is logged unless `quiet` (a successful quiet
/// run prints nothing).
fn acquire_backend(choice: Option<BackendChoice>, quiet: bool) -> anyhow::Result<Backend> {
    let choice = choice.unwrap_or(BackendChoice::Auto);
    let backend = Backend::acquire(choice)?;
    if let Backend::Cpu { reason } = &backend {
        if choice == BackendChoice::Auto && !quiet {
            tracing::warn!("{reason}");
        }
    }
    Ok(backend)
}

fn progress_bar(quiet: bool) -> Bar {
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0).with_style(
            ProgressStyle::with_template(
                "sweeping {bar:40} {pos}/{len} poses, {elapsed} elapsed, ETA {eta}",
            )
            .expect("progress template"),
        )
    };
    Bar {
        bar,
        poses: AtomicU64::new(0),
    }
}

fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    let (opts, backend) = run_options(&args)?;
    // Inputs first: a bad file is reported before any GPU start-up.
    let job = pipeline::prepare(&opts)?;
    let backend = acquire_backend(backend, args.quiet)?;
    let observer = progress_bar(args.quiet);
    let report = pipeline::execute(&job, &backend, &observer)?;
    observer.bar.finish_and_clear();
    log_done(&report, &opts.out_dir);
    Ok(report.clearance.as_ref().map_or(ExitCode::SUCCESS, |c| {
        if !args.quiet {
            let _ = say_clearance(c);
        }
        clearance_exit(c)
    }))
}

fn log_done(report: &pipeline::Report, out: &std::path::Path) {
    let t = &report.timings;
    tracing::info!(
        "done: {} posed triangles in {:.2} s ({:.3e}/s) on {}; wrote {} files to {}",
        report.counts.posed_triangles,
        t.sweep,
        t.posed_triangles_per_second,
        report.backend,
        report.outputs.len(),
        out.display()
    );
}

fn sweep_shard(args: SweepArgs) -> anyhow::Result<()> {
    let (opts, backend) = run_options(&args.run)?;
    let backend = acquire_backend(backend, args.run.quiet)?;
    let observer = progress_bar(args.run.quiet);
    match shard::sweep_shard(&opts, args.shard, &backend, &observer)? {
        shard::ShardOutcome::Swept(m) => {
            observer.bar.finish_and_clear();
            tracing::info!(
                "shard {}/{}: {} poses, {} posed triangles in {:.2} s on {}; wrote {} and its manifest to {}",
                m.shard.index,
                m.shard.count,
                m.poses,
                m.posed_triangles,
                m.sweep_seconds,
                m.backend,
                m.data,
                opts.out_dir.display()
            );
        }
        shard::ShardOutcome::AlreadyDone(path) => tracing::info!(
            "{} is a finished shard of this job (same inputs and options): kept, nothing swept",
            path.display()
        ),
    }
    Ok(())
}

/// A job file (`cluster submit` writes them), refused by name when it is not one.
fn read_job_file(path: &std::path::Path) -> anyhow::Result<sweptvol::job::JobFile> {
    let bytes = std::fs::read(path).map_err(|e| {
        error::InputError::new(path, format!("cannot read it: {e}"), "check the path")
    })?;
    serde_json::from_slice(&bytes).map_err(|e| {
        error::InputError::new(
            path,
            format!("not a sweptvol job file: {e}"),
            "give the job.json that `sweptvol cluster submit` wrote in the shard folder",
        )
        .at_line(e.line() as u64)
        .into()
    })
}

fn mesh(args: MeshArgs) -> anyhow::Result<ExitCode> {
    let (job, swept) = shard::merge(&args.from, args.out.clone(), args.name, args.overwrite)?;
    let report = pipeline::finish(&job, swept, &sweptvol::sweep::Silent)?;
    log_done(&report, &args.out);
    Ok(report.clearance.as_ref().map_or(ExitCode::SUCCESS, |c| {
        let _ = say_clearance(c);
        clearance_exit(c)
    }))
}

fn cluster(command: ClusterCommand) -> anyhow::Result<()> {
    match command {
        ClusterCommand::Submit(args) => {
            let args = *args;
            let (run, backend) = run_options(&args.run)?;
            let shard_dir = match args.shard_dir {
                Some(d) => d,
                None => cluster::default_shard_dir(&run)?,
            };
            let binary = match args.binary {
                Some(b) => b,
                None => std::env::current_exe()?,
            };
            let s = cluster::submit(&cluster::SubmitOptions {
                run,
                shards: args.shards,
                shard_dir: shard_dir.clone(),
                binary,
                sbatch: args.sbatch,
                sweep_sbatch: args.sweep_sbatch,
                merge_sbatch: args.merge_sbatch,
                retries: args.retries,
                backend: backend.unwrap_or(BackendChoice::Auto),
            })?;
            match &s.sweep_job {
                Some(id) => say(format_args!(
                    "submitted shards {} of {} as array job {id}, and the merge as job {} (runs after all succeed)\n",
                    cluster::list(&s.swept),
                    s.shards,
                    s.merge_job
                ))?,
                None => say(format_args!(
                    "every shard is finished; submitted the merge as job {}\n",
                    s.merge_job
                ))?,
            }
            say(format_args!(
                "progress: sweptvol cluster status {}\noutputs:  {}\n",
                shard_dir.display(),
                s.out_dir.display()
            ))?;
            Ok(())
        }
        ClusterCommand::Status(args) => {
            if !args.dir.is_dir() {
                return Err(sweptvol::error::InputError::new(
                    &args.dir,
                    "is not a folder",
                    "give the shard folder a cluster submit wrote (its --shard-dir)",
                )
                .into());
            }
            let st = cluster::status(&args.dir, true)?;
            if args.json {
                say(format_args!("{}\n", serde_json::to_string_pretty(&st)?))?;
                return Ok(());
            }
            say(format_args!("{}", cluster::describe(&st)))?;
            Ok(())
        }
    }
}

fn watch(args: WatchArgs) -> anyhow::Result<()> {
    let secs = |key: OptionKey, v: f64| {
        if v.is_finite() && v >= 0.0 {
            Ok(Duration::from_secs_f64(v))
        } else {
            Err(OptionError::new(
                key,
                format!("${} {v}: give a number of seconds >= 0", key.name()),
            ))
        }
    };
    let executor = match args.executor {
        ExecutorArg::Local => watch::Executor::Local,
        ExecutorArg::Slurm => watch::Executor::Slurm(watch::SlurmExecutor {
            shards: args.shards,
            binary: match args.binary {
                Some(b) => b,
                None => std::env::current_exe()?,
            },
            sbatch: args.sbatch,
            retries: args.retries,
        }),
    };
    let opts = WatchOptions {
        executor,
        dir: args.dir,
        once: args.once,
        settle: secs(OptionKey::Settle, args.settle)?,
        rescan: secs(OptionKey::Rescan, args.rescan)?.max(Duration::from_millis(100)),
        jobs: args.jobs,
        backend: args.backend,
        default_accuracy: Accuracy::choose(args.resolution, args.tolerance, Accuracy::DEFAULT),
        max_input_bytes: args.max_input_bytes,
    };
    watch::run(&opts)
}

/// Stage names and progress on a terminal bar.
struct VerifyBar(ProgressBar);

impl sweptvol::verify::Progress for VerifyBar {
    fn stage(&self, name: &str, total: u64) {
        self.0.set_message(name.to_string());
        self.0.set_length(total);
        self.0.set_position(0);
    }
    fn advance(&self, done: u64, total: u64) {
        self.0.set_length(total);
        self.0.set_position(done);
    }
}

/// Exit code of a verification whose certificate failed (2 stays "bad input", 1 "error").
const EXIT_CERTIFICATE_FAILED: u8 = 3;

fn verify(args: VerifyArgs) -> anyhow::Result<ExitCode> {
    let opts = sweptvol::verify::VerifyOptions {
        generator: args.generator,
        trajectory: args.trajectory,
        mesh: args.mesh,
        bound: args.bound,
        bound_scope: args.bound_scope.into(),
        spacing: args.spacing,
        all_failures: args.all_failures,
        motion: args.motion,
        relative_to: args.relative_to,
        rows: args.rows,
        package_dir: args.package_dir,
    };
    let bar = if args.quiet || args.json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0).with_style(
            ProgressStyle::with_template(
                "{msg} {bar:40} {pos}/{len}, {elapsed} elapsed, ETA {eta}",
            )
            .expect("progress template"),
        )
    };
    let bar = VerifyBar(bar);
    let report = sweptvol::verify::verify(&opts, &bar)?;
    bar.0.finish_and_clear();
    if args.json {
        say(format_args!("{}\n", serde_json::to_string_pretty(&report)?))?;
    } else {
        say(format_args!("{}", report.text()))?;
    }
    Ok(if report.passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_CERTIFICATE_FAILED)
    })
}

fn clearance(args: ClearanceArgs) -> anyhow::Result<ExitCode> {
    use sweptvol::pipeline::clearance as c;
    let opts = c::ClearanceOptions {
        mesh: args.mesh,
        report: args.report,
        asked: c::Asked {
            against: args.against,
            require: args.require_clearance,
            scale: args.clearance_scale,
        },
        out_dir: args.out,
        overwrite: args.overwrite,
    };
    let report = c::run(&opts)?;
    if args.json {
        say(format_args!("{}\n", serde_json::to_string_pretty(&report)?))?;
    } else {
        say_clearance(&report.clearance)?;
    }
    Ok(clearance_exit(&report.clearance))
}

/// One line per obstacle: verdict, interval, map.
fn say_clearance(c: &sweptvol::clearance::ClearanceSection) -> std::io::Result<()> {
    for e in &c.obstacles {
        let o = &e.clearance;
        say(format_args!(
            "{}: {}; clearance in [{:.6}, {}]; map {}\n",
            o.name,
            sweptvol::clearance::verdict_words(o),
            o.lower,
            o.upper.map_or("unknown".into(), |u| format!("{u:.6}")),
            e.map.display()
        ))?;
    }
    Ok(())
}

/// 0, or 3 when an obstacle does not keep the required clearance.
fn clearance_exit(c: &sweptvol::clearance::ClearanceSection) -> ExitCode {
    if c.passes {
        return ExitCode::SUCCESS;
    }
    if let Some(x) = c.required {
        tracing::error!(
            "an obstacle does not keep the required clearance {x} (--require-clearance)"
        );
    }
    ExitCode::from(EXIT_CERTIFICATE_FAILED)
}

fn main() -> ExitCode {
    // Mesa's implicit Vulkan layer VK_LAYER_MESA_device_select probes Wayland while adapters
    // are enumerated and prints "XDG_RUNTIME_DIR is invalid" without a session; it only picks
    // the display's GPU, which a compute job does not need. Set before any thread starts.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    let cli = Cli::parse();
    let quiet = match &cli.command {
        Command::Run(a) => a.quiet,
        Command::Sweep(a) => a.run.quiet,
        Command::Mesh(a) => a.quiet,
        Command::Cluster(_) => false,
        Command::Watch(a) => a.quiet,
        Command::Verify(a) => a.quiet || a.json,
        Command::Clearance(a) => a.json,
        Command::Protocol => true,
    };
    let default_level = if quiet { "warn" } else { "info" };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level)),
        )
        .with_writer(std::io::stderr)
        // A closed stderr (`2>&1 | head`) must not end the job: log lines that cannot be
        // written are dropped, not reported on the same closed stderr (which panics).
        .log_internal_errors(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .init();
    let result = match cli.command {
        Command::Run(args) => run(args),
        Command::Sweep(args) => sweep_shard(args).map(|()| ExitCode::SUCCESS),
        Command::Mesh(args) => mesh(args),
        Command::Cluster(c) => cluster(c).map(|()| ExitCode::SUCCESS),
        Command::Watch(args) => watch(args).map(|()| ExitCode::SUCCESS),
        Command::Verify(args) => verify(args),
        Command::Clearance(args) => clearance(args),
        Command::Protocol => say(format_args!("{:#}\n", watch::protocol::names_json()))
            .map(|()| ExitCode::SUCCESS)
            .map_err(anyhow::Error::from),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            // A closed stderr must not turn an error into a panic either.
            let _ = writeln!(
                std::io::stderr(),
                "error: {}",
                error::worded_chain(&e, OptionKey::flag)
            );
            // 2: the input or the options are wrong; 1: anything else.
            if error::is_user_error(&e) {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

/// A count of at least one.
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

/// Write `text` to stdout. A reader that went away (a closed pipe: `| head`) ends the output
/// quietly, as ripgrep does; the command carries on and exits as it would have.
fn say(text: std::fmt::Arguments) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_fmt(text).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}
