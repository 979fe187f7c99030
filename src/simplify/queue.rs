//! The candidates, cheapest first.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};

/// A heap entry: 16 bytes, as the heap holds about 1.5 per start triangle.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    /// Quadric error of the cheapest target (f32: only the order matters, and ties fall to
    /// [`Candidate::scatter`]).
    pub(super) cost: f32,
    pub(super) a: u32,
    pub(super) b: u32,
    /// version[a] + version[b] when the candidate was computed. Versions only grow, so the sum
    /// changes exactly when either does: the entry is stale then (the target is recomputed
    /// when a fresh candidate is taken, keeping the heap's entries small).
    pub(super) ver: u32,
}
const _: () = assert!(std::mem::size_of::<Candidate>() == 16);

impl Candidate {
    /// Tie-break among equal costs: a hash of the edge, so that equal-cost collapses (flat
    /// regions) spread over the surface instead of sweeping it in index order, and the order
    /// does not depend on the heap's history.
    pub(super) fn scatter(&self) -> u64 {
        ((self.a as u64) << 32 | self.b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
    }
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    // Min-heap on cost; ties by edge, so the order does not depend on the heap's history.
    fn cmp(&self, o: &Self) -> Ordering {
        o.cost
            .total_cmp(&self.cost)
            .then_with(|| o.scatter().cmp(&self.scatter()))
    }
}

/// Candidates, cheapest first. Those of cost 0 (flat regions and straight creases: most of the
/// start) wait in a FIFO, first in the scattered tie order, then in the order they arise. The
/// rest wait in buckets by the top 15 bits of their cost (sign excluded: for costs ≥ 0 the bits
/// order as the values), each a small binary heap: the exact order, with short sifts that stay
/// in cache instead of one heap's ~20 levels across memory.
pub(super) struct Queue {
    pub(super) zero: VecDeque<Candidate>,
    pub(super) buckets: Vec<BinaryHeap<Candidate>>,
    /// No greater than the first non-empty bucket.
    pub(super) low: usize,
}

/// Buckets of [`Queue`]: one per value of a non-negative f32's top 16 bits.
pub(super) const BUCKETS: usize = 1 << 15;

/// The bucket of a cost: negative ones (rounding) first, NaN last.
pub(super) fn bucket(cost: f32) -> usize {
    if cost <= 0.0 {
        0
    } else {
        ((cost.to_bits() >> 16) as usize).min(BUCKETS - 1)
    }
}

impl Queue {
    pub(super) fn new(mut all: Vec<Candidate>) -> Queue {
        // [costly | free]: the free ones move out; the costly ones go to their buckets.
        let split = partition_by(&mut all, |c| c.cost != 0.0);
        let mut zero = all.split_off(split);
        zero.sort_unstable_by_key(Candidate::scatter);
        // Split off bucket by bucket from the back of `all` sorted by bucket, shrinking it as it
        // goes, so that its freed memory serves the next buckets: the candidates are held once,
        // not twice (memory freed to the allocator mid-heap stays resident).
        all.sort_unstable_by_key(|c| bucket(c.cost));
        let mut buckets: Vec<BinaryHeap<Candidate>> =
            (0..BUCKETS).map(|_| BinaryHeap::new()).collect();
        while let Some(last) = all.last() {
            let k = bucket(last.cost);
            let start = all.partition_point(|c| bucket(c.cost) < k);
            buckets[k] = BinaryHeap::from(all.split_off(start));
            all.shrink_to_fit();
        }
        Queue {
            zero: VecDeque::from(zero),
            buckets,
            low: 0,
        }
    }

    pub(super) fn pop(&mut self) -> Option<Candidate> {
        if let Some(c) = self.zero.pop_front() {
            return Some(c);
        }
        while self.low < BUCKETS {
            if let Some(c) = self.buckets[self.low].pop() {
                return Some(c);
            }
            self.low += 1;
        }
        None
    }
}

/// Reorders `v` so that the elements for which `pred` holds come first; returns their count.
pub(super) fn partition_by<T>(v: &mut [T], pred: impl Fn(&T) -> bool) -> usize {
    let mut split = 0;
    for i in 0..v.len() {
        if pred(&v[i]) {
            v.swap(split, i);
            split += 1;
        }
    }
    split
}
