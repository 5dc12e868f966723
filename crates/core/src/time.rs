//! GPS time kept exactly in `f32` columns.
//!
//! Every attribute is an `f32` column plus an `f64` offset ([`crate::points`]);
//! a LAS file's `gps_time` is an `f64`, of which `f32` around one offset keeps
//! about half the bits (within 0.5 µs on a survey of seconds, milliseconds on
//! one of days). The column `gps_time` stays that value, which every viewer,
//! filter and ramp uses as before, and three whole-number columns beside it
//! ([`EXACT_BANDS`]) give back the source's `f64` bit for bit:
//!
//! - `gps_time_lo`: the low bits of the time's ordered key (its bits read as
//!   an integer that orders like the doubles, consecutive doubles one apart):
//!   8, 16 or 23 bits, the fewest whole bytes the `f32` value leaves unknown
//!   (16 on a survey of up to about 4 minutes around the offset in GPS week
//!   seconds, 6 days in adjusted standard time). How many is a function of
//!   the stored value and the offset alone ([`low_bits`]), so a reader knows
//!   it too.
//! - `gps_time_mid`, `gps_time_hi`: how many steps of 2^bits the true key lies
//!   from the key nearest the `f32` value with those low bits. Zero whenever
//!   the low bits suffice, so they cost next to nothing; further out (a time
//!   of 0 among times of 10^8, a NaN) they carry the rest, up to the full 64
//!   bits.
//!
//! A `gps_time_lo` of NaN means the point keeps only the `f32` value: the
//! pyramid's coarser levels (an even sample, for viewing and light copies)
//! store NaN there, because in their order, points far apart in time side by
//! side, the low bits cost four bytes a point.
//!
//! Our own code: this is a layout of our columns, not a codec a crate offers.
//! Measured in `bench/RESULTS.md` ("Compact storage").

/// The bands that make `gps_time` exact, in the order they follow it.
pub const EXACT_BANDS: [&str; 3] = ["gps_time_lo", "gps_time_mid", "gps_time_hi"];

/// The range [`EXACT_BANDS`]' values may take, which a part records as
/// theirs (its statistics), whatever they hold: whole numbers in `[-2^23,
/// 2^23)`.
pub const EXACT_RANGE: (f32, f32) = (-8_388_608.0, 8_388_607.0);
/// [`EXACT_RANGE`] in `f64`.
pub const EXACT_RANGE_F64: (f64, f64) = (-8_388_608.0, 8_388_607.0);

/// The band they make exact.
pub const TIME_BAND: &str = "gps_time";

/// The columns of [`EXACT_BANDS`] that `column` finds by name, when it
/// finds all three: what [`join`] takes beside the Float32.
pub fn exact_columns<'a>(column: impl Fn(&str) -> Option<&'a [f32]>) -> Option<[&'a [f32]; 3]> {
    let [lo, mid, hi] = EXACT_BANDS.map(column);
    Some([lo?, mid?, hi?])
}

/// Whether `name` is one of [`EXACT_BANDS`]: a part of another band's value,
/// which programs that list bands to users (info, export, the legend) leave
/// out.
pub fn is_exact_band(name: &str) -> bool {
    EXACT_BANDS.contains(&name)
}

/// The most low bits [`low_bits`] gives; `gps_time_mid` and `gps_time_hi`
/// hold 23 bits each above them.
const LOW: u32 = 23;

/// How many low bits of the key `gps_time_lo` holds for the stored value
/// `offset + v`: 8, 16 or 23, the first with `2^(b-1)` at least the distance,
/// in ulps of that value, from it to any time that gives it (half an `f32`
/// ulp of `v`, two roundings of `f64` arithmetic and a margin); 23 for values
/// that are not finite, or 0.
#[inline(always)]
pub fn low_bits(offset: f64, v: f32) -> u32 {
    // From the numbers' exponents (biased), in whole numbers: the measure in
    // floating point took a tenth of a conversion's time.
    let t = offset + v as f64;
    let et = (t.to_bits() >> 52) as i64 & 0x7ff;
    let ev = (v.to_bits() >> 23) as i64 & 0xff;
    let em = ((offset.to_bits() >> 52) as i64 & 0x7ff).max(et);
    if et == 0 || et == 0x7ff || ev == 0xff || em + 1 >= 0x7ff {
        return LOW;
    }
    // Half an f32 ulp of `v` over an ulp of `t`: 2^(ev - 151) / 2^(et - 1075)
    // (a subnormal `v` has the ulp of exponent 1); an ulp of 2·max(|offset|,
    // |t|) over an ulp of `t`: 2^(em + 1 - et); and 2. Their sum lies above
    // 2^top, the largest, and is at most 2^(top+1) unless two of them are
    // that large: the fewest bits are ceil(log2(sum)) + 1, then whole bytes
    // (the predictor differences byte planes: 16 bits took 10 % fewer bytes
    // than 13 to 15 on autzen_trim).
    let (a, b) = (ev.max(1) - et + 924, em + 1 - et);
    let top = a.max(b).max(1);
    let ties = i64::from(a == top) + i64::from(b == top) + i64::from(top == 1);
    match top + 2 + i64::from(ties > 1) {
        ..=8 => 8,
        9..=16 => 16,
        _ => LOW,
    }
}

