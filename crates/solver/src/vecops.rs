//! Deterministic parallel vector kernels: fixed-size chunks, partial sums reduced in order,
//! so a solve gives the same bits on every run regardless of thread scheduling.

use rayon::prelude::*;

/// Chunk length for the parallel loops (large enough to amortise rayon's overhead).
pub(crate) const CHUNK: usize = 8192;

/// Preallocated per-chunk partial sums for reductions.
pub(crate) struct Reducer {
    partials: Vec<f64>,
}

impl Reducer {
    pub(crate) fn new(n: usize) -> Self {
        Self {
            partials: vec![0.0; n.div_ceil(CHUNK).max(1)],
        }
    }

    /// `Σ_chunks f(range)`, chunks evaluated in parallel and summed in order.
    pub(crate) fn sum<F>(&mut self, n: usize, f: F) -> f64
    where
        F: Fn(std::ops::Range<usize>) -> f64 + Sync,
    {
        let chunks = n.div_ceil(CHUNK);
        if chunks <= 1 {
            return f(0..n);
        }
        self.partials[..chunks]
            .par_iter_mut()
            .enumerate()
            .for_each(|(c, p)| *p = f(c * CHUNK..((c + 1) * CHUNK).min(n)));
        self.partials[..chunks].iter().sum()
    }

    /// Runs `f(offset, chunk)` over chunks of `out` in parallel and returns the ordered sum
    /// of what it returns (a fused update-and-reduce).
    pub(crate) fn update<F>(&mut self, out: &mut [f64], f: F) -> f64
    where
        F: Fn(usize, &mut [f64]) -> f64 + Sync,
    {
        let n = out.len();
        let chunks = n.div_ceil(CHUNK);
        if chunks <= 1 {
            return f(0, out);
        }
        self.partials[..chunks]
            .par_iter_mut()
            .zip(out.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(c, (p, chunk))| *p = f(c * CHUNK, chunk));
        self.partials[..chunks].iter().sum()
    }

    pub(crate) fn dot(&mut self, a: &[f64], b: &[f64]) -> f64 {
        self.sum(a.len(), |r| {
            a[r.clone()].iter().zip(&b[r]).map(|(x, y)| x * y).sum()
        })
    }

    pub(crate) fn norm(&mut self, a: &[f64]) -> f64 {
        self.dot(a, a).sqrt()
    }

    /// `Σ w_i a_i b_i`.
    pub(crate) fn weighted_dot(&mut self, w: &[f64], a: &[f64], b: &[f64]) -> f64 {
        self.sum(a.len(), |r| {
            w[r.clone()]
                .iter()
                .zip(&a[r.clone()])
                .zip(&b[r])
                .map(|((w, x), y)| w * x * y)
                .sum()
        })
    }
}

/// Parallel elementwise map into `out`: `out[i] = f(i, out[i])`.
pub(crate) fn for_each_mut<F>(out: &mut [f64], f: F)
where
    F: Fn(usize, f64) -> f64 + Sync,
{
    if out.len() <= CHUNK {
        out.iter_mut().enumerate().for_each(|(i, v)| *v = f(i, *v));
        return;
    }
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let off = c * CHUNK;
            chunk
                .iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = f(off + i, *v));
        });
}

/// The residual `r = E − (g − K g)` written over `kg = K g`, and its squared norm.
pub(crate) fn residual_in_place(
    red: &mut Reducer,
    kg: &mut [f64],
    source: &[f64],
    g: &[f64],
) -> f64 {
    red.update(kg, |off, chunk| {
        let mut s = 0.0;
        for (i, v) in chunk.iter_mut().enumerate() {
            let k = off + i;
            *v += source[k] - g[k];
            s += *v * *v;
        }
        s
    })
}
