//! The simplifier block by block (docs/design.md, "Blocks"): each block's patch of the voxel
//! boundary is extracted and simplified on its own, blocks in parallel, with the patch's open
//! edges locked; the patches are then welded along their locked vertices and one seam pass
//! simplifies the whole, starting from the edges at the seams. Only one block's fine mesh per
//! worker is held at a time, and a block's data stays in cache.
//!
//! What keeps it sound, beyond the checks of a single pass (`super`):
//! - A block's pass never moves or removes a locked vertex (no candidate with a locked end), so
//!   the patches fit together vertex for vertex.
//! - Every triangle a block's pass moves lies in the block's closed box and touches the box's
//!   faces only at locked vertices (each of its vertices is locked or strictly inside the box;
//!   else the collapse is left to the seam pass). Other blocks' triangles lie in their own
//!   boxes and likewise, so triangles of different blocks meet only at shared locked vertices
//!   or along shared locked edges; each block's own self-intersection test covers the rest.
//!   Collapses that keep the surface's point set move nothing and need no such rule. A
//!   remeshed disc (`discs`) follows the same rule and makes no new edge between two locked
//!   vertices (one could lie on the box's face, where the next block's triangles are).
//! - The tolerance and sweep checks are local to each collapse; a collapse's swept region lies
//!   in its block's box, and the winding numbers it changes add up whatever the order.
//!
//! - Groups of 2×2×2 blocks (then of groups) are welded and simplified the same way as one block
//!   of their joint box, with only the seam vertices on that box's planes locked; every point
//!   strictly inside the box is the group's alone, so the rules above hold for it unchanged.
//!
//! The output does not depend on the thread count: each block and group is simplified on its
//! own, in one fixed order, their results are kept by index (whatever order they ran in) and
//! welded in a fixed order, and the seam pass is deterministic.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::hash::BuildHasherDefault;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use glam::DVec3;
use rayon::prelude::*;

use super::band::{pack_cell, KeyHasher};
use super::pieces::Pieces;
use super::quadric::Quadric;
use super::queue::{Candidate, Queue};
use super::state::{park, Crossings, Reject, Scratch, State};
use super::{all_edges, check_radii, run_batches, SimplifyOptions, SimplifyStats};
use super::{clusters, discs};
use crate::mesh::blocks::{blocks, extract_block, faces_estimate, split_dominant, Block, Patch};
use crate::mesh::classify::{Classifier, VoxelSet};
use crate::mesh::Mesh;

/// Voxels along each edge of a block: its fine mesh (about 2·B² start triangles where the
/// surface crosses it) is one worker's to hold, and blocks are few enough for the seams to be
/// short. 256 against 128, with the groups and the clusters: 4-11% faster at n = 512 and 11-22%
/// at n = 1500 on two cores, the same peak at n = 1500 (docs/design.md, "Why 256").
pub const BLOCK_VOXELS: usize = 256;

/// Least width (voxels) of a block that [`split_dominant`] makes.
const SPLIT_AT_LEAST: usize = 32;

/// After the blocks, groups of 2×2×2 of them (then of those groups, and so on) are simplified
/// in parallel while a level has at least this many groups; the seam pass takes what is left.
/// A fixed count, so that the levels, like the output, do not depend on the thread count.
pub const GROUPS_AT_LEAST: usize = 8;

/// What the block by block simplifier did.
#[derive(Clone, Debug)]
pub struct Simplified {
    pub mesh: Mesh,
    pub stats: SimplifyStats,
    /// Triangles of the whole voxel boundary (the blocks' patches together).
    pub triangles_start: u64,
}

/// One block (or group of blocks) after its pass: its box, its live mesh, each vertex's
/// quadric, which vertices are locked, the edges left to a later pass for the border rule (ids
/// of `mesh`), and its share of a target count (0: none).
struct Done {
    block: Block,
    mesh: Mesh,
    quadric: Vec<Quadric>,
    locked: Vec<bool>,
    border: Vec<(u32, u32)>,
    stats: SimplifyStats,
    triangles_start: u64,
    target: usize,
}

/// Simplify the boundary of `set` (the joined voxels of `cls`) block by block, then along the
/// seams. `block` voxels per block edge. None when `stop` said yes.
pub fn simplify_boundary(
    set: &(dyn VoxelSet + Sync),
    cls: &Classifier,
    pieces: Option<&Pieces>,
    opts: SimplifyOptions,
    block: usize,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<Simplified> {
    simplify_boundary_with(set, cls, pieces, opts, block, Locks::Honour, stop)
}

/// Whether a block's (and a group's) pass keeps its locked vertices (the tests show what
/// breaks otherwise).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Locks {
    Honour,
    #[cfg(test)]
    Ignore,
    /// Blocks keep theirs; groups free every seam vertex, those on their own faces too.
    #[cfg(test)]
    IgnoreInGroups,
}

impl Locks {
    fn in_blocks(self) -> bool {
        match self {
            Locks::Honour => true,
            #[cfg(test)]
            Locks::Ignore => false,
            #[cfg(test)]
            Locks::IgnoreInGroups => true,
        }
    }

    fn in_groups(self) -> bool {
        self == Locks::Honour
    }
}

