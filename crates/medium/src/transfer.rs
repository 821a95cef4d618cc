//! Transfer functions from a cell's data value to its optical properties: constants,
//! piecewise-linear tables (clamped at the ends), named presets, and Max's particle model
//! (emission = C·σt, eq. 8).

use serde::{Deserialize, Serialize};

/// Why a transfer function was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TransferError {
    #[error("a piecewise-linear table needs at least one point")]
    Empty,
    #[error("point {index} ({x}, {y}) is not finite")]
    NotFinite { index: usize, x: f64, y: f64 },
    #[error("points must be sorted by strictly increasing x: point {index} has x = {x} after {previous}")]
    Unsorted { index: usize, x: f64, previous: f64 },
    #[error("unknown preset `{0}` (expected one of: {list})", list = PRESET_NAMES.join(", "))]
    UnknownPreset(String),
}

/// A piecewise-linear function through sorted points, constant beyond the first and last.
///
/// # Invariants
/// At least one point; x strictly increasing; all coordinates finite.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PiecewiseLinear {
    points: Vec<[f64; 2]>,
}

/// Names accepted by [`PiecewiseLinear::preset`].
pub const PRESET_NAMES: [&str; 5] = ["linear", "smoothstep", "threshold", "inverse", "cloud-edge"];

impl PiecewiseLinear {
    pub fn new(points: Vec<[f64; 2]>) -> Result<Self, TransferError> {
        if points.is_empty() {
            return Err(TransferError::Empty);
        }
        for (index, &[x, y]) in points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                return Err(TransferError::NotFinite { index, x, y });
            }
            if index > 0 && x <= points[index - 1][0] {
                return Err(TransferError::Unsorted {
                    index,
                    x,
                    previous: points[index - 1][0],
                });
            }
        }
        Ok(PiecewiseLinear { points })
    }

    /// A named table on data values in `[0, 1]` with outputs in `[0, 1]`:
    /// - `linear`: y = x;
    /// - `smoothstep`: 3x² − 2x³ sampled at 9 points;
    /// - `threshold`: 0 below 0.2, rising to 1 at 0.3 (a soft iso-surface);
    /// - `inverse`: y = 1 − x;
    /// - `cloud-edge`: 0 below 0.05, a soft knee, 1 from 0.6 (thin edges stay thin).
    pub fn preset(name: &str) -> Result<Self, TransferError> {
        let points: Vec<[f64; 2]> = match name {
            "linear" => vec![[0.0, 0.0], [1.0, 1.0]],
            "smoothstep" => (0..=8)
                .map(|i| {
                    let x = i as f64 / 8.0;
                    [x, x * x * (3.0 - 2.0 * x)]
                })
                .collect(),
            "threshold" => vec![[0.2, 0.0], [0.3, 1.0]],
            "inverse" => vec![[0.0, 1.0], [1.0, 0.0]],
            "cloud-edge" => vec![[0.05, 0.0], [0.2, 0.35], [0.6, 1.0]],
            other => return Err(TransferError::UnknownPreset(other.to_string())),
        };
        PiecewiseLinear::new(points)
    }

    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// Multiplies every output by `factor`.
    pub fn scaled(mut self, factor: f64) -> Self {
        self.points.iter_mut().for_each(|p| p[1] *= factor);
        self
    }

    /// The table's value at `x`, clamped to the end values outside the table.
    pub fn eval(&self, x: f64) -> f64 {
        let pts = &self.points;
        let first = pts[0];
        let last = pts[pts.len() - 1];
        // NaN lands here too: it maps to the first value rather than poisoning σt.
        if x.is_nan() || x <= first[0] {
            return first[1];
        }
        if x >= last[0] {
            return last[1];
        }
        // First point with x_i > x; it exists and is at index ≥ 1 by the checks above.
        let hi = pts.partition_point(|p| p[0] <= x);
        let [x0, y0] = pts[hi - 1];
        let [x1, y1] = pts[hi];
        y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    }

    /// Smallest and largest output: a piecewise-linear function attains both at its points.
    pub fn range(&self) -> (f64, f64) {
        self.points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p[1]), hi.max(p[1]))
            })
    }
}

/// One channel's mapping from data value to a non-σt property (albedo or emission).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Transfer {
    Constant {
        value: f64,
    },
    Table {
        table: PiecewiseLinear,
    },
    /// Max's particle model (eq. 8): emission = `c · σt`, so a uniform-`c` region composites
    /// as `I = I0 T + c (1 − T)`.
    Particle {
        c: f64,
    },
}

impl Transfer {
    /// The property for a cell with data value `value` and extinction `sigma_t`.
    #[inline]
    pub fn eval(&self, value: f32, sigma_t: f32) -> f32 {
        match self {
            Transfer::Constant { value } => *value as f32,
            Transfer::Table { table } => table.eval(value as f64) as f32,
            Transfer::Particle { c } => (*c * sigma_t as f64) as f32,
        }
    }

    /// The constant, when the property does not depend on the cell.
    pub fn as_constant(&self) -> Option<f64> {
        match self {
            Transfer::Constant { value } => Some(*value),
            Transfer::Particle { c } if *c == 0.0 => Some(0.0),
            _ => None,
        }
    }

