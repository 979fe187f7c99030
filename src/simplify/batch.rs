//! Batches of candidates whose regions are disjoint, so that they can be checked together.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use super::queue::{Candidate, Queue};
use super::region::{Plan, Region, Reject};
use super::state::State;
use super::BATCH;

/// A gather stops after deferring this many candidates. Late in a seam pass most of the queue
/// lies around the regions in flight; scanning all of it for every batch made the pass
/// quadratic in its queue (the gear at n = 512: 3.06 M candidates popped for 1,257 batches,
/// 2.99 M of them deferred; docs/perf-log.md, "Gathers that stop").
pub(super) const DEFER_AT_MOST: usize = 4 * BATCH;

/// Batches gathered and not yet committed, the one being gathered included: its regions are
/// disjoint from theirs, so their checks run side by side and its regions can be read from
/// the mesh before they commit (a commit changes only triangles whose vertices all lie in its
/// regions). Three and four measured no faster than two on the gear's seam pass (more batches
/// queued, but each gathered against more regions: docs/perf-log.md, "The seam pass's checks
/// queued").
pub(super) const IN_FLIGHT: u32 = 2;

/// Draws batches from the queue: candidates still current whose regions (a, b and their
/// neighbours) meet no region in flight.
pub(super) struct Gatherer {
    /// Per vertex, the number of the last batch whose region held it.
    pub(super) stamp: Vec<u32>,
    pub(super) batch_no: u32,
    pub(super) region: Vec<usize>,
}

impl Gatherer {
    /// For a mesh of `n` vertices. Batches are numbered from `IN_FLIGHT` up, and batch k
    /// conflicts with the stamps k - IN_FLIGHT + 1 to k: the initial stamps, 0, with none.
    pub(super) fn new(n: usize) -> Self {
        Gatherer {
            stamp: vec![0; n],
            batch_no: IN_FLIGHT - 1,
            region: Vec::new(),
        }
    }

    /// The next batch (up to [`BATCH`] regions, cheapest first) and the candidates deferred
    /// because their regions meet this batch's or one of the `IN_FLIGHT - 1` before it (not
    /// yet committed): they go back to the queue at the next commit. At most [`DEFER_AT_MOST`] are
    /// deferred; the batch is then what was found before them.
    pub(super) fn gather(&mut self, s: &State, heap: &mut Queue) -> (Vec<Region>, Vec<Candidate>) {
        self.batch_no += 1;
        let (mut batch, mut deferred) = (Vec::with_capacity(BATCH), Vec::new());
        while batch.len() < BATCH && deferred.len() < DEFER_AT_MOST {
            let Some(c) = heap.pop() else { break };
            if !s.is_current(&c) {
                continue;
            }
            let region = &mut self.region;
            region.clear();
            s.star_vertices(c.a as usize, region);
            s.star_vertices(c.b as usize, region);
            if region
                .iter()
                .any(|&x| self.stamp[x] + IN_FLIGHT > self.batch_no)
            {
                deferred.push(c);
                continue;
            }
            for &x in region.iter() {
                self.stamp[x] = self.batch_no;
            }
            batch.push(s.region(c.a, c.b));
        }
        (batch, deferred)
    }
}

/// Counts a task done when dropped: when it returns, and when it unwinds.
struct Done(Arc<AtomicUsize>);

impl Drop for Done {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Release);
    }
}

/// One outcome of a region's local checks.
type Outcome = Result<Plan, Reject>;

/// A batch whose regions' local checks run as tasks on the pool; [`Self::wait`] collects them
/// in the batch's order, running queued tasks (this batch's or a later one's) while it waits.
pub(super) struct InFlight {
    keys: Vec<(u32, u32)>,
    slots: Arc<Vec<Mutex<Option<Outcome>>>>,
    left: Arc<AtomicUsize>,
}

impl InFlight {
    /// Queues `check` of every region of `batch` on `pool`, oldest first.
    pub(super) fn start<'s, F>(
        pool: &rayon::ScopeFifo<'s>,
        batch: Vec<Region>,
        check: &'s F,
    ) -> Self
    where
        F: Fn(&Region) -> Outcome + Sync,
    {
        let keys = batch.iter().map(|r| (r.a, r.b)).collect();
        let slots: Arc<Vec<_>> = Arc::new(batch.iter().map(|_| Mutex::new(None)).collect());
        let left = Arc::new(AtomicUsize::new(batch.len()));
        for (i, region) in batch.into_iter().enumerate() {
            let (slots, done) = (slots.clone(), Done(left.clone()));
            pool.spawn_fifo(move |_| {
                let _done = done; // counted even if the check panics, so no wait hangs
                *slots[i].lock().expect("one writer") = Some(check(&region));
            });
        }
        InFlight { keys, slots, left }
    }

    pub(super) fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The candidates' edges and their outcomes, in the batch's order, once every check ran.
    /// Must be called on a thread of the pool the checks were queued on.
    pub(super) fn wait(self) -> (Vec<(u32, u32)>, Vec<Outcome>) {
        while self.left.load(Ordering::Acquire) > 0 {
            match rayon::yield_now() {
                Some(rayon::Yield::Executed) => {}
                Some(rayon::Yield::Idle) => std::thread::yield_now(),
                None => unreachable!("InFlight::wait runs on a thread of the pool"),
            }
        }
        let outcomes = (self.slots.iter())
            .map(|slot| {
                let mut outcome = slot.lock().expect("a check that panicked");
                outcome.take().expect("a check that panicked")
            })
            .collect();
        (self.keys, outcomes)
    }
}
