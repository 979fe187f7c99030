//! A block's start coarsened by vertex clustering, each level checked once as one step
//! (docs/design.md, "A coarse start by clusters"). The free vertices in each cell of the level
//! (8³, then 4³, then 2³ voxels: [`LEVELS`]), joined by the patch's edges inside the cell,
//! become one vertex at their mean; every triangle is mapped, and those with two corners in one
//! cluster vanish. Each level clusters the mesh the one before left. Most of a block's
//! collapses (the in-plane ones and the first moving levels) are done this way at once, each
//! new triangle checked once.
//!
//! What keeps it sound, the checks of a collapse applied to the whole step, on a patch whose
//! triangles are faces of the joined voxels or lie in T (the fine start, and every level's
//! result again):
//! - tolerance: every moved triangle passes the band test (`band::Proximity::triangle_within`);
//! - border: every moved triangle's vertex is locked or strictly inside the block's box, and
//!   clusters hold no locked vertex, so the patches still fit and stay in their boxes;
//! - sweep: the triangles moved (O: faces of outside voxels or triangles in T) and the new ones
//!   (N, in T) both miss the swept volume, so the winding number of O - N is constant on each
//!   of its pieces; the step is taken only when it is zero at each
//!   ([`super::pieces::Pieces::swallowed_by_map`], summed over prisms), so no point of it is
//!   lost. Without the pieces, or with too many in the step's box ([`SWEEP_BUDGET`]), the level
//!   declines;
//! - topology: each cluster spans a contractible part of the surface (connected, Euler
//!   characteristic 1); after mapping, every vertex a moved triangle touches has one fan (so
//!   every edge at a cluster has one triangle each way); and the patch's Euler characteristic is
//!   unchanged. A map of a surface that keeps orientation never raises the genus and never
//!   splits or joins components here (a cluster is connected), so the same characteristic means
//!   the same surface, a closed 2-manifold once the blocks are welded;
//! - self-intersection: not here; by the block's certificate at the end of a pass that tests
//!   neighbours only, and for a pass that tests every near triangle by a check of the start
//!   itself (`blocked::coarse_start`).
//!
//! A cluster whose triangles fail a local check is left fine and the checks run again on what
//! changed, until none fails; a failed sweep or Euler check declines the whole level (the mesh
//! of the level before stands, the fine patch for the first). The result depends only on the
//! patch: cells, clusters and ids follow vertex order.

use std::collections::HashSet;
use std::hash::BuildHasherDefault;

use glam::DVec3;

use super::band::KeyHasher;
use super::pieces::Mapped;
use super::quadric::Quadric;
use super::region::Scratch;
use super::SimplifyOptions;
use crate::mesh::blocks::Block;
use crate::mesh::Mesh;
use crate::union_find::UnionFind;

/// Lattice points along each edge of a cell (voxels) of a start of one level, the start of a
/// pass whose clusters may be vetoed ([`coarsen`]). At 4 a surface of every fourth voxel put
/// 99% of its triangles in T at n = 512 and 1500 (docs/perf-log.md, "A coarse start by surface
/// nets"); at 8, 89-93%.
const CELL: f64 = 4.0;

/// The cells of [`coarsen_levels`], coarsest first (voxels): each level clusters the mesh the
/// one before left, so where cells of 8 fail their check, cells of 4 and then 2 take what
/// they can (docs/perf-log.md, "Clusters in three levels").
const LEVELS: [f64; 3] = [8.0, 4.0, 2.0];

/// Most solid angles (pieces in the box times triangles of O and N) the sweep check of one step
/// may cost, about a tenth of a second.
const SWEEP_BUDGET: usize = 20_000_000;

/// Least twice-area of a moved triangle, voxel²: slivers are left fine.
const MIN_AREA2: f64 = 1e-6;

