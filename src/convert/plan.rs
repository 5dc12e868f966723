//! The spatial plan: the regions a conversion of several parts splits the input
//! into, placed by a count grid filled from the first pass's sample, each with
//! the origin its points are stored around, and what writing their parts needs.
//! A [`Plan`] is plain data (it can be written to a file and read back: as JSON,
//! its f64 values come back exact only with serde_json's `float_roundtrip`); the
//! grid's cell → region map that pass 2 looks points up in is made from it
//! ([`Cells`]).

use super::job::Job;
use super::partition::{self, CountGrid, Region};
use super::sample::Sample;
use super::scan::Overflow;
use crate::ingest::ReadOptions;
use crate::points::{Attribute, Bounds, PointColumns};
use crate::store::{Compression, Layout};
use std::path::PathBuf;

/// What one stage of a spatial conversion hands the next: where every point
/// goes, and how the parts are written.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Plan {
    /// The input files, read one after the other as one point cloud.
    pub inputs: Vec<PathBuf>,
    /// How they are read.
    pub read: ReadOptions,
    /// The bounds the count grid covers: `CountGrid::new(grid_bounds)` is the
    /// grid the regions' cells belong to.
    pub grid_bounds: Bounds,
    /// The regions, boxes of grid cells (with the points the sample gave each).
    /// A point in a cell of no region joins the nearest region.
    pub regions: Vec<Region>,
    /// Each region's origin, which its points are stored relative to (the centre
    /// of its occupied cells, or of its points' bounds where they reach farther).
    pub origins: Vec<[f64; 3]>,
    /// The attributes every part stores: name and offset, in band order.
    pub attributes: Vec<(String, f64)>,
    /// The input's points (an estimate where the first pass sampled).
    pub points: u64,
    /// Points one part holds at most.
    pub points_per_part: u64,
    pub compression: Compression,
    /// The LERC codecs' error bound for the coordinates (`--max-error`), when
    /// given; else each shard takes the input's lattice (plans before it: none).
    #[serde(default)]
    pub max_error: Option<f64>,
    /// `--precision`, when given (plans before it: none).
    #[serde(default)]
    pub precision: Option<f64>,
    pub layout: Layout,
    /// `--zstd-level`, when given (plans before it: none, each shard choosing
    /// by the input's size as `convert` does).
    #[serde(default)]
    pub zstd_level: Option<i32>,
}

/// A plan's count grid and, for each of its cells, the index of its region
/// (`u32::MAX` for cells of no region).
pub(super) struct Cells {
    pub(super) grid: CountGrid,
    pub(super) cell_region: Vec<u32>,
}

impl Cells {
    /// The cells of a plan read back (its grid rebuilt from its bounds): what a
    /// stage given only the plan looks points up in.
    #[allow(dead_code)]
    pub(super) fn of(plan: &Plan) -> Cells {
        let grid = CountGrid::new(plan.grid_bounds);
        let cell_region = partition::cell_regions(&grid, &plan.regions);
        Cells { grid, cell_region }
    }
}

/// Places regions from the first pass's sample.
pub(super) struct Placer<'a> {
    sample: &'a Sample,
    /// The sample's points one region holds at most: a part's worth, with
    /// margin for the sample's error.
    target: u64,
    /// The widest a region may spread on each axis (`super::max_extent`).
    max_extent: [f64; 3],
}

impl<'a> Placer<'a> {
    pub(super) fn new(sample: &'a Sample, per_part: u64, max_extent: [f64; 3]) -> Self {
        let scale = sample.seen as f64 / sample.pts.len().max(1) as f64;
        let target = ((per_part as f64 * 0.85) / scale).max(1.0) as u64;
        Placer {
            sample,
            target,
            max_extent,
        }
    }

    /// Regions over `bounds` from the sample, grid cells marked in `occupied`
    /// counted as holding a point at least (see `distribute::regions`), and the
    /// origin of each.
    fn place(&self, bounds: Bounds, occupied: &[bool]) -> (Cells, Vec<Region>, Vec<[f64; 3]>) {
        let mut grid = CountGrid::new(bounds);
        for p in &self.sample.pts {
            grid.add(*p);
        }
        for (c, _) in grid.counts.iter_mut().zip(occupied).filter(|(_, o)| **o) {
            *c = (*c).max(1);
        }
        let regions = partition::split(&grid, self.target, self.max_extent);
        let cell_region = partition::cell_regions(&grid, &regions);
        let origins: Vec<[f64; 3]> = regions
            .iter()
            .map(|r| partition::occupied(&grid, *r).centre(&grid))
            .collect();
        (Cells { grid, cell_region }, regions, origins)
    }
}

