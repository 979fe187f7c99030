//! Disjoint sets over ids 0..n (path halving, the smaller root kept): the connected components
//! of a mesh by shared vertices, for `verify::health` and the sweep check's pieces
//! (`simplify::pieces`).

/// Each id's parent; a root is its own.
pub struct UnionFind(Vec<u32>);

impl UnionFind {
    /// `n` singletons, ids 0..n.
    pub fn new(n: usize) -> Self {
        UnionFind((0..n as u32).collect())
    }

    /// A new singleton; its id.
    pub fn push(&mut self) -> u32 {
        let id = self.0.len() as u32;
        self.0.push(id);
        id
    }

    /// The root of `i`'s set.
    pub fn find(&mut self, mut i: u32) -> u32 {
        let parent = &mut self.0;
        while parent[i as usize] != i {
            parent[i as usize] = parent[parent[i as usize] as usize];
            i = parent[i as usize];
        }
        i
    }

    /// Joins the sets of `a` and `b`.
    pub fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        self.0[ra.max(rb) as usize] = ra.min(rb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joined_ids_share_a_root_and_others_do_not() {
        let mut s = UnionFind::new(6);
        s.join(0, 3);
        s.join(4, 3);
        assert_eq!(s.push(), 6);
        s.join(6, 5);
        assert_eq!(s.find(4), s.find(0));
        assert_eq!(s.find(6), s.find(5));
        assert_ne!(s.find(0), s.find(5));
        assert_ne!(s.find(1), s.find(2));
        let roots = (0..7).filter(|&i| s.find(i) == i).count();
        assert_eq!(roots, 4); // {0, 3, 4}, {1}, {2}, {5, 6}
    }
}
