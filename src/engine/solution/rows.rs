//! [`CellRows`]: a per-cell, per-direction-bin field stored only where it is not zero.
//!
//! A discrete-ordinates solution's higher-order source is `σs` times the bins' scattered
//! light: zero in every cell that does not scatter, which in a cloud is most of the grid
//! (87 % of the 192 × 192 × 144 sample's transport cells). Those cells cost neither memory
//! nor file space nor the render's set-up; a lookup of one gives 0, as the dense field did.

/// One row of `width` values per cell of a grid, kept for the cells whose row has a
/// non-zero value (the others read as zeros). Invariant: `rows.len() == width ·` (the
/// number of kept cells), and `row_of[cell]` is the kept cell's rank among kept cells in
/// cell order, or [`CellRows::ABSENT`].
#[derive(Clone, Debug, PartialEq)]
pub struct CellRows {
    width: usize,
    row_of: Vec<u32>,
    rows: Vec<f32>,
}

impl CellRows {
    /// `row_of` of a cell without a row.
    const ABSENT: u32 = u32::MAX;

    /// The rows of a dense `cells × width` field given as `value(cell · width + column)`,
    /// keeping the cells with a non-zero value. `None` if `width` is 0 or there are more
    /// cells than `u32` can rank.
    pub fn from_dense(cells: usize, width: usize, value: impl Fn(usize) -> f32) -> Option<Self> {
        Self::keeping_non_zero(cells, width, (0..cells).map(|c| (c, c * width)), value)
    }

    /// The rows of a field given for some cells only, the others zero: `value(k · width +
    /// column)` for cell `row_cells[k]` (increasing, each below `cells`), as a
    /// discrete-ordinates solve holds its cells with medium; kept as
    /// [`from_dense`](Self::from_dense) keeps them. `None` where that gives `None`, or if
    /// `row_cells` is not increasing within the grid.
    pub fn from_rows(
        cells: usize,
        width: usize,
        row_cells: &[u32],
        value: impl Fn(usize) -> f32,
    ) -> Option<Self> {
        let increasing = row_cells.windows(2).all(|w| w[0] < w[1]);
        if !increasing || row_cells.last().is_some_and(|&c| c as usize >= cells) {
            return None;
        }
        let candidates = row_cells
            .iter()
            .enumerate()
            .map(|(k, &c)| (c as usize, k * width));
        Self::keeping_non_zero(cells, width, candidates, value)
    }

    /// The rows of `candidates` (cell, index of its first value, in cell order) with a
    /// non-zero value.
    fn keeping_non_zero(
        cells: usize,
        width: usize,
        candidates: impl Iterator<Item = (usize, usize)>,
        value: impl Fn(usize) -> f32,
    ) -> Option<Self> {
        if width == 0 || cells >= Self::ABSENT as usize {
            return None;
        }
        let mut row_of = vec![Self::ABSENT; cells];
        let mut rows = Vec::new();
        let mut kept = 0u32;
        for (cell, base) in candidates {
            if (base..base + width).any(|i| value(i) != 0.0) {
                rows.extend((base..base + width).map(&value));
                row_of[cell] = kept;
                kept += 1;
            }
        }
        rows.shrink_to_fit();
        Some(CellRows {
            width,
            row_of,
            rows,
        })
    }

    /// The rows as stored in a solution file: `kept[cell]` 1 for a cell with a row, 0 without
    /// (as [`CellRows::kept_mask`] writes it), and the kept rows in cell order. Names what
    /// does not fit.
    pub fn from_parts(width: usize, kept: &[f32], rows: Vec<f32>) -> Result<Self, String> {
        if width == 0 {
            return Err("rows of width 0".into());
        }
        if kept.len() >= Self::ABSENT as usize {
            return Err(format!("{} cells: too many to index", kept.len()));
        }
        let mut row_of = Vec::with_capacity(kept.len());
        let mut count = 0u32;
        for (cell, &k) in kept.iter().enumerate() {
            if k == 1.0 {
                row_of.push(count);
                count += 1;
            } else if k == 0.0 {
                row_of.push(Self::ABSENT);
            } else {
                return Err(format!("cell {cell}: kept mark {k} is neither 0 nor 1"));
            }
        }
        if rows.len() != count as usize * width {
            return Err(format!(
                "{} values for {count} kept cells of {width} values each",
                rows.len()
            ));
        }
        Ok(CellRows {
            width,
            row_of,
            rows,
        })
    }

    /// Values per row (the direction bins).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Cells of the grid the rows belong to.
    pub fn cells(&self) -> usize {
        self.row_of.len()
    }

    /// Cells with a row.
    pub fn kept_cells(&self) -> usize {
        self.rows.len() / self.width
    }

    /// The kept rows, one after another in cell order.
    pub fn values(&self) -> &[f32] {
        &self.rows
    }

