//! Which jobs are ready to run: a pure state machine. It is fed snapshots of the watched folder
//! with the time they were taken (an injected clock: any monotonic `Duration`), and answers
//! with jobs to start. It does no I/O, so it is tested on recorded sequences without sleeping.
//!
//! Rules (docs/exchange-protocol.md):
//! - a job folder is ready as soon as it appears (its rename was the commit);
//! - a drop is ready once `<name>.glb` and `<name>.csv` both exist and neither's size or mtime
//!   has changed for the settle time;
//! - a job whose recorded status is finished for the same inputs is skipped; one left `queued`
//!   or `running` (a crash, a shutdown) runs again;
//! - within one daemon run a job runs at most once per set of inputs, and never twice at once.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use super::protocol::{classify, FileStamp, Fingerprint, JobId, Recorded, Role};

/// One entry at the top of the watched folder.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub name: String,
    /// After following a symlink.
    pub is_dir: bool,
    pub symlink: bool,
    pub size: u64,
    pub mtime_ns: i64,
}

/// What the scanner saw at one moment.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Snapshot {
    pub entries: Vec<Entry>,
    /// The inputs inside each job folder (read only for `Role::JobFolder`, never in `.partial`).
    pub folders: BTreeMap<String, Fingerprint>,
    /// Status files that exist and parse.
    pub recorded: BTreeMap<JobId, Recorded>,
}

/// What the daemon should do.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Start this job; `inputs` go into its status file.
    Run { id: JobId, inputs: Fingerprint },
    /// Refuse an entry (said once per name); nothing is written for it.
    Refuse { name: String, reason: String },
}

/// A complete drop pair and when it last changed.
#[derive(Clone, Debug)]
struct Settling {
    inputs: Fingerprint,
    since: Duration,
}

#[derive(Debug)]
pub struct Detector {
    settle: Duration,
    settling: BTreeMap<String, Settling>,
    in_flight: BTreeSet<JobId>,
    /// Inputs each job ran with in this daemon run.
    ran: BTreeMap<JobId, Fingerprint>,
    refused: BTreeSet<String>,
}

impl Detector {
    pub fn new(settle: Duration) -> Self {
        Detector {
            settle,
            settling: BTreeMap::new(),
            in_flight: BTreeSet::new(),
            ran: BTreeMap::new(),
            refused: BTreeSet::new(),
        }
    }

    /// Take in a snapshot taken at `now`; returns the jobs to start in arrival order (oldest
    /// input mtime first, then name) and the entries to refuse. Started jobs are in flight until
    /// [`Detector::finished`].
    pub fn observe(&mut self, now: Duration, snap: &Snapshot) -> Vec<Action> {
        let mut actions = Vec::new();
        let mut ready: Vec<(i64, JobId, Fingerprint)> = Vec::new();
        let mut drops: BTreeMap<String, [Option<&Entry>; 2]> = BTreeMap::new();
        let mut seen_names = BTreeSet::new();
        for e in &snap.entries {
            seen_names.insert(e.name.clone());
            match classify(&e.name, e.is_dir) {
                Role::JobFolder if e.symlink => {
                    if self.refused.insert(e.name.clone()) {
                        actions.push(Action::Refuse {
                            name: e.name.clone(),
                            reason: "a job folder must be a real folder in the watched folder, not a symbolic link (nothing is read or written through it); copy the folder in instead".into(),
                        });
                    }
                }
                Role::JobFolder => {
                    let Some(inputs) = snap.folders.get(&e.name) else {
                        continue; // vanished between listing and reading
                    };
                    let id = JobId::Folder(e.name.clone());
                    if self.wanted(&id, inputs, snap) {
                        // Arrival: the newest input, not the folder's mtime, which every
                        // status write inside it moves.
                        let arrival = inputs.iter().map(|f| f.mtime_ns).max();
                        ready.push((arrival.unwrap_or(e.mtime_ns), id, inputs.clone()));
                    }
                }
                Role::DropGenerator(stem) => drops.entry(stem).or_default()[0] = Some(e),
                Role::DropTrajectory(stem) => drops.entry(stem).or_default()[1] = Some(e),
                Role::Ignored => {}
            }
        }
        // Forget refusals of names that went away, so a new entry under that name is judged anew.
        self.refused.retain(|n| seen_names.contains(n));

        let mut still_settling = BTreeMap::new();
        for (stem, pair) in drops {
            let [Some(g), Some(t)] = pair else { continue };
            let mut inputs = vec![stamp(g), stamp(t)];
            inputs.sort();
            let id = JobId::Drop(stem.clone());
            if !self.wanted(&id, &inputs, snap) {
                continue;
            }
            let since = match self.settling.get(&stem) {
                Some(s) if s.inputs == inputs => s.since,
                _ => now,
            };
            if now.saturating_sub(since) >= self.settle {
                ready.push((g.mtime_ns.max(t.mtime_ns), id, inputs));
            } else {
                still_settling.insert(stem, Settling { inputs, since });
            }
        }
        self.settling = still_settling;

        ready.sort();
        for (_, id, inputs) in ready {
            self.in_flight.insert(id.clone());
            self.ran.insert(id.clone(), inputs.clone());
            actions.push(Action::Run { id, inputs });
        }
        actions
    }