fn simplify_boundary_with(
    set: &(dyn VoxelSet + Sync),
    cls: &Classifier,
    pieces: Option<&Pieces>,
    opts: SimplifyOptions,
    block: usize,
    locks: Locks,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<Simplified> {
    check_radii(&opts);
    // The costliest blocks first, by a sample of their faces, so that none of them is left
    // to run alone at the end; a block holding more than half of all is split first.
    let list = blocks(set.dims(), block);
    let cost: Vec<usize> = list.par_iter().map(|b| faces_estimate(set, b)).collect();
    let whole = list.len();
    let (list, cost) = split_dominant(list, cost, SPLIT_AT_LEAST, |b| faces_estimate(set, b));
    if list.len() > whole {
        tracing::info!(
            "blocks holding more than half of the surface split: {whole} blocks of {block} \
             voxels became {}",
            list.len()
        );
    }
    // With a target count, each block stops at its share of it (by start triangles), counted
    // first; groups stop at their blocks' shares together, the seam pass at the target itself.
    let shares = (opts.target_triangles > 0).then(|| {
        let counts: Vec<usize> = list
            .par_iter()
            .map(|b| extract_block(set, b).mesh.triangles.len())
            .collect();
        let total = counts.iter().sum::<usize>().max(1);
        counts
            .iter()
            .map(|&c| (opts.target_triangles * c).div_ceil(total))
            .collect::<Vec<_>>()
    });
    // Progress for long runs: a line at every tenth of the blocks.
    let finished = AtomicUsize::new(0);
    let tenth = list.len().div_ceil(10).max(1);
    let done = largest_first(&cost, |n| {
        if stop() {
            return None;
        }
        let b = &list[n];
        let target = shares.as_ref().map_or(0, |s| s[n]);
        // Crossings tested against the neighbours only, the result certified; where it holds
        // a crossing pair, the block again with every near triangle tested.
        let pass = |crossings| {
            let patch = extract_block(set, b);
            let pass = Pass {
                opts,
                target,
                crossings,
                locks: locks.in_blocks(),
            };
            simplify_block(patch, b, cls, pieces, pass, stop)
        };
        let out = pass(Crossings::Neighbours).unwrap_or_else(|| {
            let mut done = pass(Crossings::Near).expect("a pass that tests every near pair");
            done.stats.blocks_redone += 1;
            done
        });
        let k = finished.fetch_add(1, Ordering::Relaxed) + 1;
        if k % tenth == 0 && k < list.len() {
            tracing::info!("simplified {k} of {} blocks", list.len());
        }
        Some(out)
    });
    let mut done: Vec<Done> = done.into_iter().collect::<Option<Vec<_>>>()?;
    let triangles_start = done.iter().map(|d| d.triangles_start).sum::<u64>();
    let mut size = block;
    loop {
        if stop() {
            return None;
        }
        let what = if size == block { "blocks" } else { "groups" };
        tracing::info!(
            "{} {what} of up to {size} voxels simplified: {triangles_start} start triangles down \
             to {}",
            done.len(),
            done.iter().map(|d| d.mesh.triangles.len()).sum::<usize>()
        );
        let groups = groups(done, 2 * size);
        if groups.len() < GROUPS_AT_LEAST {
            done = groups.into_iter().flatten().collect();
            break;
        }
        size *= 2;
        let cost: Vec<usize> = groups
            .iter()
            .map(|g| g.iter().map(|d| d.mesh.triangles.len()).sum())
            .collect();
        let groups: Vec<Mutex<Option<Vec<Done>>>> =
            groups.into_iter().map(|g| Mutex::new(Some(g))).collect();
        done = largest_first(&cost, |n| {
            let members = groups[n]
                .lock()
                .expect("one user")
                .take()
                .expect("taken once");
            simplify_group(members, cls, pieces, opts, locks, stop)
        })
        .into_iter()
        .collect::<Option<Vec<_>>>()?;
    }
    let Welded {
        mesh,
        quadric,
        seam,
        border,
        mut stats,
    } = weld(done);
    tracing::info!(
        "simplifying along the seams: {} triangles",
        mesh.triangles.len()
    );
    if stats.blocks_redone > 0 {
        tracing::info!(
            "{} of the blocks and groups simplified twice: their first pass ended with two \
             triangles crossing",
            stats.blocks_redone
        );
    }
    // Edges at the seams (and those the border rule left) are tried again; every other edge
    // was tried last in its block on the same triangles around it, so it is parked until a
    // collapse changes them. Crossings tested against the neighbours only and certified at the
    // end, as for a group; where the certificate finds a pair, the pass again from the same
    // welded start with every near triangle tested (its members meet only at shared locked
    // vertices and edges, so no two of its triangles cross). The loop runs on a worker of the
    // pool, so that it takes part in its batches' parallel checks instead of sleeping through
    // each one and waiting to be woken.
    let pass = |crossings| {
        let mut s = State::unfiled(mesh.clone(), Some(quadric.clone()));
        s.crossings = crossings;
        s.file();
        let (queued, parked) = seeds(&s, &seam, &border, |_| true);
        let heap = Queue::new(queued);
        let s = rayon::scope(|_| run_batches(s, heap, parked, cls, pieces, opts, stop))?;
        Some((crossings == Crossings::Near || s.crossing_free()).then_some(s))
    };
    let s = match pass(Crossings::Neighbours)? {
        Some(s) => s,
        None => {
            tracing::info!(
                "the seam pass ended with two triangles crossing: done again, every near \
                 triangle tested"
            );
            stats.blocks_redone += 1;
            pass(Crossings::Near)?.expect("a pass that tests every near pair")
        }
    };
    stats.add(&s.stats);
    Some(Simplified {
        mesh: s.compact(),
        stats,
        triangles_start,
    })
}

/// Runs `job(i)` for every i in 0..cost.len() on the pool's threads, costliest first (each
/// thread takes the next one as it finishes one, so the longest are not left to the end), and
/// returns the results in index order: the same whatever the thread count.
fn largest_first<T: Send>(cost: &[usize], job: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let mut order: Vec<usize> = (0..cost.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(cost[i]), i));
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<T>>> = (0..cost.len()).map(|_| Mutex::new(None)).collect();
    rayon::scope(|scope| {
        for _ in 0..rayon::current_num_threads().min(cost.len()) {
            scope.spawn(|_| {
                while let Some(&i) = order.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let out = job(i);
                    *slots[i].lock().expect("one writer") = Some(out);
                }
            });
        }
    });
    slots
        .into_iter()
        .map(|m| m.into_inner().expect("no panic").expect("every job ran"))
        .collect()
}