/// A block's start after clustering: the mesh, which vertices are locked, each vertex's
/// quadric (the planes of the fine triangles it stands for), and how many clusters were taken
/// and how many vertices they removed.
pub(super) struct Coarse {
    pub(super) mesh: Mesh,
    pub(super) locked: Vec<bool>,
    pub(super) quadric: Vec<Quadric>,
    pub(super) clusters: u64,
    pub(super) removed: u64,
    /// Each vertex's cluster (an id [`coarsen`] takes in `vetoed`), u32::MAX for a vertex no
    /// cluster made. From [`coarsen_levels`]: the clusters of the last level that took any,
    /// numbered on that level's input, so not ids to veto with.
    pub(super) cluster: Vec<u32>,
}

/// Why a block's start stayed fine.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum Declined {
    /// No cluster of two or more free vertices passed the checks.
    Nothing,
    /// The swept volume's pieces are not known.
    NoPieces,
    /// The step would change the winding number at a piece of the swept volume.
    Sweep,
    /// So many pieces lie in the step's box that their winding numbers would cost more than
    /// [`SWEEP_BUDGET`] (many rows at a small resolution): the collapses check them instead.
    SweepCost,
    /// The patch's Euler characteristic would change.
    Euler,
}

/// The clusters of `mesh`'s free vertices in cells of `size`³: each vertex's cluster
/// (u32::MAX for none) and each cluster's members in vertex order. Only clusters of two or
/// more are kept.
fn clusters(mesh: &Mesh, locked: &[bool], size: f64) -> (Vec<u32>, Vec<Vec<u32>>) {
    let n = mesh.positions.len();
    // Each free vertex's cell, packed; None if locked. (A function of the position alone:
    // lattice points are exact, and a former cluster's mean lies in one cell like any point.)
    let cell: Vec<Option<[i64; 3]>> = (0..n)
        .map(|v| {
            let c = (mesh.positions[v] / size).floor();
            (!locked[v]).then_some([c.x as i64, c.y as i64, c.z as i64])
        })
        .collect();
    let mut uf = UnionFind::new(n);
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if cell[a as usize].is_some() && cell[a as usize] == cell[b as usize] {
                uf.join(a, b);
            }
        }
    }
    // A root is its set's smallest id, so clusters are numbered in the order of their first
    // member.
    let mut members_of = vec![0u32; n];
    for v in 0..n as u32 {
        members_of[uf.find(v) as usize] += 1;
    }
    let mut id = vec![u32::MAX; n];
    let mut members: Vec<Vec<u32>> = Vec::new();
    for v in 0..n as u32 {
        let root = uf.find(v);
        if members_of[root as usize] < 2 {
            continue;
        }
        if root == v {
            id[v as usize] = members.len() as u32;
            members.push(Vec::new());
        }
        let c = id[root as usize];
        id[v as usize] = c;
        members[c as usize].push(v);
    }
    (id, members)
}

/// Whether the edges and triangles among each cluster's members form a contractible set
/// (connected by construction; Euler characteristic 1), per cluster.
fn contractible<'s>(
    mesh: &Mesh,
    cluster: &[u32],
    count: usize,
    star: impl Fn(u32) -> &'s [u32],
) -> Vec<bool> {
    let mut chi: Vec<i64> = vec![0; count];
    for t in &mesh.triangles {
        let c = cluster[t[0] as usize];
        if c != u32::MAX && t.iter().all(|&x| cluster[x as usize] == c) {
            chi[c as usize] += 1;
        }
    }
    // Vertices, less each edge once: at its lower end, its distinct higher ends in the cluster.
    let mut ends: Vec<u32> = Vec::new();
    for (a, &c) in cluster.iter().enumerate() {
        if c == u32::MAX {
            continue;
        }
        let a = a as u32;
        ends.clear();
        for &t in star(a) {
            ends.extend(
                mesh.triangles[t as usize]
                    .iter()
                    .filter(|&&b| b > a && cluster[b as usize] == c),
            );
        }
        ends.sort_unstable();
        ends.dedup();
        chi[c as usize] += 1 - ends.len() as i64;
    }
    chi.iter().map(|&x| x == 1).collect()
}

