//! Typed values to columns: one field element of consecutive records decoded
//! into its column in a tight loop per type (binary records and the columns of
//! `binary_compressed` both use it), and packed `rgb`/`rgba` split into
//! `red green blue`.

use super::header::Ty;

/// Where one element (one value of a field) of every point goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Role {
    X,
    Y,
    Z,
    /// Attribute column `a`.
    Attr(usize),
    /// Packed colour: attribute columns `a`, `a + 1`, `a + 2` (red, green, blue).
    Rgb(usize),
    Skip,
}

/// One element of the record: its field, type, role and byte offsets.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Elem {
    pub field: usize,
    /// Offset in a binary record.
    pub off: usize,
    /// Offset within one point's values of its field (`binary_compressed`
    /// stores each field's values of all points together).
    pub within: usize,
    pub ty: Ty,
    pub role: Role,
}

pub use crate::value::Val;

/// Columns of consecutive points to fill.
pub struct Out<'a, A> {
    pub x: &'a mut [f64],
    pub y: &'a mut [f64],
    pub z: &'a mut [f64],
    pub attrs: Vec<&'a mut [A]>,
}

impl<A> Out<'_, A> {
    pub fn len(&self) -> usize {
        self.x.len()
    }
}

/// `out` cut into runs of at most `m` points (for rayon), each with the index
/// of its first point.
pub fn split<A>(out: Out<'_, A>, m: usize) -> Vec<(usize, Out<'_, A>)> {
    let m = m.max(1);
    let Out { x, y, z, attrs } = out;
    let mut xs = x.chunks_mut(m);
    let mut ys = y.chunks_mut(m);
    let mut zs = z.chunks_mut(m);
    let mut ats: Vec<_> = attrs.into_iter().map(|a| a.chunks_mut(m)).collect();
    let mut runs = Vec::new();
    let mut first = 0;
    while let (Some(x), Some(y), Some(z)) = (xs.next(), ys.next(), zs.next()) {
        let len = x.len();
        let attrs = ats.iter_mut().filter_map(|it| it.next()).collect();
        runs.push((first, Out { x, y, z, attrs }));
        first += len;
    }
    runs
}

/// Points per rayon task for `n` points.
pub(crate) fn task_points(n: usize) -> usize {
    (n / (rayon::current_num_threads().max(1) * 4)).max(16 << 10)
}

/// The 32 bits of a packed colour at the start of `b` (any 4-byte type).
#[inline(always)]
fn packed(b: &[u8]) -> u32 {
    let mut a = [0u8; 4];
    if let Some(s) = b.get(..4) {
        a.copy_from_slice(s);
    }
    u32::from_le_bytes(a)
}

/// Red, green and blue of a packed colour (`0x00RRGGBB`, alpha above).
#[inline(always)]
pub fn unpack(v: u32) -> [f64; 3] {
    [
        ((v >> 16) & 255) as f64,
        ((v >> 8) & 255) as f64,
        (v & 255) as f64,
    ]
}

fn column<O: Val>(recs: &[u8], stride: usize, off: usize, ty: Ty, out: &mut [O], offset: f64) {
    macro_rules! col {
        ($t:ty, $n:expr) => {
            for (rec, o) in recs.chunks_exact(stride).zip(out.iter_mut()) {
                if let Some(b) = rec.get(off..off + $n) {
                    let mut a = [0u8; $n];
                    a.copy_from_slice(b);
                    *o = O::from_f64(<$t>::from_le_bytes(a) as f64 - offset);
                }
            }
        };
    }
    match ty {
        Ty::I1 => col!(i8, 1),
        Ty::U1 => col!(u8, 1),
        Ty::I2 => col!(i16, 2),
        Ty::U2 => col!(u16, 2),
        Ty::I4 => col!(i32, 4),
        Ty::U4 => col!(u32, 4),
        Ty::I8 => col!(i64, 8),
        Ty::U8 => col!(u64, 8),
        Ty::F4 => col!(f32, 4),
        Ty::F8 => col!(f64, 8),
    }
}

/// Decodes element `e`, found at byte `off` of records of `stride` bytes in
/// `recs`, into its column(s) of `out`.
pub fn element<A: Val>(
    recs: &[u8],
    stride: usize,
    off: usize,
    e: &Elem,
    out: &mut Out<'_, A>,
    offsets: &[f64],
) {
    match e.role {
        Role::X => column(recs, stride, off, e.ty, out.x, 0.0),
        Role::Y => column(recs, stride, off, e.ty, out.y, 0.0),
        Role::Z => column(recs, stride, off, e.ty, out.z, 0.0),
        Role::Attr(a) => {
            let offset = offsets.get(a).copied().unwrap_or(0.0);
            if let Some(col) = out.attrs.get_mut(a) {
                column(recs, stride, off, e.ty, col, offset);
            }
        }
        Role::Rgb(a) => {
            let Some([r, g, b]) = out.attrs.get_mut(a..a + 3) else {
                return;
            };
            for (i, rec) in recs.chunks_exact(stride).enumerate().take(r.len()) {
                let [vr, vg, vb] = unpack(packed(rec.get(off..).unwrap_or_default()));
                r[i] = A::from_f64(vr);
                g[i] = A::from_f64(vg);
                b[i] = A::from_f64(vb);
            }
        }
        Role::Skip => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_and_colour() {
        // Two records: f32 x, u16 label, packed rgba.
        let mut recs = Vec::new();
        for (x, l, c) in [(1.5f32, 7u16, 0xff10_2030u32), (-2.0, 65535, 0x00ff_00ff)] {
            recs.extend_from_slice(&x.to_le_bytes());
            recs.extend_from_slice(&l.to_le_bytes());
            recs.extend_from_slice(&c.to_le_bytes());
        }
        let (mut x, mut y, mut z) = (vec![0.0; 2], vec![0.0; 2], vec![0.0; 2]);
        let mut cols = vec![vec![0f32; 2]; 4];
        let mut out = Out {
            x: &mut x,
            y: &mut y,
            z: &mut z,
            attrs: cols.iter_mut().map(|c| c.as_mut_slice()).collect(),
        };
        let e = |off, ty, role| Elem {
            field: 0,
            off,
            within: 0,
            ty,
            role,
        };
        element(&recs, 10, 0, &e(0, Ty::F4, Role::X), &mut out, &[]);
        element(&recs, 10, 4, &e(4, Ty::U2, Role::Attr(0)), &mut out, &[1.0]);
        element(&recs, 10, 6, &e(6, Ty::U4, Role::Rgb(1)), &mut out, &[]);
        assert_eq!(x, [1.5, -2.0]);
        assert_eq!(cols[0], [6.0, 65534.0]);
        assert_eq!((cols[1][0], cols[2][0], cols[3][0]), (16.0, 32.0, 48.0));
        assert_eq!((cols[1][1], cols[2][1], cols[3][1]), (255.0, 0.0, 255.0));
    }
}
