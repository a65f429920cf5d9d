//! The fixed-radius neighbour search of training: a uniform grid whose cell side is the search
//! radius, so a point's neighbours lie in the 27 cells around its own (linear in the points).
//! Used by the emitter clustering's connected pieces ([`crate::stage2::kmeans::components`]) and by the
//! pooling of diffuse sums over a surface ([`crate::stage2::shading::pool_diffuse`]). Each caller computes
//! the cells in its own precision and tests the distances itself; the grid only says which points
//! to test, in a fixed order (so sums over the neighbours come out the same on every run).

use std::collections::HashMap;

pub struct NeighbourGrid {
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl NeighbourGrid {
    /// The grid of points `0..n`, point `i` in cell `cell_of(i)` (its coordinates divided by the
    /// cell side, floored). At most `u32::MAX` points.
    pub fn new(n: usize, cell_of: impl Fn(usize) -> [i64; 3]) -> NeighbourGrid {
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for i in 0..n {
            cells.entry(cell_of(i)).or_default().push(i as u32);
        }
        NeighbourGrid { cells }
    }

    /// Calls `f(j)` for every point `j` in the 27 cells around `cell` (itself included): the
    /// cells in order of their x, then y, then z offset (−1, 0, 1), each cell's points in index
    /// order.
    pub fn for_each_near(&self, cell: [i64; 3], mut f: impl FnMut(usize)) {
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                    for &j in self.cells.get(&key).into_iter().flatten() {
                        f(j as usize);
                    }
                }
            }
        }
    }
}