/// `done` in groups of up to 2×2×2 by the boxes of `size` voxels their lowest corners fall
/// in, groups in z, y, x order and each group's members in their order.
fn groups(done: Vec<Done>, size: usize) -> Vec<Vec<Done>> {
    let mut by: BTreeMap<[usize; 3], Vec<Done>> = BTreeMap::new();
    for d in done {
        let [x, y, z] = d.block.lo.map(|c| c / size);
        by.entry([z, y, x]).or_default().push(d);
    }
    by.into_values().collect()
}

/// The candidates of a pass that starts from meshes already simplified: edges with both ends
/// free (`free`) that touch a seam vertex or were left by the border rule are queued; every
/// other edge was tried last on the same triangles around it, so it is parked until a collapse
/// changes them.
fn seeds(
    s: &State,
    seam: &[bool],
    border: &[(u32, u32)],
    free: impl Fn(u32) -> bool,
) -> (Vec<Candidate>, HashMap<u32, Vec<u32>>) {
    let border: HashSet<(u32, u32), BuildHasherDefault<KeyHasher>> =
        border.iter().copied().collect();
    let (mut queued, mut parked) = (Vec::new(), HashMap::new());
    for c in all_edges(s) {
        let (a, b) = (c.a, c.b);
        if !free(a) || !free(b) {
            continue;
        }
        if seam[a as usize] || seam[b as usize] || border.contains(&(a.min(b), a.max(b))) {
            queued.push(c);
        } else {
            park(&mut parked, a, b);
        }
    }
    (queued, parked)
}

/// The box of a group's members together (they tile it: `groups`).
fn joint_box(members: &[Done]) -> Block {
    let mut block = members[0].block;
    for m in members {
        for a in 0..3 {
            block.lo[a] = block.lo[a].min(m.block.lo[a]);
            block.hi[a] = block.hi[a].max(m.block.hi[a]);
        }
    }
    block
}

