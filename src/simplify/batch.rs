//! Batches of candidates whose regions are disjoint, so that they can be checked together.

use super::queue::{Candidate, Queue};
use super::region::Region;
use super::state::State;
use super::BATCH;

/// A gather stops after deferring this many candidates. Late in a seam pass most of the queue
/// lies around the regions in flight; scanning all of it for every batch made the pass
/// quadratic in its queue (the gear at n = 512: 3.06 M candidates popped for 1,257 batches,
/// 2.99 M of them deferred; docs/perf-log.md, "Gathers that stop").
pub(super) const DEFER_AT_MOST: usize = 4 * BATCH;

/// Draws batches from the queue: candidates still current whose regions (a, b and their
/// neighbours) meet no region in flight.
pub(super) struct Gatherer {
    /// Per vertex, the number of the last batch whose region held it.
    pub(super) stamp: Vec<u32>,
    pub(super) batch_no: u32,
    pub(super) region: Vec<usize>,
}

impl Gatherer {
    /// For a mesh of `n` vertices. Batches are numbered from 2 up, and batch k conflicts with
    /// the stamps k and k - 1: the initial stamps, 0, with none.
    pub(super) fn new(n: usize) -> Self {
        Gatherer {
            stamp: vec![0; n],
            batch_no: 1,
            region: Vec::new(),
        }
    }

    /// The next batch (up to [`BATCH`] regions, cheapest first) and the candidates deferred
    /// because their regions meet this batch's or the previous one's (not yet committed):
    /// they go back to the queue once that one commits. At most [`DEFER_AT_MOST`] are
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
            if region.iter().any(|&x| self.stamp[x] + 1 >= self.batch_no) {
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
