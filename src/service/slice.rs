//! `GET /v1/scenes/{id}/slice`: one plane of cells of a solved field (fluence, source or σt),
//! as a PNG through a colour map, one pixel per cell; what the viewer's slice panel shows.
//!
//! The colour range is the whole volume's, not the plane's, so planes compare: linear from 0
//! to the field's maximum (the default), or logarithmic over the four decades below it (for
//! dense media, where the light in a shadow is orders of magnitude below the lit side).

use std::collections::HashMap;

use crate::engine::methods::ExportField;

/// Decades a logarithmic slice spans below the field's maximum.
pub const LOG_DECADES: f64 = 4.0;

/// What a slice request asks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SliceQuery {
    pub field: ExportField,
    /// 0, 1, 2 for x, y, z: the axis the plane is perpendicular to.
    pub axis: usize,
    /// The plane's cell index along `axis`; `None` is the middle.
    pub index: Option<usize>,
    pub channel: usize,
    pub log: bool,
}

/// The parameters `slice` reads.
pub const SLICE_PARAMETERS: [&str; 5] = ["field", "axis", "index", "channel", "scale"];

/// Reads a slice query (unknown parameters are refused by the caller).
pub fn parse_slice_query(q: &HashMap<String, String>) -> Result<SliceQuery, String> {
    let field = match q.get("field") {
        None => ExportField::Fluence,
        Some(f) => f
            .parse::<ExportField>()
            .map_err(|e| format!("field: {e}"))?,
    };
    let axis = match q.get("axis").map(String::as_str) {
        None | Some("z") => 2,
        Some("x") => 0,
        Some("y") => 1,
        Some(other) => return Err(format!("axis: `{other}` is not x, y or z")),
    };
    let number = |key: &str| -> Result<Option<usize>, String> {
        q.get(key)
            .map(|v| {
                v.parse::<usize>()
                    .map_err(|_| format!("{key}: `{v}` is not a whole number ≥ 0"))
            })
            .transpose()
    };
    let log = match q.get("scale").map(String::as_str) {
        Some("log") => true,
        None | Some("linear") => false,
        Some(other) => return Err(format!("scale: `{other}` is not log or linear")),
    };
    Ok(SliceQuery {
        field,
        axis,
        index: number("index")?,
        channel: number("channel")?.unwrap_or(0),
        log,
    })
}

/// A plane of `values` (a field on a grid of `dims`, x fastest): the image's width and height
/// and its values, row by row from the top. The plane's two axes are the other two in order
/// (x and y for z; x and z for y; y and z for x), the second one pointing up.
pub fn plane(
    values: &[f32],
    dims: [usize; 3],
    axis: usize,
    index: usize,
) -> (usize, usize, Vec<f32>) {
    let (a, b) = match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let (w, h) = (dims[a], dims[b]);
    let mut out = Vec::with_capacity(w * h);
    for row in 0..h {
        let vb = h - 1 - row;
        for va in 0..w {
            let mut c = [0usize; 3];
            c[axis] = index;
            c[a] = va;
            c[b] = vb;
            out.push(values[c[0] + dims[0] * (c[1] + dims[1] * c[2])]);
        }
    }
    (w, h, out)
}

/// The colour range `[lo, hi]` of a field: `[0, max]`, or the `LOG_DECADES` below the
/// maximum. `None` when the field has no positive value.
pub fn range(values: &[f32], log: bool) -> Option<(f64, f64)> {
    let max = values.iter().copied().fold(0.0f32, f32::max) as f64;
    (max > 0.0 && max.is_finite()).then(|| {
        if log {
            (max * 10f64.powf(-LOG_DECADES), max)
        } else {
            (0.0, max)
        }
    })
}

/// RGB bytes of `values` through the colour map over `range` (values below it take the
/// lowest colour; a field with no range is all the lowest colour).
pub fn colour(values: &[f32], range: Option<(f64, f64)>, log: bool) -> Vec<u8> {
    let position = |v: f64| -> f64 {
        let Some((lo, hi)) = range else { return 0.0 };
        let t = if log {
            if v <= lo {
                0.0
            } else {
                (v / lo).ln() / (hi / lo).ln()
            }
        } else {
            v / hi
        };
        t.clamp(0.0, 1.0)
    };
    values
        .iter()
        .flat_map(|&v| viridis(position(v as f64)))
        .collect()
}

/// Matplotlib's viridis at nine stops, linearly between them: perceptually even, legible in
/// grey and to colour-blind readers.
fn viridis(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let x = t.clamp(0.0, 1.0) * 8.0;
    let i = (x.floor() as usize).min(7);
    let f = x - i as f64;
    std::array::from_fn(|k| (STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane holds the cells at its index, its second axis pointing up (the first row is
    /// the top), for each axis.
    #[test]
    fn planes_hold_their_cells_with_the_second_axis_up() {
        let dims = [2, 3, 4];
        let values: Vec<f32> = (0..24).map(|v| v as f32).collect();
        let at = |i: usize, j: usize, k: usize| (i + 2 * (j + 3 * k)) as f32;
        let (w, h, z) = plane(&values, dims, 2, 1);
        assert_eq!((w, h), (2, 3));
        assert_eq!(z[0], at(0, 2, 1));
        assert_eq!(z[w * h - 1], at(1, 0, 1));
        let (w, h, y) = plane(&values, dims, 1, 2);
        assert_eq!((w, h), (2, 4));
        assert_eq!(y[1], at(1, 2, 3));
        let (w, h, x) = plane(&values, dims, 0, 1);
        assert_eq!((w, h), (3, 4));
        assert_eq!(x[w * (h - 1)], at(1, 0, 0));
    }

    /// The colour map runs from dark violet to yellow; a log range spans four decades below
    /// the maximum, the maximum taking the top colour and values below the range the bottom.
    #[test]
    fn colours_follow_the_range() {
        let values = [0.0f32, 1e-5, 1e-2, 1.0];
        let log = range(&values, true).unwrap();
        assert!((log.0 - 1e-4).abs() < 1e-12 && log.1 == 1.0);
        let rgb = colour(&values, Some(log), true);
        assert_eq!(&rgb[0..3], &[68, 1, 84]);
        assert_eq!(&rgb[3..6], &[68, 1, 84]);
        assert_eq!(&rgb[9..12], &[253, 231, 37]);
        // Half way in log (1e-2 of 1e-4…1): the middle stop.
        assert_eq!(&rgb[6..9], &[33, 144, 141]);
        assert_eq!(range(&[0.0, 0.0], false), None);
        assert_eq!(colour(&[3.0], None, false), vec![68, 1, 84]);
    }

    #[test]
    fn bad_queries_are_refused_naming_the_parameter() {
        let q = |pairs: &[(&str, &str)]| -> HashMap<String, String> {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        };
        for (pairs, mentions) in [
            (q(&[("field", "heat")]), "field"),
            (q(&[("axis", "w")]), "axis"),
            (q(&[("index", "-1")]), "index"),
            (q(&[("scale", "sqrt")]), "scale"),
        ] {
            let e = parse_slice_query(&pairs).unwrap_err();
            assert!(e.starts_with(mentions), "{e}");
        }
        let ok = parse_slice_query(&q(&[("axis", "x"), ("index", "3")])).unwrap();
        assert_eq!((ok.axis, ok.index, ok.log), (0, Some(3), false));
    }
}
