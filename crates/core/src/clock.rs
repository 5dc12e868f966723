//! Wall and CPU time of the phases a conversion reports (`convert --timings`):
//! the CPU time is the whole process's (every thread, user and system), so a
//! phase's CPU over its wall time says how many cores it kept busy.

use std::time::{Duration, Instant};

/// A wall time and the process's CPU time over it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Span {
    pub wall: Duration,
    pub cpu: Duration,
}

impl std::ops::Add for Span {
    type Output = Span;
    fn add(self, o: Span) -> Span {
        Span {
            wall: self.wall + o.wall,
            cpu: self.cpu + o.cpu,
        }
    }
}

impl Span {
    pub fn saturating_sub(self, o: Span) -> Span {
        Span {
            wall: self.wall.saturating_sub(o.wall),
            cpu: self.cpu.saturating_sub(o.cpu),
        }
    }

    /// Cores kept busy on average (CPU time over wall time; 0 for no time).
    pub fn cores(self) -> f64 {
        let w = self.wall.as_secs_f64();
        if w > 0.0 {
            self.cpu.as_secs_f64() / w
        } else {
            0.0
        }
    }
}

/// A point in time: the wall clock and the process's CPU time so far.
#[derive(Debug, Clone, Copy)]
pub struct Stamp {
    wall: Instant,
    cpu: Duration,
}

impl Stamp {
    pub fn now() -> Stamp {
        Stamp {
            wall: Instant::now(),
            cpu: process_cpu(),
        }
    }

    /// The span from this stamp to now.
    pub fn elapsed(&self) -> Span {
        Span {
            wall: self.wall.elapsed(),
            cpu: process_cpu().saturating_sub(self.cpu),
        }
    }
}

/// User and system CPU time of the process so far (zero where unknown).
#[cfg(unix)]
pub(crate) fn process_cpu() -> Duration {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given; RUSAGE_SELF is always valid.
    let r = unsafe { libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr()) };
    if r != 0 {
        return Duration::ZERO;
    }
    // SAFETY: initialized by the successful call above (and zeroed before).
    let u = unsafe { u.assume_init() };
    let tv = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec.max(0) as u64) + Duration::from_micros(t.tv_usec.max(0) as u64)
    };
    tv(u.ru_utime) + tv(u.ru_stime)
}

#[cfg(not(unix))]
pub(crate) fn process_cpu() -> Duration {
    Duration::ZERO
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn busy_work_shows_as_cpu_time() {
        let t = Stamp::now();
        let mut x = 0u64;
        while t.elapsed().wall < Duration::from_millis(60) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let s = t.elapsed();
        // One thread spinning: close to one core (the clock ticks coarsely).
        assert!(s.cpu >= Duration::from_millis(20), "{s:?}");
        assert!(s.cores() > 0.3 && s.cores() < 2.5, "{s:?}");
        let d = s.saturating_sub(Span {
            wall: s.wall * 2,
            cpu: Duration::ZERO,
        });
        assert_eq!((d.wall, d.cpu), (Duration::ZERO, s.cpu));
        assert_eq!(Span::default().cores(), 0.0);
    }
}
