//! Batches of candidates whose regions are disjoint, so that they can be checked together.

use super::queue::{Candidate, Queue};
use super::region::Region;
use super::state::State;
use super::BATCH;

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
    /// they go back to the queue once that one commits.
    pub(super) fn gather(&mut self, s: &State, heap: &mut Queue) -> (Vec<Region>, Vec<Candidate>) {
        self.batch_no += 1;
        let (mut batch, mut deferred) = (Vec::with_capacity(BATCH), Vec::new());
        while batch.len() < BATCH {
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