/// Whether the directed link edges around one vertex form one fan: a single cycle, or for a
/// vertex on the patch's open edges (`open`) a single path.
fn one_fan(link: &mut [(u32, u32)], open: bool) -> bool {
    if link.is_empty() || (!open && link.len() < 3) {
        return false;
    }
    link.sort_unstable();
    if link.windows(2).any(|w| w[0].0 == w[1].0) {
        return false;
    }
    // The walk starts where no edge ends (a path), else anywhere (a cycle).
    let mut ends: Vec<u32> = link.iter().map(|e| e.1).collect();
    ends.sort_unstable();
    if ends.windows(2).any(|w| w[0] == w[1]) {
        return false;
    }
    let start = link
        .iter()
        .map(|e| e.0)
        .find(|x| ends.binary_search(x).is_err());
    let first = match (start, open) {
        (Some(s), true) => s,
        (None, false) => link[0].0,
        _ => return false,
    };
    let mut at = first;
    for step in 1..=link.len() {
        let Ok(k) = link.binary_search_by_key(&at, |e| e.0) else {
            return false;
        };
        at = link[k].1;
        if at == first || (open && step == link.len()) {
            return step == link.len() && (open != (at == first));
        }
    }
    false
}

/// `mesh`'s start coarsened by one level of clusters (cells of [`CELL`]) where every check
/// passes (module docs), none of the clusters `vetoed` (ids as [`Coarse::cluster`] gives
/// them); the reason when it stays fine.
pub(super) fn coarsen(
    mesh: &Mesh,
    locked: &[bool],
    vetoed: &[u32],
    block: &Block,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
) -> Result<Coarse, Declined> {
    coarsen_in(mesh, locked, None, vetoed, CELL, block, scratch, opts)
}

/// `mesh`'s start coarsened by the clusters of each of [`LEVELS`] in turn, each level a step
/// checked as [`coarsen`]'s (the tolerance, border, sweep and topology checks apply to the
/// mesh the level before left, which they hold for as the fine start does). The quadrics add
/// up the fine triangles' planes through the levels. [`Coarse::cluster`] gives the last
/// level's clusters. The first level's reason when no level takes any cluster.
pub(super) fn coarsen_levels(
    mesh: &Mesh,
    locked: &[bool],
    block: &Block,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
) -> Result<Coarse, Declined> {
    let mut done: Option<Coarse> = None;
    let mut first_reason = None;
    for size in LEVELS {
        let step = match &done {
            None => coarsen_in(mesh, locked, None, &[], size, block, scratch, opts),
            Some(c) => {
                let quadric = Some(c.quadric.as_slice());
                coarsen_in(&c.mesh, &c.locked, quadric, &[], size, block, scratch, opts)
            }
        };
        match step {
            Ok(mut c) => {
                if let Some(before) = &done {
                    c.clusters += before.clusters;
                    c.removed += before.removed;
                }
                done = Some(c);
            }
            Err(why) => {
                first_reason.get_or_insert(why);
            }
        }
    }
    done.ok_or_else(|| first_reason.expect("at least one level"))
}

