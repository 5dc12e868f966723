//! pcimg's foundation, below every other crate: the point columns the input readers
//! hand to the store ([`points`]), terminal-safe text ([`text`]), large buffers
//! ([`bigvec`]), the process's pool of large blocks ([`alloc`]), wall and CPU
//! clocks ([`clock`]), a deterministic generator for synthetic data ([`rng`]), and
//! local disks' room, mount points and locks ([`disk`]: full-disk messages, runs
//! that were killed).

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

#[cfg(target_os = "linux")]
pub mod alloc;
/// Elsewhere the system allocator serves everything; the pool's controls do nothing.
#[cfg(not(target_os = "linux"))]
pub mod alloc {
    pub fn set_pool_limit(_bytes: usize) {}
    pub fn release_pool() {}
    pub fn fresh_bytes() -> usize {
        0
    }
}
pub mod bigvec;
pub mod clock;
#[cfg(unix)]
pub mod disk;
pub mod points;
pub mod rng;
pub mod text;
pub mod time;