/// 8, 16 or 23: the first `b` with `2^(b-1)` at least `reach`.
#[cfg(test)]
fn bits_for(reach: f64) -> u32 {
    if reach.is_nan() || reach >= (1u64 << (LOW - 1)) as f64 {
        return LOW;
    }
    // ceil(log2(reach)) + 1, from the double's exponent and mantissa.
    let b = reach.to_bits();
    let floor = (b >> 52) as i64 - 1023;
    let fewest = floor + i64::from(b & ((1 << 52) - 1) != 0) + 1;
    match fewest {
        ..=8 => 8,
        9..=16 => 16,
        _ => LOW,
    }
}

/// [`low_bits`]' measure, as docs/format.md states it: half an `f32` ulp of
/// `v` plus an `f64` ulp of `2·max(|offset|, |t|)`, in `f64` ulps of `t`, plus
/// 2 (`None` for values that are not finite, or 0).
#[cfg(test)]
fn reach(offset: f64, v: f32) -> Option<f64> {
    let t = offset + v as f64;
    if !t.is_finite() || !v.is_finite() || t == 0.0 || t.abs() < f64::MIN_POSITIVE {
        return None;
    }
    let ulp64 = |x: f64| {
        let a = x.abs();
        f64::from_bits(a.to_bits() + 1) - a
    };
    let a = v.abs();
    let ulp32 = (f32::from_bits(a.to_bits() + 1) - a) as f64;
    Some((0.5 * ulp32 + ulp64(offset.abs().max(t.abs()) * 2.0)) / ulp64(t) + 2.0)
}

/// The double's bits as an integer that orders as `f64::total_cmp` does, with
/// consecutive doubles one apart (-0.0 is -1, +0.0 is 0).
#[inline(always)]
fn key(t: f64) -> i64 {
    let b = t.to_bits() as i64;
    b ^ (((b >> 63) as u64) >> 1) as i64
}

#[inline(always)]
fn unkey(k: i64) -> f64 {
    f64::from_bits((k ^ (((k >> 63) as u64) >> 1) as i64) as u64)
}

/// The key nearest that of the stored value (`offset + v`) whose low `bits`
/// bits are `lo`. A NaN value stands for key 0 (whatever its payload).
#[inline(always)]
fn base(offset: f64, v: f32, lo: i64, bits: u32) -> i64 {
    let t = offset + v as f64;
    let k = if t.is_nan() { 0 } else { key(t) };
    let mask = (1i64 << bits) - 1;
    let mut d = lo - (k & mask);
    if d >= 1 << (bits - 1) {
        d -= 1 << bits;
    } else if d < -(1 << (bits - 1)) {
        d += 1 << bits;
    }
    k.wrapping_add(d)
}

/// The columns' values for time `t` around `offset`: `gps_time` (`(t -
/// offset) as f32`, as every reader stores it) and the three of
/// [`EXACT_BANDS`], each a whole number below 2^23 in magnitude (exact in an
/// `f32`).
#[inline]
pub fn split(t: f64, offset: f64) -> [f32; 4] {
    let v = (t - offset) as f32;
    let k = key(t);
    let bits = low_bits(offset, v);
    let lo = k & ((1i64 << bits) - 1);
    let q = k.wrapping_sub(base(offset, v, lo, bits)) >> bits;
    let hi = (q + (1 << (LOW - 1))) >> LOW;
    let mid = q - (hi << LOW);
    [v, lo as f32, mid as f32, hi as f32]
}