/// A group of blocks (or of groups) welded and simplified as one block of their joint box:
/// the seam vertices inside the box are free now, those on its faces stay locked. Crossings
/// tested against the neighbours only and certified at the end, as for a block; where the
/// certificate finds a pair, the group again from the same welded start with every near
/// triangle tested (no two of its triangles cross: members meet only at shared locked
/// vertices and edges). None when `stop` said yes.
fn simplify_group(
    members: Vec<Done>,
    cls: &Classifier,
    pieces: Option<&Pieces>,
    opts: SimplifyOptions,
    locks: Locks,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<Done> {
    let block = joint_box(&members);
    let target = members.iter().map(|m| m.target).sum();
    let triangles_start = members.iter().map(|m| m.triangles_start).sum();
    let Welded {
        mesh,
        quadric,
        seam,
        border,
        mut stats,
    } = weld(members);
    stats.groups += 1;
    let locked: Vec<bool> = seam
        .iter()
        .zip(&mesh.positions)
        .map(|(&s, &p)| s && block.on_faces(p))
        .collect();
    let locks = locks.in_groups();
    let pass = |crossings| {
        let mut s = State::unfiled(mesh.clone(), Some(quadric.clone()));
        s.crossings = crossings;
        let (queued, parked) = seeds(&s, &seam, &border, |v| !locks || !locked[v as usize]);
        let mut scratch = Scratch::new(cls, pieces, s.tris.len());
        let heap = Queue::new(queued);
        let border = run_block(
            &mut s,
            heap,
            parked,
            &mut scratch,
            (&locked, locks),
            &block,
            &opts,
            target,
            false,
            stop,
        );
        if stop() {
            return Err(true);
        }
        if crossings == Crossings::Neighbours && !s.crossing_free() {
            return Err(false);
        }
        Ok(finish(&s, &locked, border, block, triangles_start, target))
    };
    let mut out = match pass(Crossings::Neighbours) {
        Ok(out) => out,
        Err(true) => return None,
        Err(false) => {
            let mut out = pass(Crossings::Near).ok()?;
            out.stats.blocks_redone += 1;
            out
        }
    };
    stats.add(&out.stats);
    out.stats = stats;
    Some(out)
}

/// How a block's pass runs: its options and share of a target count (0: none), how each step's
/// crossings are tested, and whether its locked vertices are kept (false only in the tests'
/// mutations: the border rule and the weld still read them).
#[derive(Clone, Copy)]
struct Pass {
    opts: SimplifyOptions,
    target: usize,
    crossings: Crossings,
    locks: bool,
}

/// One block's pass: candidates cheapest first, one at a time, none with a locked end, each
/// step's new triangles tested for crossings as `crossings` says. None when the pass tested
/// neighbours only and its result holds a crossing pair ([`State::crossing_free`]).
fn simplify_block(
    patch: Patch,
    block: &Block,
    cls: &Classifier,
    pieces: Option<&Pieces>,
    pass: Pass,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<Done> {
    let Pass {
        opts,
        target,
        crossings,
        locks,
    } = pass;
    let Patch { mesh, locked } = patch;
    let triangles_start = mesh.triangles.len() as u64;
    if mesh.triangles.is_empty() {
        return Some(Done {
            block: *block,
            mesh,
            quadric: Vec::new(),
            locked,
            border: Vec::new(),
            stats: SimplifyStats::default(),
            triangles_start,
            target,
        });
    }
    let mut scratch = Scratch::new(cls, pieces, mesh.triangles.len());
    let (mut s, locked) = coarse_start(&mesh, &locked, block, &mut scratch, &opts, crossings)
        .unwrap_or_else(|| (State::unfiled(mesh, None), locked));
    s.crossings = crossings;
    let free = |c: &Candidate| !locks || (!locked[c.a as usize] && !locked[c.b as usize]);
    let heap = Queue::new(all_edges(&s).into_iter().filter(free).collect());
    let border = run_block(
        &mut s,
        heap,
        HashMap::new(),
        &mut scratch,
        (&locked, locks),
        block,
        &opts,
        target,
        true,
        stop,
    );
    if crossings == Crossings::Neighbours && !s.crossing_free() {
        return None;
    }
    Some(finish(&s, &locked, border, *block, triangles_start, target))
}

/// The collapses of one block's (or group's) pass, one at a time from `heap`, until none is
/// left, `target` triangles are reached or `stop` says yes; with `discs`, the disc patches are
/// remeshed once the collapses that keep the surface are done. No candidate has a `locked` end
/// unless `locks` is false (the tests' mutations); the border rule reads `locked` either way.
/// Returns the edges whose last outcome was the border rule.
#[allow(clippy::too_many_arguments)]
fn run_block(
    s: &mut State,
    mut heap: Queue,
    mut parked: HashMap<u32, Vec<u32>>,
    scratch: &mut Scratch,
    (locked, locks): (&[bool], bool),
    block: &Block,
    opts: &SimplifyOptions,
    target: usize,
    discs: bool,
    stop: &(dyn Fn() -> bool + Sync),
) -> HashSet<(u32, u32), BuildHasherDefault<KeyHasher>> {
    let free = |c: &Candidate| !locks || (!locked[c.a as usize] && !locked[c.b as usize]);
    // Edges whose last outcome was the border rule.
    let mut border: HashSet<(u32, u32), BuildHasherDefault<KeyHasher>> = HashSet::default();
    // The border rule, before the costly checks: every moved triangle's vertex locked or
    // strictly inside the block's box.
    let in_box = |moved: &[([u32; 3], [DVec3; 3])]| {
        let off_box = moved.iter().any(|(ids, q)| {
            ids.iter()
                .zip(q)
                .any(|(&x, &p)| !locked[x as usize] && !block.strictly_holds(p))
        });
        if off_box {
            Err(Reject::Border)
        } else {
            Ok(())
        }
    };
    let mut tried = 0u32;
    // Disc patches are remeshed once, when the collapses that keep the surface are done (the
    // cost-0 FIFO first empties: docs/design.md, "Disc patches").
    let mut discs_done = !discs;
    loop {
        if !discs_done && heap.zero.is_empty() {
            discs_done = true;
            let stopped = discs::remesh_discs(
                s,
                &mut heap,
                &mut parked,
                scratch,
                opts,
                locked,
                target,
                in_box,
                stop,
            );
            if stopped {
                break;
            }
        }
        let Some(c) = heap.pop() else { break };
        if !s.is_current(&c) || !free(&c) {
            continue;
        }
        tried = tried.wrapping_add(1);
        if tried % 4096 == 0 && stop() {
            break;
        }
        // A collapse that flips a triangle is refused before its region is copied: half of a
        // block's candidates on the gear, each 12 µs through the region's checks against
        // 0.4 µs here (docs/perf-log.md, "Flips refused on the live mesh").
        let v = s.best_target(c.a, c.b).1;
        let outcome = if s.flips(c.a, c.b, v) {
            Err(Reject::Flip)
        } else {
            s.region(c.a, c.b).check_moving(scratch, opts, v, in_box)
        };
        let outcome = outcome.and_then(|plan| {
            if !plan.in_plane {
                s.file();
                s.crosses_nothing(&mut scratch.crossing, &plan)?;
            }
            Ok(plan)
        });
        let key = (c.a.min(c.b), c.a.max(c.b));
        if matches!(outcome, Err(Reject::Border)) {
            border.insert(key);
        } else {
            border.remove(&key);
        }
        if s.commit_batch(
            &mut heap,
            &mut parked,
            vec![((c.a, c.b), outcome)],
            Vec::new(),
            target,
        ) {
            break;
        }
    }
    border
}

/// A pass's result as its live mesh (compacted), with each vertex's quadric and lock and the
/// border rule's edges carried over.
fn finish(
    s: &State,
    locked: &[bool],
    border: HashSet<(u32, u32), BuildHasherDefault<KeyHasher>>,
    block: Block,
    triangles_start: u64,
    target: usize,
) -> Done {
    let (mesh, map) = s.compact_with_map();
    let mut quadric = vec![Quadric::default(); mesh.positions.len()];
    let mut kept_locked = vec![false; mesh.positions.len()];
    for (old, &new) in map.iter().enumerate() {
        if new != u32::MAX {
            quadric[new as usize] = s.quadric[old];
            kept_locked[new as usize] = locked[old];
        }
    }
    let mut border: Vec<(u32, u32)> = border
        .into_iter()
        .filter_map(|(a, b)| {
            let (a, b) = (map[a as usize], map[b as usize]);
            (a != u32::MAX && b != u32::MAX).then_some((a.min(b), a.max(b)))
        })
        .collect();
    border.sort_unstable();
    Done {
        block,
        mesh,
        quadric,
        locked: kept_locked,
        border,
        stats: s.stats,
        triangles_start,
        target,
    }
}

/// A block's start coarsened by clusters (`clusters`), as a state (hash not filed) with its
/// vertices' locks; None when no cluster is taken. Crossings: a pass that tests neighbours only
/// is certified at its end, coarse start included, and starts from the clusters' levels; for a
/// pass that tests every near triangle the start itself must hold no conflicting pair, so it
/// starts from one level, the clusters of the triangles in a conflicting pair are left fine
/// and the start made again (a few times at most, else the pass starts fine).
fn coarse_start(
    mesh: &Mesh,
    locked: &[bool],
    block: &Block,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
    crossings: Crossings,
) -> Option<(State, Vec<bool>)> {
    /// Starts made again for conflicting pairs before the pass starts fine.
    const TRIES: usize = 4;
    let state = |c: clusters::Coarse| {
        let mut s = State::unfiled(c.mesh, Some(c.quadric));
        (s.stats.clusters, s.stats.cluster_vertices) = (c.clusters, c.removed);
        (s, c.locked)
    };
    if crossings == Crossings::Neighbours {
        return clusters::coarsen_levels(mesh, locked, block, scratch, opts)
            .ok()
            .map(state);
    }
    let mut vetoed: Vec<u32> = Vec::new();
    for _ in 0..TRIES {
        let mut c = clusters::coarsen(mesh, locked, &vetoed, block, scratch, opts).ok()?;
        let cluster = std::mem::take(&mut c.cluster);
        let (s, locked) = state(c);
        let pairs = s.conflicts(false);
        if pairs.is_empty() {
            return Some((s, locked));
        }
        let before = vetoed.len();
        for (t, u) in pairs {
            for x in s.tris[t as usize].iter().chain(&s.tris[u as usize]) {
                let k = cluster[*x as usize];
                if k != u32::MAX {
                    vetoed.push(k);
                }
            }
        }
        vetoed.sort_unstable();
        vetoed.dedup();
        if vetoed.len() == before {
            return None;
        }
    }
    None
}

/// Meshes of blocks (or groups) welded into one.
struct Welded {
    mesh: Mesh,
    quadric: Vec<Quadric>,
    /// Whether each vertex was locked in its block (or group): a seam vertex.
    seam: Vec<bool>,
    /// The members' edges left by the border rule.
    border: Vec<(u32, u32)>,
    /// The members' stats, summed.
    stats: SimplifyStats,
}

/// `done` as one mesh, welded at the members' locked vertices (which sit on lattice corners),
/// in the given order.
fn weld(done: Vec<Done>) -> Welded {
    let mut mesh = Mesh::default();
    let (mut quadric, mut seam, mut border) = (Vec::new(), Vec::new(), Vec::new());
    let mut stats = SimplifyStats::default();
    let mut at: HashMap<u64, u32, BuildHasherDefault<KeyHasher>> = HashMap::default();
    for d in done {
        stats.add(&d.stats);
        let ids: Vec<u32> = (0..d.mesh.positions.len())
            .map(|v| {
                let p = d.mesh.positions[v];
                let fresh = mesh.positions.len() as u32;
                let id = if d.locked[v] {
                    let key = pack_cell(p.to_array().map(|x| x as i64));
                    *at.entry(key).or_insert(fresh)
                } else {
                    fresh
                };
                if id == fresh {
                    mesh.positions.push(p);
                    quadric.push(d.quadric[v]);
                    seam.push(d.locked[v]);
                } else {
                    quadric[id as usize] = quadric[id as usize].add(&d.quadric[v]);
                }
                id
            })
            .collect();
        mesh.triangles
            .extend(d.mesh.triangles.iter().map(|t| t.map(|v| ids[v as usize])));
        border.extend(d.border.iter().map(|&(a, b)| {
            let (a, b) = (ids[a as usize], ids[b as usize]);
            (a.min(b), a.max(b))
        }));
    }
    Welded {
        mesh,
        quadric,
        seam,
        border,
        stats,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::test_support::random;
    use crate::mesh::manifold::Joined;
    use crate::simplify::band::HALF_DIAGONAL;
    use crate::simplify::clusters::tests::{deep_and_far, opts, places};
    use crate::simplify::tests::{deep, in_volume, winding_number};
    use crate::verify::bvh::Bvh;

    /// Rough random voxel sets cut into small blocks (up to three levels of groups): the
    /// welded, simplified mesh is a closed 2-manifold whatever the block size. (What the locks
    /// keep: `seam_vertices_stay_where_they_are`.)
    #[test]
    fn seams_weld_into_a_manifold() {
        assert!(opts().tolerance.outside > HALF_DIAGONAL);
        for seed in 0..3 {
            let cls = random([18, 16, 14], seed);
            let joined = Joined::new(&cls);
            let start = crate::mesh::extract::extract(&joined).triangles.len() as u64;
            for size in [2, 5, 7, 64] {
                let out = simplify_boundary(&joined, &cls, None, opts(), size, &|| false).unwrap();
                assert_eq!(out.triangles_start, start);
                let defects = out.mesh.manifold_defects();
                assert!(
                    defects.is_manifold() && out.mesh.unpaired_edges().is_empty(),
                    "seed {seed}, blocks of {size}: {defects:?}"
                );
                assert!(out.mesh.triangles.len() * 3 < start as usize, "seed {seed}");
            }
        }
    }

    /// The locked vertices' positions of `mesh` (their coordinates' bits: exact).
    fn locked_at(mesh: &Mesh, locked: &[bool], keep: impl Fn(DVec3) -> bool) -> Vec<[u64; 3]> {
        let mut out: Vec<[u64; 3]> = (0..locked.len())
            .filter(|&v| locked[v] && keep(mesh.positions[v]))
            .map(|v| mesh.positions[v].to_array().map(f64::to_bits))
            .collect();
        out.sort_unstable();
        out
    }

    /// Every vertex a block locks (on its patch's open edges) comes out of its pass where it
    /// was, and every seam vertex on a group's own faces out of the group's pass. With the
    /// locks ignored in the groups' passes (the border rule and the weld still reading them),
    /// some move or vanish and the same check fails; ignored in the blocks' passes, the
    /// topology check still refuses every collapse at an open edge.
    #[test]
    fn seam_vertices_stay_where_they_are() {
        let mut moved = [0, 0];
        for seed in 0..3 {
            let cls = random([18, 16, 14], seed);
            let joined = Joined::new(&cls);
            for locks in [Locks::Honour, Locks::Ignore, Locks::IgnoreInGroups] {
                let pass = Pass {
                    opts: opts(),
                    target: 0,
                    crossings: Crossings::Near,
                    locks: locks.in_blocks(),
                };
                let mut lost = [0, 0];
                let done: Vec<Done> = blocks([18, 16, 14], 3)
                    .iter()
                    .map(|b| {
                        let patch = extract_block(&joined, b);
                        let before = locked_at(&patch.mesh, &patch.locked, |_| true);
                        let d = simplify_block(patch, b, &cls, None, pass, &|| false).unwrap();
                        let after = locked_at(&d.mesh, &d.locked, |_| true);
                        lost[0] += before
                            .iter()
                            .filter(|p| after.binary_search(p).is_err())
                            .count();
                        d
                    })
                    .collect();
                for members in groups(done, 6) {
                    let block = joint_box(&members);
                    let mut before: Vec<[u64; 3]> = members
                        .iter()
                        .flat_map(|m| locked_at(&m.mesh, &m.locked, |p| block.on_faces(p)))
                        .collect();
                    before.sort_unstable();
                    before.dedup();
                    let g = simplify_group(members, &cls, None, opts(), locks, &|| false).unwrap();
                    let after = locked_at(&g.mesh, &g.locked, |_| true);
                    lost[1] += before
                        .iter()
                        .filter(|p| after.binary_search(p).is_err())
                        .count();
                }
                match locks {
                    Locks::Honour => assert_eq!(lost, [0, 0], "seed {seed}"),
                    Locks::Ignore => moved[0] += lost[0],
                    Locks::IgnoreInGroups => moved[1] += lost[1],
                }
            }
        }
        // A block's locked vertices lie on its patch's open edges, whose open fans the
        // topology check refuses anyway: the lock is a second guard there, and nothing moves.
        assert_eq!(moved[0], 0, "a block moved a vertex of an open edge");
        assert!(moved[1] > 0, "moved seam vertices went unnoticed");
    }

    /// A block's pass, a group's and the seam pass test each step's new triangles against
    /// their neighbours only and are certified at their end. On these rough sets (found by a
    /// search over seeds and block sizes) a block's first pass (the first two) or the seam
    /// pass's (the others) ends with a crossing pair: the certificate must see it and the pass
    /// be done again testing every near triangle, so that verify's own check finds no crossing
    /// pair in the output. Keeping the first pass's result leaves crossings here (checked by
    /// mutation for both).
    #[test]
    fn a_pass_that_ends_crossed_is_done_again() {
        for (seed, size, dims) in [
            (1, 64, [18, 16, 14]),
            (16, 7, [18, 16, 14]),
            (8, 7, [18, 16, 14]),
            (44, 7, [12, 12, 12]),
            (17, 5, [18, 16, 14]),
        ] {
            let cls = random(dims, seed);
            let joined = Joined::new(&cls);
            let out = simplify_boundary(&joined, &cls, None, opts(), size, &|| false).unwrap();
            assert!(
                out.stats.blocks_redone >= 1,
                "seed {seed}, blocks of {size}: no pass ended crossed"
            );
            let m = &out.mesh;
            let tris: Vec<[DVec3; 3]> = m
                .triangles
                .iter()
                .map(|t| t.map(|v| m.positions[v as usize]))
                .collect();
            let (health, _) = crate::verify::health::check(&tris, &Bvh::build(tris.clone(), 8));
            assert_eq!(
                health.self_intersecting_pairs, 0,
                "seed {seed}, blocks of {size}: {:?}",
                health.self_intersection_examples
            );
        }
    }

    /// Balls cut into small blocks, smooth enough for many discs to be remeshed at once
    /// (`discs`): the welded mesh is a closed 2-manifold, every point sampled on it lies in the
    /// tolerance volume, and it winds once around every voxel centre farther than the sweep
    /// radius from the outside (what no step may sweep over). With the discs' band check
    /// skipped, points of the output leave T here.
    #[test]
    fn discs_at_block_borders_weld_into_a_manifold() {
        let mut discs = 0;
        for (k, r) in [7.3f32, 8.6, 9.2].into_iter().enumerate() {
            let c = [11.0 + 0.3 * k as f32, 10.6, 10.2];
            let cls = crate::mesh::classify::test_support::ball([24, 24, 24], c, r);
            let joined = Joined::new(&cls);
            for size in [5, 7, 9] {
                let out = simplify_boundary(&joined, &cls, None, opts(), size, &|| false).unwrap();
                let defects = out.mesh.manifold_defects();
                assert!(
                    defects.is_manifold() && out.mesh.unpaired_edges().is_empty(),
                    "ball {r}, blocks of {size}: {defects:?}"
                );
                discs += out.stats.discs;
                let m = &out.mesh;
                for t in &m.triangles {
                    let p = t.map(|v| m.positions[v as usize]);
                    for (a, b) in [(0.0, 0.0), (1.0 / 3.0, 1.0 / 3.0), (0.5, 0.25), (0.1, 0.6)] {
                        let x = p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b;
                        assert!(
                            in_volume(&cls, x, opts()),
                            "ball {r}, blocks of {size}: {x} out of T"
                        );
                    }
                }
                for i in (0..24).step_by(2) {
                    for j in 0..24 {
                        for k in 0..24 {
                            if deep(&cls, [i, j, k], opts()) {
                                let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                                let w = winding_number(m, c);
                                assert!((w - 1.0).abs() < 1e-6, "ball {r}: winding {w} at {c}");
                            }
                        }
                    }
                }
            }
        }
        assert!(discs > 100, "only {discs} discs remeshed");
    }

    /// Rough random sets and a ball cut into blocks, with every voxel centre inside and out of
    /// T as a piece of "the swept volume", so that the blocks start from clusters (`clusters`):
    /// the welded output is a closed 2-manifold without crossing pairs (verify's own check),
    /// winds once around every such centre and not at all around the outside's centres out of
    /// T (no pocket filled).
    #[test]
    fn blocks_started_from_clusters_stay_sound() {
        let mut clusters = 0;
        let sets = [random([22, 20, 18], 4), random([22, 20, 18], 9)]
            .into_iter()
            .chain([crate::mesh::classify::test_support::ball(
                [22, 20, 18],
                [11.2, 10.3, 9.1],
                7.4,
            )]);
        for (n, cls) in sets.enumerate() {
            let joined = Joined::new(&cls);
            let (inside, outside) = deep_and_far(&cls, [22, 20, 18]);
            let pieces = Pieces::from_points(inside.iter().map(|&p| [p, p]).collect());
            for size in [8, 13, 64] {
                let out = simplify_boundary(&joined, &cls, Some(&pieces), opts(), size, &|| false)
                    .unwrap();
                clusters += out.stats.clusters;
                let m = &out.mesh;
                let defects = m.manifold_defects();
                assert!(
                    defects.is_manifold() && m.unpaired_edges().is_empty(),
                    "set {n}, blocks of {size}: {defects:?}"
                );
                let tris = places(m);
                let (health, _) = crate::verify::health::check(&tris, &Bvh::build(tris.clone(), 8));
                assert_eq!(
                    health.self_intersecting_pairs, 0,
                    "set {n}, blocks of {size}"
                );
                for &c in &inside {
                    let w = winding_number(m, c);
                    assert!((w - 1.0).abs() < 1e-6, "set {n}: winding {w} at {c}");
                }
                for &c in &outside {
                    let w = winding_number(m, c);
                    assert!(w.abs() < 1e-6, "set {n}: winding {w} at {c}");
                }
            }
        }
        assert!(clusters > 150, "only {clusters} clusters taken");
    }

    /// A pass that tests every near triangle keeps its coarse start only without a conflicting
    /// pair: on random piles of boxes (each pixel's depth range spans the boxes it meets) whose
    /// clusters alone give such pairs, the start made again without their clusters holds none
    /// and still has clusters.
    #[test]
    fn a_near_pass_starts_from_clusters_without_conflicts() {
        let (mut conflicted, mut kept) = (0, 0);
        for seed in 0..200 {
            let mut rng = fastrand::Rng::with_seed(seed);
            let boxes: Vec<([f32; 3], [f32; 3])> = (0..6)
                .map(|_| {
                    let lo = [0; 3].map(|_| rng.u32(2..12) as f32);
                    let hi = lo.map(|x| x + rng.u32(1..7) as f32);
                    (lo, hi)
                })
                .collect();
            let cls = crate::mesh::classify::test_support::from_ranges([20, 18, 16], |a, u, v| {
                let (cu, rv) = (crate::depth::COLUMN_AXIS[a], crate::depth::ROW_AXIS[a]);
                let hits: Vec<_> = boxes
                    .iter()
                    .filter(|(lo, hi)| u > lo[cu] && u < hi[cu] && v > lo[rv] && v < hi[rv])
                    .collect();
                let lo = hits.iter().map(|b| b.0[a]).fold(f32::MAX, f32::min);
                let hi = hits.iter().map(|b| b.1[a]).fold(f32::MIN, f32::max);
                (!hits.is_empty()).then_some((lo + 0.1, hi - 0.1))
            });
            let fine = crate::mesh::extract::extract(&Joined::new(&cls));
            let pieces = Pieces::from_points(Vec::new());
            let block = Block {
                lo: [0; 3],
                hi: [20, 18, 16],
            };
            let locked = vec![false; fine.positions.len()];
            let mut scratch = Scratch::new(&cls, Some(&pieces), fine.triangles.len());
            let first = clusters::coarsen(&fine, &locked, &[], &block, &mut scratch, &opts());
            let Ok(first) = first else { continue };
            if State::unfiled(first.mesh, None).crossing_free() {
                continue;
            }
            conflicted += 1;
            let near = coarse_start(
                &fine,
                &locked,
                &block,
                &mut scratch,
                &opts(),
                Crossings::Near,
            );
            if let Some((s, _)) = near {
                assert!(s.conflicts(false).is_empty(), "seed {seed}");
                assert!(s.stats.clusters > 0);
                kept += 1;
            }
        }
        assert!(
            conflicted > 0 && kept > 0,
            "{conflicted} conflicted, {kept} kept"
        );
    }

    /// The classifier of boxes (lo, hi) no two of which share a pixel of any image: each ray
    /// through a box holds its span, shrunk by 0.1.
    fn from_boxes(dims: [u32; 3], boxes: &[([f32; 3], [f32; 3])]) -> Classifier {
        crate::mesh::classify::test_support::from_ranges(dims, |a, u, v| {
            let (cu, rv) = (crate::depth::COLUMN_AXIS[a], crate::depth::ROW_AXIS[a]);
            boxes.iter().find_map(|(lo, hi)| {
                (u > lo[cu] && u < hi[cu] && v > lo[rv] && v < hi[rv])
                    .then_some((lo[a] + 0.1, hi[a] - 0.1))
            })
        })
    }

    /// Small separate blobs (2 to 4 voxels wide), each with the points farther than the tolerance
    /// radius from every outside centre as a piece of "the swept volume" (no live triangle can
    /// reach them): the output winds once around every such point.
    #[test]
    fn the_output_encloses_every_piece() {
        let mut rng = fastrand::Rng::with_seed(5);
        let mut deep = 0;
        for seed in 0..12 {
            // Blobs along the diagonal, so that no two share a pixel of any image.
            let blobs: Vec<([f32; 3], [f32; 3])> = (0..4)
                .map(|i| {
                    let at = 2.0 + 6.0 * i as f32;
                    let lo = [0, 1, 2].map(|_| at + rng.u32(0..2) as f32);
                    let hi = lo.map(|x| x + rng.u32(2..5) as f32);
                    (lo, hi)
                })
                .collect();
            let cls = from_boxes([28, 28, 28], &blobs);
            let joined = Joined::new(&cls);
            let mut points = Vec::new();
            let mut prox = crate::simplify::band::Proximity::new(&cls);
            for x in 0..56 {
                for y in 0..56 {
                    for z in 0..56 {
                        let p = DVec3::new(x as f64, y as f64, z as f64) * 0.5 + 0.25;
                        let near = prox.nearest(p);
                        let (d_out, _) = near.centre_distances();
                        if near.inside && d_out > opts().tolerance.outside + 0.01 {
                            points.push([p, p]);
                        }
                    }
                }
            }
            deep += points.len();
            let pieces = Pieces::from_points(points.clone());
            let out =
                simplify_boundary(&joined, &cls, Some(&pieces), opts(), 8, &|| false).unwrap();
            let tris: Vec<[DVec3; 3]> = out
                .mesh
                .triangles
                .iter()
                .map(|t| t.map(|v| out.mesh.positions[v as usize]))
                .collect();
            for [p, _] in &points {
                let w = super::super::pieces::winding(&tris, *p);
                assert!((w - 1.0).abs() < 1e-6, "seed {seed}: winding {w} at {p}");
            }
        }
        assert!(deep > 100, "only {deep} deep points");
    }

    /// A grid whose surface lies almost all in one block (boxes in its low-x end): that block
    /// is split ([`split_dominant`]), and the output is still a closed 2-manifold that winds
    /// once around every point deep inside and not around any far outside, the same on one
    /// thread and on four.
    #[test]
    fn a_block_holding_most_of_the_surface_is_split_and_stays_sound() {
        let mut rng = fastrand::Rng::with_seed(11);
        for seed in 0..3 {
            // Boxes along the diagonal of the grid's low-x end, so that no two share a pixel
            // of any image.
            let boxes: Vec<([f32; 3], [f32; 3])> = (0..4)
                .map(|i| {
                    let lo = [
                        2.0 + 14.0 * i as f32,
                        2.0 + 9.0 * i as f32,
                        2.0 + 9.0 * i as f32,
                    ];
                    let hi = [
                        lo[0] + rng.u32(6..11) as f32,
                        lo[1] + rng.u32(5..8) as f32,
                        lo[2] + rng.u32(5..8) as f32,
                    ];
                    (lo, hi)
                })
                .collect();
            let dims = [100, 40, 40];
            let cls = from_boxes(dims, &boxes);
            let joined = Joined::new(&cls);
            let list = blocks(dims.map(|n| n as usize), 64);
            let cost: Vec<usize> = list.iter().map(|b| faces_estimate(&joined, b)).collect();
            let (split, _) = split_dominant(list.clone(), cost, SPLIT_AT_LEAST, |b| {
                faces_estimate(&joined, b)
            });
            assert!(split.len() > list.len(), "seed {seed}: no block split");
            let (deep, far) = deep_and_far(&cls, dims);
            assert!(deep.len() > 100, "seed {seed}: {} deep points", deep.len());
            let pieces = Pieces::from_points(deep.iter().map(|&p| [p, p]).collect());
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| {
                        simplify_boundary(&joined, &cls, Some(&pieces), opts(), 64, &|| false)
                            .unwrap()
                    })
            };
            let (one, four) = (run(1), run(4));
            assert_eq!(one.mesh, four.mesh, "seed {seed}");
            let defects = one.mesh.manifold_defects();
            assert!(
                defects.is_manifold() && one.mesh.unpaired_edges().is_empty(),
                "seed {seed}: {defects:?}"
            );
            for p in &deep {
                let w = winding_number(&one.mesh, *p);
                assert!((w - 1.0).abs() < 1e-6, "seed {seed}: winding {w} at {p}");
            }
            for p in &far {
                let w = winding_number(&one.mesh, *p);
                assert!(
                    w.abs() < 1e-6,
                    "seed {seed}: winding {w} at {p} (far outside)"
                );
            }
        }
    }

    /// Jobs run once each, costliest first on one thread, and their results come back in
    /// index order on any number of threads.
    #[test]
    fn largest_first_runs_each_job_once_in_cost_order() {
        let cost = [3, 9, 1, 9, 0, 5];
        for threads in [1, 3] {
            let order = Mutex::new(Vec::new());
            let out = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    largest_first(&cost, |i| {
                        order.lock().unwrap().push(i);
                        10 * i
                    })
                });
            assert_eq!(out, vec![0, 10, 20, 30, 40, 50]);
            let mut order = order.into_inner().unwrap();
            if threads == 1 {
                assert_eq!(order, vec![1, 3, 5, 0, 2, 4]);
            }
            order.sort_unstable();
            assert_eq!(order, vec![0, 1, 2, 3, 4, 5]);
        }
    }

    #[test]
    fn the_memory_estimate_knows_the_block_size() {
        assert_eq!(BLOCK_VOXELS, crate::input::memory::BLOCK_VOXELS);
    }

    /// The same input gives the same mesh on one thread and on four, also where a block is
    /// done again (the second case: see `a_block_whose_pass_ends_crossed_is_done_again`).
    #[test]
    fn the_result_does_not_depend_on_the_thread_count() {
        for (dims, seed, size) in [([20, 18, 16], 7, 6), ([18, 16, 14], 26, 7)] {
            let cls = random(dims, seed);
            let joined = Joined::new(&cls);
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| {
                        simplify_boundary(&joined, &cls, None, opts(), size, &|| false).unwrap()
                    })
            };
            let (one, four) = (run(1), run(4));
            assert!(one.stats.groups > 0, "seed {seed}: no group simplified");
            assert_eq!(one.mesh, four.mesh, "seed {seed}");
            assert_eq!(one.stats, four.stats, "seed {seed}");
        }
    }
}