    /// Bounds of the outputs that do not scale with σt (for range validation); the particle
    /// model reports `c`.
    pub fn range(&self) -> (f64, f64) {
        match self {
            Transfer::Constant { value } => (*value, *value),
            Transfer::Table { table } => table.range(),
            Transfer::Particle { c } => (*c, *c),
        }
    }

    /// Applies to every cell: a uniform value when constant, else one value per cell.
    pub fn apply(&self, data: &[f32], sigma_t: &[f32]) -> crate::CellValues {
        match self.as_constant() {
            Some(v) => crate::CellValues::Uniform(v as f32),
            None => crate::CellValues::PerCell(
                data.iter()
                    .zip(sigma_t)
                    .map(|(&d, &s)| self.eval(d, s))
                    .collect(),
            ),
        }
    }
}

/// The mapping from data value to σt for one channel: `scale · value` (the contract's default,
/// `sigma_t_scale`) or `scale · table(value)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SigmaTransfer {
    pub scale: f64,
    pub table: Option<PiecewiseLinear>,
}

impl SigmaTransfer {
    #[inline]
    pub fn eval(&self, value: f32) -> f32 {
        match &self.table {
            None => (self.scale * value as f64) as f32,
            Some(t) => (self.scale * t.eval(value as f64)) as f32,
        }
    }

    pub fn apply(&self, data: &[f32]) -> Vec<f32> {
        data.iter().map(|&v| self.eval(v)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_interpolates_and_clamps() {
        let t = PiecewiseLinear::new(vec![[0.0, 1.0], [1.0, 3.0], [3.0, 2.0]]).unwrap();
        assert_eq!(t.eval(-5.0), 1.0);
        assert_eq!(t.eval(0.0), 1.0);
        assert!((t.eval(0.25) - 1.5).abs() < 1e-12);
        assert_eq!(t.eval(1.0), 3.0);
        assert!((t.eval(2.0) - 2.5).abs() < 1e-12);
        assert_eq!(t.eval(3.0), 2.0);
        assert_eq!(t.eval(100.0), 2.0);
        assert_eq!(t.eval(f64::NAN), 1.0);
        assert_eq!(t.range(), (1.0, 3.0));
    }

    #[test]
    fn single_point_table_is_constant() {
        let t = PiecewiseLinear::new(vec![[0.5, 0.7]]).unwrap();
        for x in [-1.0, 0.5, 2.0] {
            assert_eq!(t.eval(x), 0.7);
        }
    }

    #[test]
    fn bad_tables_are_refused() {
        assert_eq!(PiecewiseLinear::new(vec![]), Err(TransferError::Empty));
        assert!(matches!(
            PiecewiseLinear::new(vec![[0.0, 0.0], [0.0, 1.0]]),
            Err(TransferError::Unsorted { index: 1, .. })
        ));
        assert!(matches!(
            PiecewiseLinear::new(vec![[1.0, 0.0], [0.5, 1.0]]),
            Err(TransferError::Unsorted { .. })
        ));
        assert!(matches!(
            PiecewiseLinear::new(vec![[0.0, f64::NAN]]),
            Err(TransferError::NotFinite { .. })
        ));
        assert!(matches!(
            PiecewiseLinear::preset("no-such"),
            Err(TransferError::UnknownPreset(_))
        ));
    }

    #[test]
    fn presets_map_unit_interval_into_unit_interval_monotonically() {
        for name in PRESET_NAMES {
            let t = PiecewiseLinear::preset(name).unwrap();
            let (lo, hi) = t.range();
            assert!(lo >= 0.0 && hi <= 1.0, "{name}");
            let ys: Vec<f64> = (0..=100).map(|i| t.eval(i as f64 / 100.0)).collect();
            let increasing = ys.windows(2).all(|w| w[1] >= w[0]);
            let decreasing = ys.windows(2).all(|w| w[1] <= w[0]);
            assert!(increasing || decreasing, "{name} is not monotone");
        }
        let s = PiecewiseLinear::preset("smoothstep").unwrap();
        assert!((s.eval(0.5) - 0.5).abs() < 1e-12);
        assert!((s.eval(0.25) - 0.15625).abs() < 1e-12);
    }

    #[test]
    fn particle_emission_is_c_times_sigma_t() {
        let p = Transfer::Particle { c: 0.5 };
        assert_eq!(p.eval(123.0, 4.0), 2.0);
        let e = p.apply(&[0.0, 1.0, 2.0], &[0.0, 3.0, 6.0]);
        assert_eq!(e, crate::CellValues::PerCell(vec![0.0, 1.5, 3.0]));
        assert_eq!(
            Transfer::Constant { value: 0.9 }.apply(&[1.0, 2.0], &[1.0, 2.0]),
            crate::CellValues::Uniform(0.9)
        );
    }

    #[test]
    fn sigma_transfer_scales_value_or_table() {
        let plain = SigmaTransfer {
            scale: 2.0,
            table: None,
        };
        assert_eq!(plain.apply(&[0.0, 0.5, 3.0]), vec![0.0, 1.0, 6.0]);
        let tabled = SigmaTransfer {
            scale: 10.0,
            table: Some(PiecewiseLinear::preset("threshold").unwrap()),
        };
        assert_eq!(tabled.apply(&[0.1, 0.25, 0.9]), vec![0.0, 5.0, 10.0]);
    }
}
