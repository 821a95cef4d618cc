//! Which cells carry the operator's unknowns: the cells that hold medium (σt > 0), in cell
//! order. Empty space carries light between them, in the sweeps' own per-group buffers, but
//! no state of its own: a cloud that fills a tenth of its box keeps a tenth of the radiances.

use std::ops::Range;

/// The state cells of a grid and the map from each cell to its row.
///
/// # Invariants
/// `cells` is strictly increasing; `row[c]` is `c`'s index in `cells`, or [`Self::NONE`];
/// `block_start[b]` is the first row whose cell is at or past `b · block` (one more entry
/// than blocks). Built only by [`StateCells::new`].
#[derive(Clone, Debug)]
pub(crate) struct StateCells {
    cells: Vec<u32>,
    row: Vec<u32>,
    block: usize,
    block_start: Vec<u32>,
}

impl StateCells {
    const NONE: u32 = u32::MAX;

    /// The cells with `sigma_t > 0`, and their rows' ranges per block of `block` cells.
    /// `None` when the grid has more cells than a `u32` can index.
    pub(crate) fn new(sigma_t: &[f64], block: usize) -> Option<Self> {
        let n = sigma_t.len();
        if n >= Self::NONE as usize || block == 0 {
            return None;
        }
        let mut cells = Vec::new();
        let mut row = vec![Self::NONE; n];
        let mut block_start = Vec::with_capacity(n.div_ceil(block) + 1);
        for (c, &s) in sigma_t.iter().enumerate() {
            if c % block == 0 {
                block_start.push(cells.len() as u32);
            }
            if s > 0.0 {
                row[c] = cells.len() as u32;
                cells.push(c as u32);
            }
        }
        block_start.push(cells.len() as u32);
        cells.shrink_to_fit();
        Some(StateCells {
            cells,
            row,
            block,
            block_start,
        })
    }

    /// How many cells carry state.
    pub(crate) fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether every cell of the grid carries state (a slab, a uniform block).
    pub(crate) fn is_every_cell(&self) -> bool {
        self.cells.len() == self.row.len()
    }

    /// The state cells, in cell order (row `k` is cell `cells()[k]`).
    pub(crate) fn cells(&self) -> &[u32] {
        &self.cells
    }

    /// Cell `c`'s row, if it carries state.
    #[inline]
    pub(crate) fn row(&self, c: usize) -> Option<usize> {
        let r = self.row[c];
        (r != Self::NONE).then_some(r as usize)
    }

    /// The rows of the cells of block `b` (cells `b · block .. (b + 1) · block`).
    #[inline]
    pub(crate) fn rows_of_block(&self, b: usize) -> Range<usize> {
        self.block_start[b] as usize..self.block_start[b + 1] as usize
    }

    /// The cells of block `b`.
    #[inline]
    pub(crate) fn cells_of_block(&self, b: usize) -> Range<usize> {
        b * self.block..((b + 1) * self.block).min(self.row.len())
    }

    /// The cells of block `b` without state, in order: the gaps between its rows' cells.
    #[inline]
    pub(crate) fn empty_cells_of_block(&self, b: usize) -> impl Iterator<Item = usize> + '_ {
        let cells = self.cells_of_block(b);
        let ends = self.cells[self.rows_of_block(b)]
            .iter()
            .map(|&c| c as usize)
            .chain(std::iter::once(cells.end));
        ends.scan(cells.start, |next, end| {
            let gap = *next..end;
            *next = end + 1;
            Some(gap)
        })
        .flatten()
    }

    /// Bytes of the map.
    pub(crate) fn bytes(&self) -> usize {
        (self.cells.len() + self.row.len() + self.block_start.len()) * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_follow_the_cells_with_medium_block_by_block() {
        let sigma = [0.0, 1.0, 0.0, 0.0, 2.0, 3.0, 0.0];
        let s = StateCells::new(&sigma, 3).unwrap();
        assert_eq!(s.cells(), &[1, 4, 5]);
        assert_eq!((s.row(0), s.row(1), s.row(5)), (None, Some(0), Some(2)));
        assert_eq!(s.rows_of_block(0), 0..1);
        assert_eq!(s.rows_of_block(1), 1..3);
        assert_eq!(s.rows_of_block(2), 3..3);
        assert_eq!(s.cells_of_block(2), 6..7);
        let empty: Vec<Vec<usize>> = (0..3)
            .map(|b| s.empty_cells_of_block(b).collect())
            .collect();
        assert_eq!(empty, [vec![0, 2], vec![3], vec![6]]);
        assert!(!s.is_every_cell());
        assert!(StateCells::new(&[1.0, 1.0], 4).unwrap().is_every_cell());
    }
}