/// One level of clusters: [`coarsen`] in cells of `size`, the vertices' quadrics `quadric`
/// (None: the planes of `mesh`'s own triangles, for a fine start).
#[allow(clippy::too_many_arguments)]
fn coarsen_in(
    mesh: &Mesh,
    locked: &[bool],
    quadric: Option<&[Quadric]>,
    vetoed: &[u32],
    size: f64,
    block: &Block,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
) -> Result<Coarse, Declined> {
    let Some(pieces) = scratch.pieces else {
        return Err(Declined::NoPieces);
    };
    let n = mesh.positions.len();
    let (cluster, members) = clusters(mesh, locked, size);
    // Each fine vertex's triangles (offsets into one list).
    let mut first = vec![0u32; n + 1];
    for &v in mesh.triangles.iter().flatten() {
        first[v as usize + 1] += 1;
    }
    for v in 0..n {
        first[v + 1] += first[v];
    }
    let mut star = vec![0u32; 3 * mesh.triangles.len()];
    let mut at = first.clone();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &v in tri {
            star[at[v as usize] as usize] = t as u32;
            at[v as usize] += 1;
        }
    }
    let star = |v: u32| &star[first[v as usize] as usize..first[v as usize + 1] as usize];
    let mut active = contractible(mesh, &cluster, members.len(), star);
    for &c in vetoed {
        active[c as usize] = false;
    }
    let point: Vec<DVec3> = members
        .iter()
        .map(|m| m.iter().map(|&v| mesh.positions[v as usize]).sum::<DVec3>() / m.len() as f64)
        .collect();
    // Ids while checking: fine vertices 0..n, cluster c as n + c; each fine vertex's image
    // (its active cluster's id, else itself), kept as clusters are left fine.
    let mut image: Vec<u32> = (0..n as u32)
        .map(|v| match cluster[v as usize] {
            c if c != u32::MAX && active[c as usize] => n as u32 + c,
            _ => v,
        })
        .collect();
    let place = |x: u32| {
        if (x as usize) < n {
            mesh.positions[x as usize]
        } else {
            point[x as usize - n]
        }
    };
    let mapped = |image: &[u32], t: &[u32; 3]| -> Option<[u32; 3]> {
        let m = t.map(|v| image[v as usize]);
        (m[0] != m[1] && m[1] != m[2] && m[2] != m[0]).then_some(m)
    };
    let mut passed: HashSet<[u32; 3], BuildHasherDefault<KeyHasher>> = HashSet::default();
    let (tol, r_min) = (opts.tolerance, opts.min_radius);
    // What each round checks: the clusters whose triangles may have changed (all active ones
    // first, then those next to a cluster just left fine) and the fine vertices next to those.
    // A cluster's one fan also gives each edge at it one triangle each way; an edge between
    // two fine vertices keeps its two triangles.
    let mut dirty: Vec<u32> = (0..members.len() as u32)
        .filter(|&c| active[c as usize])
        .collect();
    // The fine vertices next to what changed, each once (`listed`: the round that listed it).
    let mut fine_near: Vec<u32> = Vec::new();
    let (mut listed, mut round) = (vec![0u32; n], 1u32);
    let (mut link, mut near): (Vec<(u32, u32)>, Vec<u32>) = (Vec::new(), Vec::new());
    loop {
        let mut bad: Vec<u32> = Vec::new();
        let blame = |bad: &mut Vec<u32>, xs: &[u32]| {
            bad.extend(
                xs.iter()
                    .filter(|&&x| x as usize >= n)
                    .map(|&x| x - n as u32),
            );
        };
        for &c in &dirty {
            if !active[c as usize] {
                continue;
            }
            link.clear();
            let me = n as u32 + c;
            for &v in &members[c as usize] {
                for &t in star(v) {
                    let tri = &mesh.triangles[t as usize];
                    for &x in tri {
                        if image[x as usize] == x && listed[x as usize] != round {
                            listed[x as usize] = round;
                            fine_near.push(x);
                        }
                    }
                    let Some(m) = mapped(&image, tri) else {
                        continue;
                    };
                    let k = m.iter().position(|&x| x == me).expect("c is a corner");
                    link.push((m[(k + 1) % 3], m[(k + 2) % 3]));
                    // The border rule, slivers, the band (once per triangle).
                    if passed.contains(&m) {
                        continue;
                    }
                    let q = m.map(place);
                    let off_box = m.iter().zip(&q).any(|(&x, &p)| {
                        (x as usize >= n || !locked[x as usize]) && !block.strictly_holds(p)
                    });
                    let sliver = (q[1] - q[0]).cross(q[2] - q[0]).length() < MIN_AREA2;
                    let prox = &mut scratch.prox;
                    if off_box
                        || sliver
                        || prox.probes_miss(&q, tol)
                        || !prox.triangle_within(q, tol, r_min)
                    {
                        blame(&mut bad, &m);
                    } else {
                        passed.insert(m);
                    }
                }
            }
            if !one_fan(&mut link, false) {
                bad.push(c);
            }
        }
        for &v in &fine_near {
            link.clear();
            near.clear();
            for &t in star(v) {
                let tri = &mesh.triangles[t as usize];
                let Some(m) = mapped(&image, tri) else {
                    near.extend(tri.map(|x| image[x as usize]));
                    continue;
                };
                let k = m.iter().position(|&x| x == v).expect("v is a corner");
                link.push((m[(k + 1) % 3], m[(k + 2) % 3]));
                near.extend(m);
            }
            if !one_fan(&mut link, locked[v as usize]) {
                blame(&mut bad, &near);
            }
        }
        fine_near.clear();
        round += 1;
        bad.sort_unstable();
        bad.dedup();
        bad.retain(|&c| active[c as usize]);
        if bad.is_empty() {
            break;
        }
        for &c in &bad {
            active[c as usize] = false;
            for &v in &members[c as usize] {
                image[v as usize] = v;
            }
        }
        // Next: the active clusters and the fine vertices next to those just left fine.
        dirty.clear();
        for &c in &bad {
            for &v in &members[c as usize] {
                for &t in star(v) {
                    for &x in &mesh.triangles[t as usize] {
                        match image[x as usize] {
                            y if y as usize >= n => dirty.push(y - n as u32),
                            y if listed[y as usize] != round => {
                                listed[y as usize] = round;
                                fine_near.push(y);
                            }
                            _ => {}
                        }
                    }
                }
            }
        }
        dirty.sort_unstable();
        dirty.dedup();
    }
    let taken: Vec<usize> = (0..members.len()).filter(|&c| active[c]).collect();
    if taken.is_empty() {
        return Err(Declined::Nothing);
    }
    // Euler characteristic: V - E + F with E = (3F + open edges) / 2 and the open edges kept,
    // so it is unchanged when the vertices removed are half the triangles removed.
    let removed: usize = taken.iter().map(|&c| members[c].len() - 1).sum();
    // The moved triangles (O), each with its image's places (N: the images still triangles).
    // Counted first: a block's level moves up to a few hundred thousand of them (150 bytes
    // each), which growing by doubling copied over and over.
    let is_moved = |t: &[u32; 3]| t.iter().any(|&v| image[v as usize] != v);
    let mut moved: Vec<Mapped> =
        Vec::with_capacity(mesh.triangles.iter().filter(|t| is_moved(t)).count());
    let mut images = 0usize;
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let m = mapped(&image, t);
        if is_moved(t) {
            moved.push(Mapped {
                ids: *t,
                from: t.map(|v| mesh.positions[v as usize]),
                to: t.map(|v| place(image[v as usize])),
            });
            images += usize::from(m.is_some());
        }
        triangles.extend(m);
    }
    if 2 * removed != mesh.triangles.len() - triangles.len() {
        return Err(Declined::Euler);
    }
    // Each piece with both points in the step's box costs a winding number over O and N. (A
    // vanished triangle's image lies in the box of O: a cluster's point is its members' mean.)
    let enclosed = pieces.enclosed_by(Mapped::bounds_of(&moved));
    if enclosed.saturating_mul(moved.len() + images) > SWEEP_BUDGET {
        return Err(Declined::SweepCost);
    }
    if pieces.swallowed_by_map(&moved) {
        return Err(Declined::Sweep);
    }
    // Each vertex's quadric (the planes of its fine triangles), summed per cluster.
    let fine = match quadric {
        Some(q) => {
            debug_assert_eq!(q.len(), n, "a quadric per vertex");
            q.to_vec()
        }
        None => {
            let mut fine = vec![Quadric::default(); n];
            for t in &mesh.triangles {
                let q = Quadric::plane(t.map(|v| mesh.positions[v as usize]));
                for &v in t {
                    fine[v as usize] = fine[v as usize].add(&q);
                }
            }
            fine
        }
    };
    // New ids in vertex order, a cluster at its first member's place in it.
    let mut id = vec![u32::MAX; n + members.len()];
    let kept = n - removed;
    let mut out = Coarse {
        mesh: Mesh {
            positions: Vec::with_capacity(kept),
            ..Mesh::default()
        },
        locked: Vec::with_capacity(kept),
        quadric: Vec::with_capacity(kept),
        clusters: taken.len() as u64,
        removed: removed as u64,
        cluster: Vec::with_capacity(kept),
    };
    for v in 0..n as u32 {
        let x = image[v as usize];
        if x == v {
            id[v as usize] = out.mesh.positions.len() as u32;
            out.mesh.positions.push(mesh.positions[v as usize]);
            out.locked.push(locked[v as usize]);
            out.quadric.push(fine[v as usize]);
            out.cluster.push(u32::MAX);
        } else if id[x as usize] == u32::MAX {
            let c = x as usize - n;
            id[x as usize] = out.mesh.positions.len() as u32;
            out.mesh.positions.push(point[c]);
            out.locked.push(false);
            out.cluster.push(c as u32);
            out.quadric.push(
                members[c]
                    .iter()
                    .fold(Quadric::default(), |q, &m| q.add(&fine[m as usize])),
            );
        }
    }
    out.mesh.triangles = triangles
        .iter()
        .map(|t| t.map(|x| id[x as usize]))
        .collect();
    Ok(out)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::mesh::classify::test_support::{boxed, random};
    use crate::mesh::classify::Classifier;
    use crate::mesh::extract::extract;
    use crate::mesh::manifold::Joined;
    use crate::simplify::band::dist_to_centre;
    use crate::simplify::pieces::{winding, Pieces};
    use crate::simplify::Tolerance;

    /// The default radii (ε = 0.6h): T's half-width 1.466 voxels, the sweep radius 1.486.
    pub(in crate::simplify) fn opts() -> SimplifyOptions {
        SimplifyOptions {
            tolerance: Tolerance {
                outside: 1.466,
                inside: 1.466,
            },
            sweep: 1.486,
            min_radius: 0.05,
            target_triangles: 0,
        }
    }

    pub(in crate::simplify) fn places(m: &Mesh) -> Vec<[DVec3; 3]> {
        m.triangles
            .iter()
            .map(|t| t.map(|v| m.positions[v as usize]))
            .collect()
    }

    fn euler(m: &Mesh) -> i64 {
        let mut edges: Vec<(u32, u32)> = m
            .triangles
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| (a.min(b), a.max(b)))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut used: Vec<u32> = m.triangles.iter().flatten().copied().collect();
        used.sort_unstable();
        used.dedup();
        used.len() as i64 - edges.len() as i64 + m.triangles.len() as i64
    }

    /// Voxel centres (grid units) inside the voxels and out of T: where the swept volume may
    /// be. And those outside them and out of T: where the outside is.
    pub(in crate::simplify) fn deep_and_far(
        cls: &Classifier,
        dims: [u32; 3],
    ) -> (Vec<DVec3>, Vec<DVec3>) {
        let (mut deep, mut far) = (Vec::new(), Vec::new());
        let r = opts().tolerance.outside + 0.01;
        for x in 0..dims[0] {
            for y in 0..dims[1] {
                for z in 0..dims[2] {
                    let p = DVec3::new(x as f64, y as f64, z as f64) + 0.5;
                    let v = p.floor().to_array().map(|c| c as isize);
                    if cls.inside(v[0], v[1], v[2]) {
                        if dist_to_centre(cls, p, false, r).is_none() {
                            deep.push(p);
                        }
                    } else if dist_to_centre(cls, p, true, r).is_none() {
                        far.push(p);
                    }
                }
            }
        }
        (deep, far)
    }

    /// Rough random voxel sets (tunnels, thin walls, concavities), one block: the coarse start
    /// removes over a third of the vertices and stays a closed 2-manifold of the same Euler characteristic,
    /// every moved triangle in T (sampled against the exact distances), every point of the voxels
    /// out of T still enclosed and every point of the outside out of T still outside.
    #[test]
    fn random_sets_coarsen_to_the_same_closed_surface_in_t() {
        for (seed, levels) in (0..4).flat_map(|seed| [(seed, false), (seed, true)]) {
            let dims = [26, 24, 22];
            let cls = random(dims, seed);
            let joined = Joined::new(&cls);
            let fine = extract(&joined);
            let (deep, far) = deep_and_far(&cls, dims);
            assert!(deep.len() > 50 && far.len() > 50, "seed {seed}");
            let pieces = Pieces::from_points(deep.iter().map(|&p| [p, p]).collect());
            let mut scratch = Scratch::new(&cls, Some(&pieces), fine.triangles.len());
            let block = Block {
                lo: [0; 3],
                hi: dims.map(|d| d as usize),
            };
            let locked = vec![false; fine.positions.len()];
            let out = if levels {
                coarsen_levels(&fine, &locked, &block, &mut scratch, &opts())
            } else {
                coarsen(&fine, &locked, &[], &block, &mut scratch, &opts())
            }
            .unwrap_or_else(|why| panic!("seed {seed}: declined, {why:?}"));
            if levels {
                // The levels take more than cells of 8 or of 4 alone (on these rough sets cells
                // of 8 mostly fail), and the quadrics still add up to the fine triangles'
                // planes (each counted at its three corners).
                let alone = |size: f64, scratch: &mut Scratch| {
                    coarsen_in(&fine, &locked, None, &[], size, &block, scratch, &opts())
                        .map_or(0, |c| c.removed)
                };
                let (eight, four) = (alone(8.0, &mut scratch), alone(4.0, &mut scratch));
                assert!(
                    out.removed > eight.max(four),
                    "seed {seed}: {} removed, cells of 8 alone {eight}, of 4 alone {four}",
                    out.removed
                );
                let terms = |q: Quadric| [q.a.as_slice(), &q.b, &[q.c]].concat();
                let got = out.quadric.iter().fold(Quadric::default(), |s, x| s.add(x));
                let planes = places(&fine).into_iter().fold(Quadric::default(), |s, t| {
                    let q = Quadric::plane(t);
                    s.add(&q).add(&q).add(&q)
                });
                for (g, w) in terms(got).iter().zip(&terms(planes)) {
                    assert!(
                        (g - w).abs() <= 1e-9 * (1.0 + w.abs()),
                        "seed {seed}: quadric sum {g} against {w}"
                    );
                }
            }
            let m = &out.mesh;
            assert_eq!(
                m.positions.len() as u64 + out.removed,
                fine.positions.len() as u64
            );
            assert!(
                m.positions.len() * 3 < fine.positions.len() * 2,
                "seed {seed}: {} of {} vertices left",
                m.positions.len(),
                fine.positions.len()
            );
            assert!(m.manifold_defects().is_manifold() && m.unpaired_edges().is_empty());
            assert_eq!(euler(m), euler(&fine), "seed {seed}");
            // The fine triangles left as they were are joined voxels' faces, which T need not
            // hold (the stated bound covers them); every other one must lie in it.
            let key = |t: &[DVec3; 3]| t.map(|p| p.to_array().map(f64::to_bits));
            let kept: HashSet<_> = places(&fine).iter().map(key).collect();
            let moved: Vec<[DVec3; 3]> = places(m)
                .into_iter()
                .filter(|t| !kept.contains(&key(t)))
                .collect();
            assert!(
                moved.len() > 200,
                "seed {seed}: {} of {} moved",
                moved.len(),
                m.triangles.len()
            );
            for t in moved {
                for (u, v) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0 / 3.0, 1.0 / 3.0)] {
                    let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
                    let tol = opts().tolerance;
                    assert!(
                        dist_to_centre(&cls, p, false, tol.outside).is_some()
                            && dist_to_centre(&cls, p, true, tol.inside).is_some(),
                        "seed {seed}: {p} out of T"
                    );
                }
            }
            let tris = places(m);
            for &p in &deep {
                let w = winding(&tris, p);
                assert!((w - 1.0).abs() < 1e-6, "seed {seed}: winding {w} at {p}");
            }
            for &p in &far {
                let w = winding(&tris, p);
                assert!(w.abs() < 1e-6, "seed {seed}: winding {w} at {p}");
            }
        }
    }

    /// The sweep check is wired in: the corners of a cube's coarse start cut into it, so a
    /// piece of the swept volume put in a corner declines the whole step, and the same step
    /// without it leaves that point outside; pieces too many to check decline it too.
    #[test]
    fn a_piece_the_step_would_leave_outside_declines_it() {
        let cls = boxed([12, 12, 12], [2.0; 3], [8.0; 3]);
        let fine = extract(&Joined::new(&cls));
        let block = Block {
            lo: [0; 3],
            hi: [12; 3],
        };
        let locked = vec![false; fine.positions.len()];
        let corner = DVec3::splat(2.1);
        let run = |points: Vec<[DVec3; 2]>| {
            let pieces = Pieces::from_points(points);
            let mut scratch = Scratch::new(&cls, Some(&pieces), fine.triangles.len());
            coarsen(&fine, &locked, &[], &block, &mut scratch, &opts())
        };
        assert_eq!(run(vec![[corner; 2]]).err(), Some(Declined::Sweep));
        // So many pieces in the box that their winding numbers would cost too much: declined
        // before any is computed.
        let many = vec![[DVec3::splat(5.0); 2]; SWEEP_BUDGET / 300];
        assert_eq!(run(many).err(), Some(Declined::SweepCost));
        let out = run(Vec::new()).expect("no piece in the way");
        assert!(winding(&places(&out.mesh), corner).abs() < 1e-6);
        assert!((winding(&places(&fine), corner) - 1.0).abs() < 1e-6);
        // Without the pieces the start stays fine.
        let mut scratch = Scratch::new(&cls, None, fine.triangles.len());
        let none = coarsen(&fine, &locked, &[], &block, &mut scratch, &opts());
        assert_eq!(none.err(), Some(Declined::NoPieces));
    }

    /// Locked vertices (a patch's open edges) never join a cluster and stay where they are,
    /// through one level and through all of them.
    #[test]
    fn locked_vertices_stay() {
        for levels in [false, true] {
            locked_vertices_stay_in(levels);
        }
    }

    fn locked_vertices_stay_in(levels: bool) {
        let cls = random([20, 20, 20], 3);
        let fine = extract(&Joined::new(&cls));
        let locked: Vec<bool> = fine.positions.iter().map(|p| p.x < 10.0).collect();
        let pieces = Pieces::from_points(Vec::new());
        let mut scratch = Scratch::new(&cls, Some(&pieces), fine.triangles.len());
        let block = Block {
            lo: [0; 3],
            hi: [20; 3],
        };
        let out = if levels {
            coarsen_levels(&fine, &locked, &block, &mut scratch, &opts()).unwrap()
        } else {
            coarsen(&fine, &locked, &[], &block, &mut scratch, &opts()).unwrap()
        };
        let kept: Vec<DVec3> = (0..out.mesh.positions.len())
            .filter(|&v| out.locked[v])
            .map(|v| out.mesh.positions[v])
            .collect();
        let want: Vec<DVec3> = (0..fine.positions.len())
            .filter(|&v| locked[v])
            .map(|v| fine.positions[v])
            .collect();
        assert_eq!(kept, want);
        assert!(out.clusters > 0);
    }

    /// A fan is one cycle, or for an open vertex one path; a pinch (two cycles, a repeated
    /// vertex) or a broken path is not.
    #[test]
    fn fans_are_one_cycle_or_one_path() {
        let f = |l: &[(u32, u32)], open| one_fan(&mut l.to_vec(), open);
        assert!(f(&[(1, 2), (2, 3), (3, 1)], false));
        assert!(!f(&[(1, 2), (2, 3), (3, 1)], true));
        assert!(f(&[(1, 2), (2, 3), (3, 4)], true));
        assert!(!f(&[(1, 2), (2, 3), (3, 4)], false));
        assert!(!f(&[(1, 2), (2, 3), (3, 1), (4, 5), (5, 6), (6, 4)], false));
        assert!(!f(&[(1, 2), (2, 3), (3, 1), (1, 4), (4, 5), (5, 1)], false));
        assert!(!f(&[(1, 2), (3, 4)], true));
        assert!(!f(&[(1, 2), (2, 3), (3, 1), (4, 5)], true));
        assert!(!f(&[(1, 2), (2, 1)], false));
    }
}