    /// Whether `id` with these inputs should run now.
    fn wanted(&self, id: &JobId, inputs: &Fingerprint, snap: &Snapshot) -> bool {
        if self.in_flight.contains(id) || self.ran.get(id) == Some(inputs) {
            return false;
        }
        match snap.recorded.get(id) {
            Some(r) => !(r.state.is_finished() && &r.inputs == inputs),
            None => true,
        }
    }

    /// The job has ended (its status file is written).
    pub fn finished(&mut self, id: &JobId) {
        self.in_flight.remove(id);
    }

    /// When the earliest settling drop will have been stable long enough: rescan then.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.settling.values().map(|s| s.since + self.settle).min()
    }

    /// No drop is settling and no job is in flight (`--once` may exit after a rescan).
    pub fn is_idle(&self) -> bool {
        self.settling.is_empty() && self.in_flight.is_empty()
    }
}

fn stamp(e: &Entry) -> FileStamp {
    FileStamp {
        file: e.name.clone(),
        size: e.size,
        mtime_ns: e.mtime_ns,
    }
}

#[cfg(test)]
mod tests {
    //! Recorded sequences: each step is (seconds since start, the folder's top-level files as
    //! (name, size, mtime)), as the scanner would report them.
    use super::*;
    use crate::watch::protocol::State;

    const SETTLE: Duration = Duration::from_secs(2);

    fn t(secs: f64) -> Duration {
        Duration::from_secs_f64(secs)
    }

    fn file(name: &str, size: u64, mtime: i64) -> Entry {
        Entry {
            name: name.into(),
            is_dir: false,
            symlink: false,
            size,
            mtime_ns: mtime,
        }
    }

