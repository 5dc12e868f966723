//! The first pass's region sample: a fixed-memory, even sample of the points'
//! positions, from which the count grid that places the spatial regions is
//! filled. Points a sampling reader delivers stand for several points each.

use crate::points::PointColumns;

/// A fixed-memory sample of a stream: keeps every `stride`-th point, halving
/// itself and doubling the stride when full. A point delivered by a sampling
/// reader stands for `weight` points of the stream, so the sample stays even over
/// the input whether it was read whole or sampled.
pub(super) struct Sample {
    pub(super) pts: Vec<[f64; 3]>,
    stride: u64,
    /// Points of the stream so far (weighted).
    pub(super) seen: u64,
    cap: usize,
}

impl Sample {
    pub(super) fn new(cap: usize) -> Self {
        Sample {
            pts: Vec::new(),
            stride: 1,
            seen: 0,
            cap,
        }
    }

    /// Adds the points of `c`, each standing for `weight` (≥ 1) points.
    pub(super) fn add(&mut self, c: &PointColumns, weight: u64) {
        let w = weight.max(1);
        let n = c.len() as u64;
        let end = self.seen + n * w;
        // Point i covers stream positions seen + i*w .. seen + (i+1)*w; it is
        // kept once for every multiple of the stride among them (so the sample
        // holds one entry per `stride` positions everywhere, and halving it keeps
        // that true).
        let mut next = self.seen.next_multiple_of(self.stride);
        while next < end {
            let i = ((next - self.seen) / w) as usize;
            self.pts.push([c.x[i], c.y[i], c.z[i]]);
            if self.pts.len() >= self.cap {
                let mut k = 0;
                self.pts.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                self.stride *= 2;
                next = (next + 1).next_multiple_of(self.stride);
            } else {
                next += self.stride;
            }
        }
        self.seen = end;
    }
}

/// Default [`super::ConvertOptions::sample_points`]: twice the points the region
/// sample keeps, so every sampled window contributes (measured: regions within
/// ±10% of their estimate on the benchmark scan).
pub const DEFAULT_SAMPLE_POINTS: u64 = 1 << 22;

/// The fewest points a sample reads, whatever `sample_points` asks (fewer would
/// make pieces shorter than a line or a LAS window, sampling more than asked).
pub(super) const MIN_SAMPLE: u64 = 1 << 14;

#[cfg(test)]
mod tests {
    use super::*;

    /// Points whose x is their position in the stream.
    fn run(from: u64, count: u64, step: u64) -> PointColumns {
        let x: Vec<f64> = (0..count).map(|i| (from + i * step) as f64).collect();
        PointColumns {
            y: vec![0.0; x.len()],
            z: vec![0.0; x.len()],
            x,
            attributes: Vec::new(),
        }
    }

    /// A stream read whole, then sampled one point in ten: the sample is even
    /// over the stream's positions, not crowded where it was read whole.
    #[test]
    fn weighted_sample_is_even_over_the_stream() {
        let mut s = Sample::new(4096);
        s.add(&run(0, 30_000, 1), 1);
        s.add(&run(30_000, 27_000, 10), 10);
        assert_eq!(s.seen, 300_000);
        let mut bins = [0usize; 10];
        for p in &s.pts {
            bins[(p[0] / 30_000.0) as usize] += 1;
        }
        let mean = s.pts.len() as f64 / 10.0;
        assert!(
            bins.iter().all(|&b| (b as f64 - mean).abs() < 0.05 * mean),
            "{bins:?}"
        );
        // Unweighted, it keeps exactly every stride-th point.
        let mut s = Sample::new(1000);
        s.add(&run(0, 5000, 1), 1);
        assert!(s.pts.iter().all(|p| (p[0] as u64).is_multiple_of(s.stride)));
        assert_eq!(s.pts.len() as u64, 5000 / s.stride);
    }
}
