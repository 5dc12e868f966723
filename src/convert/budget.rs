//! The memory budget: reading available memory, the paper's rule
//! that decides how many points one part (one image) may hold, and [`Budget`],
//! which hands out every share of `--memory` a conversion takes.

/// The smallest budget a conversion keeps to: below it, its fixed needs (the
/// region sample, the count grid, reader windows of at least 65,536 points) come
/// to more than the budget, so parts are sized to it but resident memory is not.
pub const MIN_KEPT: u64 = 64 << 20;

/// Memory the system reports as available (`MemAvailable` of /proc/meminfo).
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    text.lines()
        .find(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<u64>().ok())
        .map(|kb| kb * 1024)
}

/// The default budget: half the available memory, at least 256 MiB, at most 16 GiB
/// (more buys nothing but fewer, larger parts).
pub fn default_budget() -> u64 {
    let avail = available_memory().unwrap_or(4 << 30);
    (avail / 2).clamp(256 << 20, 16 << 30)
}

/// Resident bytes per point while a part is sorted and written with `attributes`
/// attribute bands: the source columns (f64 x y z, f32 attributes), relative
/// positions, packed sort keys and their scratch copy, the permutation, sorted
/// positions, and the output bands.
pub fn bytes_per_point(attributes: usize) -> u64 {
    let source = 24 + 4 * attributes as u64;
    let layout = 12 + 8 + 8 + 4 + 12;
    let bands = 4 * (3 + attributes as u64);
    source + layout + bands
}

/// Fixed overhead kept out of the budget: reader windows, tile buffers, allocator
/// slack.
pub const OVERHEAD: u64 = 48 << 20;

/// One conversion's `--memory`, and the shares of it that each consumer takes:
/// the only place where the budget is divided.
///
/// | share | rule | resident while |
/// |---|---|---|
/// | [`overhead`](Self::overhead) | [`OVERHEAD`], fixed | always: reader windows, tile buffers, allocator slack |
/// | [`part`](Self::part) | `memory - OVERHEAD`, at least 16 MiB | a part is collected, sorted and written: [`points_per_part`](Self::points_per_part) points of [`bytes_per_point`] each |
/// | [`pool`](Self::pool) | `memory / 4` | always: freed large blocks the allocator keeps (`crate::alloc`) |
/// | [`spill`](Self::spill) | `memory / 4`, shared by the regions, 64 KiB to 8 MiB each ([`spill_buffer`](Self::spill_buffer)) | points are distributed to the regions' temporary files (pass 2) or a region is split: no part is held then |
///
/// A reader window holds an eighth of a part's points (at least 65,536:
/// [`window_points`](Self::window_points)); its columns are the part's source
/// columns as they arrive, so it takes no share of its own.
///
/// **How they add up.** The pool is taken before fresh memory is mapped, so it
/// lies inside the live buffers' peak rather than beside it; the spill buffers
/// live only while no part is held. The two peaks are then
/// - holding a part: `overhead + part` ([`holding_part`](Self::holding_part)),
///   which is exactly `memory` from [`MIN_KEPT`] on (below it the 16 MiB floor
///   of the part share exceeds the budget);
/// - spilling: `overhead + pool + spill` at most, counting the pool as if
///   nothing reused it ([`spilling`](Self::spilling)), which is at most
///   `memory` from `2 * OVERHEAD` (96 MiB) on, as long as the regions' 64 KiB
///   floor does not exceed the spill share (up to `memory / 4 / 64 KiB`
///   regions).
///
/// The unit tests check both sums, and that every share is the number the
/// converter used before this type gathered them (outputs stay byte-identical).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budget {
    memory: u64,
}

impl Budget {
    /// The smallest write buffer of one region's temporary file.
    const MIN_SPILL_BUFFER: u64 = 64 << 10;
    /// The largest write buffer of one region's temporary file.
    const MAX_SPILL_BUFFER: u64 = 8 << 20;
    /// The smallest part share (a budget at or below [`OVERHEAD`] still makes
    /// parts of some size).
    const MIN_PART: u64 = 16 << 20;

    /// The budget of `memory` bytes (`--memory`).
    pub fn new(memory: u64) -> Budget {
        Budget { memory }
    }

