//! Zstd frames whose only matches are runs of one byte value (offset 1), found
//! by our own scan and handed to Zstd's entropy stage
//! (`ZSTD_compressSequences`).
//!
//! For tiles of a small whole-number band (return numbers, classes, flags:
//! once the floating-point predictor has split and differenced them, three
//! byte planes of zeros and one of small differences that repeat), Zstd's
//! match search at level 1 spends most of its time probing the noisy plane for
//! matches it seldom finds. Runs found by a vector scan are cheaper and,
//! on those bands, no larger (history 51). Any Zstd decoder reads the frames.

use std::cell::RefCell;
use zstd::zstd_safe::zstd_sys as sys;

/// The shortest run a match is made of (bytes equal to the one before).
const MIN_RUN: usize = 8;

struct Ctx(*mut sys::ZSTD_CCtx);

impl Drop for Ctx {
    fn drop(&mut self) {
        // SAFETY: created by ZSTD_createCCtx, freed once.
        unsafe { sys::ZSTD_freeCCtx(self.0) };
    }
}

thread_local! {
    static CTX: RefCell<Option<Ctx>> = const { RefCell::new(None) };
    /// The sequences of a tile and its bits of equal bytes, kept between tiles.
    static SCRATCH: RefCell<(Vec<sys::ZSTD_Sequence>, Vec<u64>)> =
        const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Positions `1..n` of `raw` at which the byte equals the one before, as bits
/// (bit `k % 64` of word `k / 64` for position `k`; position 0 never).
fn equal_bits(raw: &[u8], words: &mut Vec<u64>) {
    let n = raw.len();
    words.clear();
    words.resize(n.div_ceil(64), 0);
    #[cfg(target_arch = "x86_64")]
    let start = {
        use std::arch::x86_64::*;
        // Positions 1..=16k (16 at a time: bytes i..i+16 against i-1..i+15).
        let mut i = 1;
        while i + 16 <= n {
            // SAFETY: both loads read 16 bytes inside `raw` (i >= 1, i + 16 <= n).
            let m = unsafe {
                let a = _mm_loadu_si128(raw.as_ptr().add(i) as *const __m128i);
                let b = _mm_loadu_si128(raw.as_ptr().add(i - 1) as *const __m128i);
                _mm_movemask_epi8(_mm_cmpeq_epi8(a, b)) as u32 as u64
            };
            let (w, s) = (i / 64, i % 64);
            words[w] |= m << s;
            if s > 48 {
                words[w + 1] |= m >> (64 - s);
            }
            i += 16;
        }
        i
    };
    #[cfg(not(target_arch = "x86_64"))]
    let start = 1;
    for k in start.max(1)..n {
        if raw[k] == raw[k - 1] {
            words[k / 64] |= 1 << (k % 64);
        }
    }
}

/// The sequences of `raw`'s runs (each at least [`MIN_RUN`] bytes equal to the
/// one before them) into `seqs` (`words`: scratch for [`equal_bits`]); returns
/// the literal bytes left, or `None` once they pass `max_literals`.
fn find_runs(
    raw: &[u8],
    max_literals: usize,
    seqs: &mut Vec<sys::ZSTD_Sequence>,
    words: &mut Vec<u64>,
) -> Option<usize> {
    equal_bits(raw, words);
    seqs.clear();
    let (mut anchor, mut literals) = (0usize, 0usize);
    let mut run: Option<usize> = None;
    let mut end_run = |start: usize, end: usize, anchor: &mut usize, literals: &mut usize| {
        if end - start >= MIN_RUN {
            seqs.push(sys::ZSTD_Sequence {
                offset: 1,
                litLength: (start - *anchor) as u32,
                matchLength: (end - start) as u32,
                rep: 0,
            });
            *literals += start - *anchor;
            *anchor = end;
        }
    };
    for (w, &m) in words.iter().enumerate() {
        let base = w * 64;
        match (run, m) {
            (Some(_), u64::MAX) | (None, 0) => continue,
            _ => {}
        }
        let mut bit = 0u32;
        while bit < 64 {
            match run {
                Some(start) => {
                    let rest = !m >> bit;
                    if rest == 0 {
                        break;
                    }
                    bit += rest.trailing_zeros();
                    end_run(start, base + bit as usize, &mut anchor, &mut literals);
                    run = None;
                }
                None => {
                    let rest = m >> bit;
                    if rest == 0 {
                        break;
                    }
                    bit += rest.trailing_zeros();
                    run = Some(base + bit as usize);
                }
            }
        }
        if literals > max_literals {
            return None;
        }
    }
    if let Some(start) = run {
        end_run(start, raw.len(), &mut anchor, &mut literals);
    }
    literals += raw.len() - anchor;
    (literals <= max_literals).then_some(literals)
}

/// `raw` as one Zstd frame of runs at `level`'s entropy coding into `out`
/// (cleared first, its allocation reused), if its runs leave at most
/// `max_literals` literal bytes; `Ok(false)` otherwise.
pub(crate) fn compress_runs(
    raw: &[u8],
    level: i32,
    max_literals: usize,
    out: &mut Vec<u8>,
) -> std::io::Result<bool> {
    SCRATCH.with_borrow_mut(|(seqs, words)| {
        if find_runs(raw, max_literals, seqs, words).is_none() {
            return Ok(false);
        }
        CTX.with_borrow_mut(|ctx| {
            let c = match ctx {
                Some(c) => c.0,
                None => {
                    // SAFETY: a fresh context, owned by `Ctx`.
                    let p = unsafe { sys::ZSTD_createCCtx() };
                    if p.is_null() {
                        return Err(std::io::Error::other("zstd: no memory for a context"));
                    }
                    ctx.insert(Ctx(p)).0
                }
            };
            let check = |r: usize| -> std::io::Result<usize> {
                // SAFETY: ZSTD_isError takes any value.
                if unsafe { sys::ZSTD_isError(r) } != 0 {
                    // SAFETY: ZSTD_getErrorName gives a static C string for
                    // any value.
                    let name = unsafe { std::ffi::CStr::from_ptr(sys::ZSTD_getErrorName(r)) };
                    return Err(std::io::Error::other(format!(
                        "zstd: {}",
                        name.to_string_lossy()
                    )));
                }
                Ok(r)
            };
            // SAFETY: `c` is a live context; the parameters are Zstd's own.
            unsafe {
                check(sys::ZSTD_CCtx_reset(
                    c,
                    sys::ZSTD_ResetDirective::ZSTD_reset_session_and_parameters,
                ))?;
                check(sys::ZSTD_CCtx_setParameter(
                    c,
                    sys::ZSTD_cParameter::ZSTD_c_compressionLevel,
                    level,
                ))?;
                // At most the shortest run (Zstd's largest: 7).
                check(sys::ZSTD_CCtx_setParameter(
                    c,
                    sys::ZSTD_cParameter::ZSTD_c_minMatch,
                    7,
                ))?;
                check(sys::ZSTD_CCtx_setParameter(
                    c,
                    sys::ZSTD_cParameter::ZSTD_c_experimentalParam12,
                    i32::from(cfg!(debug_assertions)),
                ))?;
            }
            let cap = zstd::zstd_safe::compress_bound(raw.len());
            out.clear();
            out.reserve(cap);
            // SAFETY: `out` has `cap` bytes of room; the sequences cover
            // `raw` in order, each match of offset 1 after at least one byte.
            let n = check(unsafe {
                sys::ZSTD_compressSequences(
                    c,
                    out.as_mut_ptr().cast(),
                    cap,
                    seqs.as_ptr(),
                    seqs.len(),
                    raw.as_ptr().cast(),
                    raw.len(),
                )
            })?;
            // SAFETY: Zstd wrote `n` bytes.
            unsafe { out.set_len(n) };
            Ok(true)
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vector scan marks exactly the bytes equal to the one before, at
    /// every length around its 16- and 64-byte steps.
    #[test]
    fn equal_bits_are_the_plain_comparison() {
        let mut r = crate::rng::Rng::new(17);
        for n in [
            0usize, 1, 2, 15, 16, 17, 31, 63, 64, 65, 127, 128, 129, 1000,
        ] {
            let raw: Vec<u8> = (0..n).map(|_| (r.next_u64() % 3) as u8).collect();
            let mut words = Vec::new();
            equal_bits(&raw, &mut words);
            for k in 0..n {
                let bit = words[k / 64] >> (k % 64) & 1 == 1;
                assert_eq!(bit, k > 0 && raw[k] == raw[k - 1], "length {n}, byte {k}");
            }
            assert!(
                words
                    .iter()
                    .enumerate()
                    .all(|(w, &m)| w * 64 + 64 <= n || m >> (n - w * 64) == 0),
                "length {n}: bits past the end"
            );
        }
    }

    /// Sequences cover the bytes in order, every match a run of at least
    /// [`MIN_RUN`] bytes equal to the one before it, and no such run of the
    /// input is left as literals.
    #[test]
    fn runs_are_every_long_run_and_nothing_else() {
        let mut r = crate::rng::Rng::new(23);
        let mut raw = Vec::new();
        for _ in 0..2000 {
            let b = (r.next_u64() % 4) as u8;
            let len = 1 + (r.next_u64() % 20) as usize;
            raw.extend(std::iter::repeat_n(b, len));
        }
        let mut seqs = Vec::new();
        let literals = find_runs(&raw, raw.len(), &mut seqs, &mut Vec::new()).unwrap();
        let mut at = 0;
        let mut matched = 0;
        for s in &seqs {
            at += s.litLength as usize;
            let len = s.matchLength as usize;
            assert_eq!(s.offset, 1);
            assert!(len >= MIN_RUN && at >= 1);
            assert!(raw[at..at + len].iter().all(|&b| b == raw[at - 1]));
            at += len;
            matched += len;
        }
        assert_eq!(literals + matched, raw.len());
        // Every stretch of MIN_RUN + 1 equal bytes lies inside some match
        // (less its first byte, which a match repeats).
        let mut inside = vec![false; raw.len()];
        let mut at = 0;
        for s in &seqs {
            at += s.litLength as usize;
            inside[at..at + s.matchLength as usize].fill(true);
            at += s.matchLength as usize;
        }
        for k in MIN_RUN..raw.len() {
            if raw[k - MIN_RUN..=k].iter().all(|&b| b == raw[k]) {
                assert!(inside[k], "byte {k} ends a long run but was left a literal");
            }
        }
        // Past the literals allowed, none.
        assert!(find_runs(&raw, literals - 1, &mut seqs, &mut Vec::new()).is_none());
    }

    /// Frames of runs decode (with Zstd's own decoder) to the input: planes
    /// of zeros and of small repeating differences, a constant buffer, and
    /// noise that leaves too many literals (refused).
    #[test]
    fn frames_of_runs_decode_to_their_input() {
        let mut r = crate::rng::Rng::new(31);
        let mut planes = Vec::new();
        for _ in 0..256 {
            planes.push(0x4B);
            planes.extend(std::iter::repeat_n(0u8, 767));
            let mut v = 0u8;
            for _ in 0..256 {
                if r.next_u64().is_multiple_of(8) {
                    v = (r.next_u64() % 5) as u8;
                }
                planes.push(v);
            }
        }
        let noise: Vec<u8> = (0..65536).map(|_| r.next_u64() as u8).collect();
        for (name, raw) in [
            ("planes", planes),
            ("zeros", vec![0u8; 65536]),
            ("noise", noise),
        ] {
            let most = raw.len() * 15 / 100;
            let mut frame = Vec::new();
            match compress_runs(&raw, 1, most, &mut frame)
                .unwrap()
                .then_some(frame)
            {
                Some(frame) => {
                    assert!(frame.len() < raw.len() / 4, "{name}: {} bytes", frame.len());
                    let back = zstd::bulk::decompress(&frame, raw.len()).unwrap();
                    assert!(back == raw, "{name}");
                }
                None => assert_eq!(name, "noise", "{name} refused"),
            }
        }
    }
}