impl Plan {
    /// The plan of the regions the scan's sample places over its bounds.
    pub(super) fn new(job: &Job, placer: &Placer, over: &Overflow) -> (Plan, Cells) {
        let (cells, regions, origins) = placer.place(over.bounds, &[]);
        let plan = Plan {
            inputs: job.inputs.to_vec(),
            read: job.read.clone(),
            grid_bounds: over.bounds,
            regions,
            origins,
            attributes: over
                .like
                .attributes
                .iter()
                .map(|a| (a.name.clone(), a.offset))
                .collect(),
            points: over.points,
            points_per_part: job.per_part,
            compression: job.o.compression,
            max_error: job.o.max_error,
            precision: job.o.precision,
            layout: job.o.layout,
            zstd_level: job.o.zstd_level,
        };
        (plan, cells)
    }

    /// Places the regions again, over `bounds`, cells marked in `occupied`
    /// counted as holding a point at least.
    pub(super) fn place_again(
        &mut self,
        placer: &Placer,
        bounds: Bounds,
        occupied: &[bool],
    ) -> Cells {
        let (cells, regions, origins) = placer.place(bounds, occupied);
        self.grid_bounds = bounds;
        self.regions = regions;
        self.origins = origins;
        cells
    }

    /// Columns with no points and the plan's attributes (names and offsets):
    /// what chunks are brought to, and spilled records decoded as.
    pub(super) fn like(&self) -> PointColumns {
        PointColumns {
            attributes: self
                .attributes
                .iter()
                .map(|(name, offset)| Attribute {
                    name: name.clone(),
                    offset: *offset,
                    values: Vec::new(),
                })
                .collect(),
            ..PointColumns::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plan's cells made from it alone are those it was placed with, and it
    /// reads back from JSON.
    #[test]
    fn plan_round_trips_and_rebuilds_its_cells() {
        let mut sample = Sample::new(1 << 16);
        let mut c = PointColumns::default();
        let mut r = crate::synth::Rng::new(7);
        for _ in 0..50_000 {
            c.x.push(r.f64() * 300.0);
            c.y.push(r.f64() * 200.0);
            c.z.push(r.f64() * 10.0);
        }
        sample.add(&c, 1);
        let placer = Placer::new(&sample, 10_000, [crate::convert::MAX_EXTENT; 3]);
        let bounds = c.bounds();
        let (cells, regions, origins) = placer.place(bounds, &[]);
        assert!(regions.len() > 1);
        let plan = Plan {
            inputs: vec!["a.las".into(), "b.las".into()],
            read: ReadOptions::default(),
            grid_bounds: bounds,
            regions,
            origins,
            attributes: vec![("intensity".into(), 0.0), ("gps_time".into(), 3e8)],
            points: 50_000,
            points_per_part: 10_000,
            compression: Compression::Zstd,
            max_error: Some(0.005),
            precision: None,
            layout: Layout::Hilbert,
            zstd_level: Some(6),
        };
        let again = Cells::of(&plan);
        assert_eq!(again.grid.dims, cells.grid.dims);
        assert_eq!(again.cell_region, cells.cell_region);
        // (serde_json without its `float_roundtrip` feature may move an f64 by
        // its last bit, so those are compared to within that.)
        let json = serde_json::to_string(&plan).unwrap();
        let back: Plan = serde_json::from_str(&json).unwrap();
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(1.0);
        assert!((0..3).all(|a| near(back.grid_bounds.max[a], plan.grid_bounds.max[a])));
        assert!(
            back.origins
                .iter()
                .flatten()
                .zip(plan.origins.iter().flatten())
                .all(|(a, b)| near(*a, *b))
        );
        assert_eq!(back.regions, plan.regions);
        assert_eq!(back.inputs, plan.inputs);
        assert_eq!(back.read, plan.read);
        assert_eq!(back.like().attributes[1].offset, 3e8);
    }
}