    /// The whole budget, in bytes.
    pub fn memory(self) -> u64 {
        self.memory
    }

    /// Fixed needs kept out of the other shares ([`OVERHEAD`]).
    pub fn overhead(self) -> u64 {
        OVERHEAD
    }

    /// Bytes one part's points may take while it is sorted and written.
    pub fn part(self) -> u64 {
        self.memory.saturating_sub(OVERHEAD).max(Self::MIN_PART)
    }

    /// Points one part may hold with `attributes` attribute bands (the paper's
    /// rule: when parsed points would exceed the budget, they become an image).
    pub fn points_per_part(self, attributes: usize) -> u64 {
        (self.part() / bytes_per_point(attributes)).clamp(1 << 16, u32::MAX as u64)
    }

    /// Points one reader window holds at most, for parts of `per_part` points.
    pub fn window_points(self, per_part: u64) -> u64 {
        (per_part / 8).max(1 << 16)
    }

    /// Bytes of freed large buffers the allocator keeps for the next ones (a
    /// part's sort keys reuse the input columns' pages, the next part reuses
    /// this one's).
    pub fn pool(self) -> u64 {
        self.memory / 4
    }

    /// [`pool`](Self::pool) as the allocator takes it.
    pub fn pool_limit(self) -> usize {
        self.pool().min(usize::MAX as u64) as usize
    }

    /// Bytes of write buffers of the regions' temporary files, all regions
    /// together (before each region's buffer is clamped: [`spill_buffer`](Self::spill_buffer)).
    pub fn spill(self) -> u64 {
        self.memory / 4
    }

    /// The write buffer of each of `regions` temporary files: an even share of
    /// [`spill`](Self::spill), from 64 KiB to 8 MiB.
    pub fn spill_buffer(self, regions: usize) -> usize {
        (self.spill() / regions.max(1) as u64).clamp(Self::MIN_SPILL_BUFFER, Self::MAX_SPILL_BUFFER)
            as usize
    }

    /// Resident bytes at most while a part is held: overhead and the part's share
    /// (the pool lies inside the part's buffers).
    pub fn holding_part(self) -> u64 {
        self.overhead() + self.part()
    }

    /// Resident bytes at most while `regions` temporary files are written:
    /// overhead, the pool as if nothing reused it, and every region's buffer.
    pub fn spilling(self, regions: usize) -> u64 {
        let buffers = self.spill_buffer(regions) as u64 * regions.max(1) as u64;
        self.overhead() + self.pool() + buffers
    }
}

impl std::fmt::Display for Budget {
    /// One line: `256.0 MiB: 48.0 MiB fixed, 208.0 MiB for a part's points (the
    /// allocator's pool of 64.0 MiB within it), 64.0 MiB of temporary-file
    /// buffers between parts`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::text::bytes;
        write!(
            f,
            "{}: {} fixed, {} for a part's points (the allocator's pool of {} within it), \
             {} of temporary-file buffers between parts",
            bytes(self.memory),
            bytes(self.overhead()),
            bytes(self.part()),
            bytes(self.pool()),
            bytes(self.spill()),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_rule() {
        let n = Budget::new(256 << 20).points_per_part(1);
        assert!(n > 1_000_000 && n < 4_000_000, "{n}");
        assert!(Budget::new(1 << 40).points_per_part(0) <= u32::MAX as u64);
        assert!(default_budget() >= 256 << 20);
    }

    /// Budgets to try: round sizes, one byte either side of them, the thresholds
    /// of the rules, and a spread of odd values.
    fn memories() -> Vec<u64> {
        let mut m = vec![0, 1, 2, 3, 4, 5, 1000, 4095, 4096, u64::MAX / 2, u64::MAX];
        for shift in 10..=44 {
            for base in [1u64 << shift, 3 << (shift - 1), 5 << (shift - 2)] {
                m.extend([base - 1, base, base + 1]);
            }
        }
        for t in [OVERHEAD, OVERHEAD + (16 << 20), MIN_KEPT, 2 * OVERHEAD] {
            m.extend([t - 1, t, t + 1]);
        }
        // 282.5 MiB (bench/remote.sh), 64 MiB (the byte-identity check).
        m.extend([(565 << 20) / 2, 64 << 20]);
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..2000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            m.push(x >> (x % 40));
        }
        m
    }

