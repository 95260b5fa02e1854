//! The one union-find of the pipeline (disjoint sets with path halving; the lower root index wins, so the
//! result does not depend on the order of the unions' arguments). Supervoxel merging keeps its parents in a
//! `[u16]` table, fusion in the Gaussians' `cluster` field: both go through [`Parents`].

/// A table of parent indices: element `i`'s parent is `parent(i)`; a root is its own parent.
pub trait Parents {
    /// Elements in the table.
    fn count(&self) -> usize;
    /// Parent of element `i` (`i` itself when out of range).
    fn parent(&self, i: usize) -> usize;
    /// Sets the parent of element `i` (nothing when out of range).
    fn set_parent(&mut self, i: usize, parent: usize);
}

impl Parents for [u16] {
    fn count(&self) -> usize {
        self.len()
    }

    fn parent(&self, i: usize) -> usize {
        self.get(i).map_or(i, |&p| p as usize)
    }

    fn set_parent(&mut self, i: usize, parent: usize) {
        if let Some(slot) = self.get_mut(i) {
            *slot = parent as u16;
        }
    }
}

/// Root of `i`, halving the path on the way (at most `count()` steps, so a corrupt table cannot loop).
pub fn find<P: Parents + ?Sized>(table: &mut P, mut i: usize) -> usize {
    for _ in 0..table.count() {
        let p = table.parent(i);
        if p == i {
            return i;
        }
        let gp = table.parent(p);
        table.set_parent(i, gp);
        i = gp;
    }
    i
}

/// Joins the sets of `a` and `b`; the lower root index becomes the root. Whether they were apart.
pub fn union<P: Parents + ?Sized>(table: &mut P, a: usize, b: usize) -> bool {
    let (ra, rb) = (find(table, a), find(table, b));
    if ra == rb {
        return false;
    }
    let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
    table.set_parent(hi, lo);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_join_under_their_lowest_index() {
        let mut t: [u16; 6] = [0, 1, 2, 3, 4, 5];
        assert!(union(&mut t[..], 4, 2));
        assert!(union(&mut t[..], 5, 4));
        assert!(!union(&mut t[..], 2, 5), "already one set");
        assert!(union(&mut t[..], 3, 1));
        let roots: [usize; 6] = core::array::from_fn(|i| find(&mut t[..], i));
        assert_eq!(roots, [0, 1, 2, 1, 2, 2]);
        // Out of range is its own root; a cycle (a corrupt table) ends after count() steps.
        assert_eq!(find(&mut t[..], 9), 9);
        let mut cyc: [u16; 3] = [1, 2, 0];
        let _ = find(&mut cyc[..], 0);
    }
}