    /// (name, size, mtime) of each top-level file.
    type Files<'a> = &'a [(&'a str, u64, i64)];

    fn snap(files: Files) -> Snapshot {
        Snapshot {
            entries: files.iter().map(|&(n, s, m)| file(n, s, m)).collect(),
            ..Default::default()
        }
    }

    fn with_folder(mut s: Snapshot, name: &str, mtime: i64, inputs: Fingerprint) -> Snapshot {
        s.entries.push(Entry {
            name: name.into(),
            is_dir: true,
            symlink: false,
            size: 4096,
            mtime_ns: mtime,
        });
        s.folders.insert(name.into(), inputs);
        s
    }

    fn started(actions: &[Action]) -> Vec<String> {
        actions
            .iter()
            .filter_map(|a| match a {
                Action::Run { id, .. } => Some(id.to_string()),
                Action::Refuse { .. } => None,
            })
            .collect()
    }

    fn folder_inputs() -> Fingerprint {
        vec![
            FileStamp {
                file: "generator.glb".into(),
                size: 900,
                mtime_ns: 5,
            },
            FileStamp {
                file: "trajectory.csv".into(),
                size: 80,
                mtime_ns: 5,
            },
        ]
    }

    /// A slow copy (`cp` of a large glb over a network share): the glb grows in chunks every
    /// 0.8 s, the csv comes last. Nothing starts until both have been unchanged for 2 s.
    #[test]
    fn slow_chunked_drop_starts_only_after_settling() {
        let mut d = Detector::new(SETTLE);
        let steps: &[(f64, Files, bool)] = &[
            (0.0, &[("part.glb", 4096, 1)], false),
            (0.8, &[("part.glb", 8192, 2)], false),
            (1.6, &[("part.glb", 12288, 3), ("part.csv", 0, 3)], false),
            (2.4, &[("part.glb", 16000, 4), ("part.csv", 0, 3)], false),
            (3.2, &[("part.glb", 16000, 4), ("part.csv", 50, 5)], false),
            (4.0, &[("part.glb", 16000, 4), ("part.csv", 100, 6)], false),
            (5.9, &[("part.glb", 16000, 4), ("part.csv", 100, 6)], false),
            (6.0, &[("part.glb", 16000, 4), ("part.csv", 100, 6)], true),
            (9.0, &[("part.glb", 16000, 4), ("part.csv", 100, 6)], false),
        ];
        for (i, &(at, files, expect)) in steps.iter().enumerate() {
            let actions = d.observe(t(at), &snap(files));
            assert_eq!(
                started(&actions).len(),
                expect as usize,
                "step {i} at {at}s"
            );
            if i == 6 {
                assert_eq!(d.next_deadline(), Some(t(6.0)));
            }
        }
        assert!(!d.is_idle());
        d.finished(&JobId::Drop("part".into()));
        assert!(d.is_idle());
        // Same inputs later in the same run: not again.
        let files: Files = &[("part.glb", 16000, 4), ("part.csv", 100, 6)];
        assert!(started(&d.observe(t(20.0), &snap(files))).is_empty());
        // A new version of the csv: settles, then runs again.
        let files: Files = &[("part.glb", 16000, 4), ("part.csv", 120, 30)];
        assert!(started(&d.observe(t(30.0), &snap(files))).is_empty());
        assert_eq!(
            started(&d.observe(t(32.0), &snap(files))),
            ["part.glb + part.csv"]
        );
    }

    /// Only a touch (mtime) changes: that is a change too.
    #[test]
    fn mtime_change_alone_restarts_the_settle_time() {
        let mut d = Detector::new(SETTLE);
        d.observe(t(0.0), &snap(&[("a.glb", 10, 1), ("a.csv", 10, 1)]));
        d.observe(t(1.5), &snap(&[("a.glb", 10, 2), ("a.csv", 10, 1)]));
        let a = d.observe(t(2.5), &snap(&[("a.glb", 10, 2), ("a.csv", 10, 1)]));
        assert!(started(&a).is_empty());
        let a = d.observe(t(3.5), &snap(&[("a.glb", 10, 2), ("a.csv", 10, 1)]));
        assert_eq!(started(&a), ["a.glb + a.csv"]);
    }

    /// Outputs, temporary files, lone halves and `.partial` folders never start anything.
    #[test]
    fn outputs_partials_and_halves_are_not_jobs() {
        let mut d = Detector::new(SETTLE);
        let mut s = snap(&[
            ("a.swept.glb", 10, 1),
            ("a.swept.csv", 10, 1), // its glb half is an output: no pair
            ("b.glb", 10, 1),       // no csv
            (".c.glb.tmp-77", 10, 1),
            (".c.csv.tmp-77", 10, 1),
            ("d.report.json", 10, 1),
        ]);
        s.entries.push(Entry {
            name: "job.partial".into(),
            is_dir: true,
            symlink: false,
            size: 0,
            mtime_ns: 1,
        });
        for at in [0.0, 5.0, 10.0] {
            assert!(d.observe(t(at), &s).is_empty());
        }
        assert!(d.is_idle());
    }

    /// `job.partial` renamed to `job` (one Create(Folder) event, then a rescan): ready at once,
    /// without a settle time.
    #[test]
    fn renamed_job_folder_starts_at_once() {
        let mut d = Detector::new(SETTLE);
        let mut s = snap(&[]);
        s.entries.push(Entry {
            name: "j1.partial".into(),
            is_dir: true,
            symlink: false,
            size: 0,
            mtime_ns: 1,
        });
        assert!(d.observe(t(0.0), &s).is_empty());
        let s = with_folder(snap(&[]), "j1", 1, folder_inputs());
        assert_eq!(started(&d.observe(t(0.3), &s)), ["j1/"]);
        // In flight: later rescans do not start it again.
        assert!(d.observe(t(0.6), &s).is_empty());
    }

    /// A restart: finished jobs with unchanged inputs are skipped, jobs left running or queued
    /// run again, a finished job whose inputs changed runs again. Oldest inputs first.
    #[test]
    fn restart_skips_finished_and_reruns_interrupted() {
        let mut d = Detector::new(SETTLE);
        let mut s = snap(&[]);
        // Inputs written in the order done, changed, queued, crashed; the folders' own mtimes
        // (moved by status writes) say otherwise and must not decide.
        let written = |mtime: i64| -> Fingerprint {
            let mut f = folder_inputs();
            f.iter_mut().for_each(|x| x.mtime_ns = mtime);
            f
        };
        for (name, mtime, folder_mtime) in [
            ("done", 1, 9),
            ("crashed", 4, 1),
            ("queued", 3, 2),
            ("changed", 2, 8),
        ] {
            s = with_folder(s, name, folder_mtime, written(mtime));
        }
        let rec = |state, inputs| Recorded { state, inputs };
        let mut old = written(2);
        old[1].size = 81;
        s.recorded
            .insert(JobId::Folder("done".into()), rec(State::Done, written(1)));
        s.recorded.insert(
            JobId::Folder("crashed".into()),
            rec(State::Running, written(4)),
        );
        s.recorded.insert(
            JobId::Folder("queued".into()),
            rec(State::Queued, written(3)),
        );
        s.recorded
            .insert(JobId::Folder("changed".into()), rec(State::Failed, old));
        assert_eq!(
            started(&d.observe(t(0.0), &s)),
            ["changed/", "queued/", "crashed/"]
        );
    }

    /// A finished drop with unchanged inputs is skipped without waiting to settle, so `--once`
    /// exits at once on a folder where everything is done.
    #[test]
    fn finished_drop_is_skipped_without_settling() {
        let mut d = Detector::new(SETTLE);
        let mut s = snap(&[("a.glb", 10, 1), ("a.csv", 10, 1)]);
        let inputs = vec![stamp(&s.entries[1]), stamp(&s.entries[0])];
        s.recorded.insert(
            JobId::Drop("a".into()),
            Recorded {
                state: State::Done,
                inputs,
            },
        );
        assert!(d.observe(t(0.0), &s).is_empty());
        assert!(d.is_idle());
    }

    /// Twenty drops arriving together all start once, in name order when mtimes tie.
    #[test]
    fn twenty_drops_start_once_each() {
        let mut d = Detector::new(SETTLE);
        let names: Vec<(String, String)> = (0..20)
            .map(|i| (format!("p{i:02}.glb"), format!("p{i:02}.csv")))
            .collect();
        let files: Vec<(&str, u64, i64)> = names
            .iter()
            .flat_map(|(g, c)| [(g.as_str(), 100, 7), (c.as_str(), 50, 7)])
            .collect();
        assert!(d.observe(t(0.0), &snap(&files)).is_empty());
        let all = started(&d.observe(t(2.0), &snap(&files)));
        assert_eq!(all.len(), 20);
        assert_eq!(all[0], "p00.glb + p00.csv");
        assert!(d.observe(t(4.0), &snap(&files)).is_empty());
    }

    /// A symlinked job folder is refused once, and judged again if it is replaced.
    #[test]
    fn symlinked_job_folder_is_refused_once() {
        let mut d = Detector::new(SETTLE);
        let mut s = with_folder(snap(&[]), "evil", 1, folder_inputs());
        s.entries[0].symlink = true;
        let a = d.observe(t(0.0), &s);
        assert!(matches!(&a[..], [Action::Refuse { name, .. }] if name == "evil"));
        assert!(d.observe(t(1.0), &s).is_empty());
        d.observe(t(2.0), &snap(&[]));
        assert_eq!(d.observe(t(3.0), &s).len(), 1);
    }
}