    const REGIONS: [usize; 16] = [
        0, 1, 2, 3, 4, 5, 7, 8, 31, 64, 100, 144, 1000, 4096, 65_536, 1_000_000,
    ];

    /// The shares as the converter computed them before [`Budget`] (job.rs,
    /// distribute.rs, this file), kept verbatim: the budget must hand out the
    /// same numbers, so conversions stay byte-identical.
    mod before {
        use super::super::{OVERHEAD, bytes_per_point};

        pub fn points_per_part(budget: u64, attributes: usize) -> u64 {
            let usable = budget.saturating_sub(OVERHEAD).max(16 << 20);
            (usable / bytes_per_point(attributes)).clamp(1 << 16, u32::MAX as u64)
        }

        /// `job.rs`: the allocator's pool limit.
        pub fn pool_limit(memory: u64) -> usize {
            (memory / 4).min(usize::MAX as u64) as usize
        }

        /// `job.rs`: the reader's window, from the options' `chunk_points`.
        pub fn chunk_points(chunk_points: usize, per_part: u64) -> usize {
            chunk_points.min((per_part / 8).max(1 << 16) as usize)
        }

        /// `distribute.rs`: each region file's write buffer.
        pub fn spill_buffer(memory: u64, regions: usize) -> usize {
            (memory / 4 / regions.max(1) as u64).clamp(64 << 10, 8 << 20) as usize
        }
    }

    #[test]
    fn shares_are_those_of_before() {
        for m in memories() {
            let b = Budget::new(m);
            assert_eq!(b.memory(), m);
            assert_eq!(b.pool_limit(), before::pool_limit(m), "pool at {m}");
            for attributes in 0..=32 {
                let per_part = b.points_per_part(attributes);
                assert_eq!(
                    per_part,
                    before::points_per_part(m, attributes),
                    "points per part at {m}, {attributes} attributes"
                );
                for chunk in [1, 1 << 16, 1 << 20, usize::MAX] {
                    assert_eq!(
                        chunk.min(b.window_points(per_part) as usize),
                        before::chunk_points(chunk, per_part),
                        "window at {m}, {attributes} attributes, chunk {chunk}"
                    );
                }
            }
            for r in REGIONS {
                assert_eq!(
                    b.spill_buffer(r),
                    before::spill_buffer(m, r),
                    "spill buffer at {m}, {r} regions"
                );
            }
        }
    }

    #[test]
    fn shares_add_up_to_the_budget() {
        for m in memories() {
            let b = Budget::new(m);
            // Every share is a part of the whole, whatever the budget.
            assert!(b.pool() <= m && b.spill() <= m && b.pool() + b.spill() <= m);
            if m >= MIN_KEPT {
                // Holding a part: the fixed needs and the part, exactly the budget;
                // the pool fits inside the part's buffers.
                assert_eq!(b.holding_part(), m, "holding a part at {m}");
                assert!(b.pool() <= b.part(), "pool within the part at {m}");
                assert!(b.spill() <= b.part(), "spill within a part's room at {m}");
            }
            if m >= 2 * OVERHEAD {
                // Spilling, no part held: fixed needs, the whole pool and every
                // region's buffer, while the 64 KiB floor leaves the share kept.
                for r in REGIONS {
                    let floor_kept = r as u64 * Budget::MIN_SPILL_BUFFER <= b.spill();
                    if floor_kept {
                        assert!(b.spilling(r) <= m, "spilling {r} regions at {m}");
                    }
                }
            }
            // The 8 MiB ceiling only ever takes less than the share.
            for r in REGIONS {
                let each = b.spill_buffer(r) as u64;
                if each > Budget::MIN_SPILL_BUFFER {
                    assert!(each * r.max(1) as u64 <= b.spill(), "{r} regions at {m}");
                }
            }
        }
    }

    #[test]
    fn budget_line() {
        let line = Budget::new(256 << 20).to_string();
        assert_eq!(
            line,
            "256.0 MiB: 48.0 MiB fixed, 208.0 MiB for a part's points (the allocator's \
             pool of 64.0 MiB within it), 64.0 MiB of temporary-file buffers between parts"
        );
    }
}
