//! Third-party decoders (the `las` and `laz` crates) run on untrusted input, and a
//! corrupt file can make them panic. [`contain`] runs one: its panic becomes `None`
//! for the caller to report as an error naming the file, and Rust's panic message
//! (with its source path) stays off the user's terminal. Panics anywhere else are
//! printed as before.

use std::cell::Cell;
use std::sync::Once;

thread_local! {
    /// How many [`contain`] calls this thread is inside.
    static INSIDE: Cell<u32> = const { Cell::new(0) };
}

/// Runs `f`; `None` if it panicked, and then nothing was printed.
pub(crate) fn contain<T>(f: impl FnOnce() -> T) -> Option<T> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if INSIDE.with(Cell::get) == 0 {
                previous(info);
            }
        }));
    });
    INSIDE.with(|n| n.set(n.get() + 1));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    INSIDE.with(|n| n.set(n.get() - 1));
    r.ok()
}

#[cfg(test)]
mod tests {
    use super::contain;

    #[test]
    fn a_panic_becomes_none_and_a_value_passes() {
        assert_eq!(contain(|| 7), Some(7));
        let r: Option<()> = contain(|| panic!("corrupt input"));
        assert_eq!(r, None);
        // Nested calls keep the count right.
        assert_eq!(
            contain(|| contain(|| -> u8 { panic!("inner") })),
            Some(None)
        );
    }
}