    /// Where `cell`'s row starts in [`CellRows::values`], if it has one.
    #[inline]
    pub fn start_of(&self, cell: usize) -> Option<usize> {
        let r = self.row_of[cell];
        (r != Self::ABSENT).then(|| r as usize * self.width)
    }

    /// `cell`'s row, if it has one (else its values are all zero).
    pub fn row(&self, cell: usize) -> Option<&[f32]> {
        self.start_of(cell).map(|s| &self.rows[s..s + self.width])
    }

    /// `cell`'s rank among the kept cells (its row is the rank-th), if it has a row.
    #[inline]
    pub fn rank_of(&self, cell: usize) -> Option<usize> {
        let r = self.row_of[cell];
        (r != Self::ABSENT).then_some(r as usize)
    }

    /// The kept cells with their rows, in cell order.
    pub fn kept_rows(&self) -> impl Iterator<Item = (usize, &[f32])> + '_ {
        self.row_of
            .iter()
            .enumerate()
            .filter(|(_, &r)| r != Self::ABSENT)
            .map(|(cell, &r)| {
                let start = r as usize * self.width;
                (cell, &self.rows[start..start + self.width])
            })
    }

    /// Per cell, 1 if it has a row and 0 if not (how a solution file stores which cells do).
    pub fn kept_mask(&self) -> Vec<f32> {
        self.row_of
            .iter()
            .map(|&r| if r == Self::ABSENT { 0.0 } else { 1.0 })
            .collect()
    }

    /// Per cell, the largest value of its row (0 without one).
    pub fn row_maxima(&self) -> Vec<f32> {
        (0..self.cells())
            .map(|c| {
                self.row(c)
                    .map_or(0.0, |r| r.iter().copied().fold(0.0f32, f32::max))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_keep_what_is_not_zero_and_read_back_the_dense_field() {
        // 5 cells × 3 bins: cells 1 and 4 all zero, cell 2 zero but for one bin.
        let dense = [
            1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 7.0, 4.0, 5.0, 6.0, 0.0, 0.0, 0.0,
        ];
        let rows = CellRows::from_dense(5, 3, |i| dense[i]).unwrap();
        assert_eq!(rows.kept_cells(), 3);
        assert_eq!(rows.values().len(), 9);
        for cell in 0..5 {
            for l in 0..3 {
                let value = rows.row(cell).map_or(0.0, |r| r[l]);
                assert_eq!(value, dense[cell * 3 + l], "cell {cell} bin {l}");
            }
        }
        assert!(rows.row(1).is_none() && rows.row(4).is_none());
        assert_eq!(rows.row(2), Some(&[0.0, 0.0, 7.0][..]));
        assert_eq!(rows.row_maxima(), vec![3.0, 0.0, 7.0, 6.0, 0.0]);
        // As a file stores them, and back.
        let again = CellRows::from_parts(3, &rows.kept_mask(), rows.values().to_vec()).unwrap();
        assert_eq!(again, rows);
    }

    /// Rows given for some cells only (a solve's cells with medium) are what the dense field
    /// with zeros elsewhere gives; a row of zeros among them is not kept.
    #[test]
    fn rows_of_some_cells_are_the_dense_fields_rows() {
        let dense = [
            1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 7.0, 4.0, 5.0, 6.0, 0.0, 0.0, 0.0,
        ];
        // Cells 0, 2, 3 and 4 hold values (4's all zero), cell 1 none.
        let row_cells = [0, 2, 3, 4];
        let packed: Vec<f32> = row_cells
            .iter()
            .flat_map(|&c| dense[3 * c as usize..3 * c as usize + 3].to_vec())
            .collect();
        let rows = CellRows::from_rows(5, 3, &row_cells, |i| packed[i]).unwrap();
        assert_eq!(rows, CellRows::from_dense(5, 3, |i| dense[i]).unwrap());
        assert!(CellRows::from_rows(5, 3, &[2, 0], |i| packed[i]).is_none());
        assert!(CellRows::from_rows(5, 3, &[0, 5], |i| packed[i]).is_none());
    }

    #[test]
    fn stored_rows_that_do_not_fit_are_refused_by_name() {
        let err = CellRows::from_parts(3, &[1.0, 0.0, 1.0], vec![0.5; 3]).unwrap_err();
        assert!(err.contains("3 values for 2 kept cells"), "{err}");
        let err = CellRows::from_parts(3, &[1.0, 0.5], vec![0.5; 3]).unwrap_err();
        assert!(
            err.contains("cell 1") && err.contains("neither 0 nor 1"),
            "{err}"
        );
        assert!(CellRows::from_parts(0, &[], vec![]).is_err());
        assert!(CellRows::from_dense(4, 0, |_| 1.0).is_none());
    }
}