/// The time [`split`] made `v, lo, mid, hi` of, bit for bit; with `lo` NaN
/// (a coarser level), `offset + v`. Values that [`split`] did not make (not
/// whole, out of range) give some time, never a panic.
#[inline]
pub fn join(offset: f64, v: f32, lo: f32, mid: f32, hi: f32) -> f64 {
    if lo.is_nan() {
        return offset + v as f64;
    }
    let bits = low_bits(offset, v);
    let lo = (lo as i64) & ((1i64 << bits) - 1);
    let q = ((hi as i64) << LOW).wrapping_add(mid as i64);
    unkey(base(offset, v, lo, bits).wrapping_add(q.wrapping_shl(bits)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip(t: f64, offset: f64) -> [f32; 4] {
        let s = split(t, offset);
        for c in &s[1..] {
            assert!(
                c.fract() == 0.0 && c.abs() < 8_388_608.0,
                "{t} {offset} {s:?}"
            );
        }
        let back = join(offset, s[0], s[1], s[2], s[3]);
        assert_eq!(back.to_bits(), t.to_bits(), "{t} around {offset}: {back}");
        s
    }

    #[test]
    fn keys_are_consecutive_and_ordered() {
        for t in [-1.5, -0.0, 0.0, 1e-300, 245379.39843682514, f64::MAX] {
            assert_eq!(unkey(key(t)).to_bits(), t.to_bits());
            let next = if t == -0.0 && t.is_sign_negative() {
                0.0
            } else if t < 0.0 {
                f64::from_bits(t.to_bits() - 1)
            } else {
                f64::from_bits(t.to_bits() + 1)
            };
            assert_eq!(key(next), key(t) + 1, "{t}");
        }
    }

    #[test]
    fn a_survey_near_its_offset_needs_no_correction() {
        // autzen's week seconds: 6.5 s around the offset.
        let off = 245382.0;
        let mut t = 245379.39843682514;
        while t < 245385.92 {
            let s = round_trip(t, off);
            assert_eq!((s[2], s[3]), (0.0, 0.0), "{t}");
            t += 1.00792386e-5 * 37.0;
        }
    }

    #[test]
    fn any_time_comes_back_bit_for_bit() {
        let mut r = crate::rng::Rng::new(7);
        let offsets = [0.0, 245382.0, 3.1e8, -1e9, 1e300];
        let specials = [
            0.0,
            -0.0,
            f64::NAN,
            -f64::NAN,
            f64::from_bits(0x7ff8_dead_beef_0001),
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            f64::MIN,
            262144.0,
            262143.99999999997,
        ];
        for &off in &offsets {
            for &t in &specials {
                round_trip(t, off);
            }
            // Hours of week seconds, and any bits at all.
            for _ in 0..20_000 {
                round_trip(off + (r.next_u64() % 36_000_000) as f64 * 1.1e-4, off);
                round_trip(f64::from_bits(r.next_u64()), off);
            }
        }
    }

    #[test]
    fn fewer_low_bits_suffice_near_the_offset_and_never_need_more() {
        let mut r = crate::rng::Rng::new(11);
        let (mut fewer, mut more) = (0, 0);
        for off in [245_382.0, 310_000_000.0, -1e9, 0.5, 1.0e5] {
            for _ in 0..50_000 {
                // Up to a day either side of the offset, any fraction.
                let t = off + (r.f64() - 0.5) * 172_800.0 * r.f64().powi(6);
                let s = round_trip(t, off);
                let b = low_bits(off, s[0]);
                if b < LOW {
                    fewer += 1;
                    assert_eq!((s[2], s[3]), (0.0, 0.0), "{t} around {off}");
                    assert!(s[1] < (1u32 << b) as f32);
                } else {
                    more += 1;
                }
            }
        }
        assert!(fewer > 100_000 && more > 10_000, "{fewer} {more}");
    }

    #[test]
    fn low_bits_is_the_stated_measure() {
        let mut r = crate::rng::Rng::new(5);
        let mut seen = [0usize; 3];
        for off in [245_382.0, 310_000_000.3, -1e9, 0.5, 1e-300, 1e300, 0.0] {
            for i in 0..100_000 {
                let t = match i % 3 {
                    0 => off + (r.f64() - 0.5) * 1e6 * r.f64().powi(8),
                    1 => f64::from_bits(r.next_u64()),
                    _ => off * (1.0 + (r.f64() - 0.5) * 1e-9),
                };
                let v = (t - off) as f32;
                let want = reach(off, v).map_or(LOW, bits_for);
                let got = low_bits(off, v);
                assert_eq!(got, want, "{t} around {off}");
                seen[match got {
                    8 => 0,
                    16 => 1,
                    _ => 2,
                }] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n > 1000), "{seen:?}");
    }

    #[test]
    fn autzen_times_need_sixteen_low_bits() {
        let off = 245_380.0;
        for (t, want) in [(245_385.9, 16), (245_381.5, 16), (245_380.001, 8)] {
            assert_eq!(low_bits(off, (t - off) as f32), want, "{t}");
        }
    }

    #[test]
    fn a_coarser_level_without_low_bits_gives_the_float32_value() {
        let s = split(245_379.398_436_825_14, 245_380.0);
        assert_eq!(
            join(245_380.0, s[0], f32::NAN, 0.0, 0.0),
            245_380.0 + s[0] as f64
        );
    }

    #[test]
    fn a_time_of_zero_among_large_ones_uses_the_high_band() {
        let s = round_trip(0.0, 310_000_000.3);
        assert!(s[3] != 0.0, "{s:?}");
    }
}
