//! Exact arithmetic on f64 values by floating-point expansions (Priest
//! 1991; Shewchuk, "Adaptive Precision Floating-Point Arithmetic and Fast
//! Robust Geometric Predicates", 1997): a value is held as a sum of f64
//! components, and sums, differences and products of such values are exact
//! (barring overflow and underflow). An expression that cancels
//! catastrophically in f64 (the distance to a plane through points 1e20
//! away) then comes out to within a few ulps of its true value.
//!
//! Used by `shape` for the plane of a planar primitive, and the power of a
//! sphere, an ellipsoid, or a cylinder's or cone's side, that reach far
//! beyond their hits (`shape::on_plane`, `shape::sphere_hits`,
//! `shape::ellipsoid_hits`, `shape::far_cylinder_roots`,
//! `shape::far_cone_roots`), a rare path. Products of expansions are
//! formed as scaled copies merged in, in time linear in the lengths, and
//! `compress` keeps the factors short. The components live inline up to
//! `INLINE` of them (the products there rarely need more), on the heap
//! beyond. Owns these functions only; touches no other module.

use smallvec::SmallVec;

/// Components an expansion holds without a heap allocation.
const INLINE: usize = 8;

/// `a + b` as `(s, e)`: `s` the rounded sum, `e` its rounding error, so
/// that `s + e == a + b` exactly (Knuth's two-sum; any order of magnitude).
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bv = s - a;
    let av = s - bv;
    (s, (a - av) + (b - bv))
}

/// `a · b` as `(p, e)` with `p + e == a · b` exactly: the fused
/// multiply-add rounds once, so `a·b − p` is exact.
#[inline]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

/// An exact value: the sum of its components, which are non-overlapping
/// and in increasing order of magnitude, with no zeros (Shewchuk's
/// invariants, kept by `grow`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Expansion(SmallVec<[f64; INLINE]>);

impl Expansion {
    /// `a − b`, exactly.
    pub fn diff(a: f64, b: f64) -> Expansion {
        let mut e = Expansion::default();
        e.grow(a);
        e.grow(-b);
        e
    }

    /// Adds `b` (Shewchuk's Grow-Expansion with zero elimination): each
    /// component in turn is two-summed into a running sum, whose errors
    /// become the new components. Exact for any components; the invariants
    /// hold when they held before.
    fn grow(&mut self, b: f64) {
        let mut q = b;
        let mut kept = 0;
        for i in 0..self.0.len() {
            let (s, h) = two_sum(q, self.0[i]);
            q = s;
            if h != 0.0 {
                self.0[kept] = h;
                kept += 1;
            }
        }
        self.0.truncate(kept);
        if q != 0.0 {
            self.0.push(q);
        }
    }

    /// Adds `x · y · sign` (`sign` ±1), exactly: `x` scaled by each
    /// component of `y` in turn and merged in (`add_scaled`).
    pub fn add_product(&mut self, x: &Expansion, y: &Expansion, sign: f64) {
        for &b in &y.0 {
            self.add_scaled(x, b * sign);
        }
    }

    /// Adds `x · b`, exactly. A single component is grown in; more are
    /// scaled (Shewchuk's Scale-Expansion) and merged (`merge`), in time
    /// linear in the two lengths, where growing each partial product in
    /// would take their product.
    pub fn add_scaled(&mut self, x: &Expansion, b: f64) {
        match x.0.as_slice() {
            [] => {}
            [a] => self.add_f64_product(*a, b),
            _ => {
                let scaled = x.scaled(b);
                self.merge(&scaled);
            }
        }
    }

    /// `self · b` as a new expansion, exactly (`add_scaled` into none).
    pub fn times(&self, b: f64) -> Expansion {
        let mut e = Expansion::default();
        e.add_scaled(self, b);
        e
    }

    /// `self · b` (Shewchuk's Scale-Expansion with zero elimination): each
    /// component's two-product, its error two-summed into the running sum.
    fn scaled(&self, b: f64) -> Expansion {
        let mut h = Expansion::default();
        let (mut q, e) = two_prod(self.0[0], b);
        h.keep(e);
        for &a in &self.0[1..] {
            let (p1, p0) = two_prod(a, b);
            let (sum, e) = two_sum(q, p0);
            h.keep(e);
            let (s, e) = two_sum(p1, sum);
            h.keep(e);
            q = s;
        }
        h.keep(q);
        h
    }

    /// Adds `other` (Shewchuk's Fast-Expansion-Sum with zero elimination,
    /// with two-sum throughout): the two merged by magnitude, then summed
    /// from the smallest, each sum's nonzero error kept.
    fn merge(&mut self, other: &Expansion) {
        let (e, f) = (&self.0, &other.0);
        let (mut i, mut j) = (0, 0);
        let merged = std::iter::from_fn(|| {
            let take_e = j == f.len() || (i < e.len() && e[i].abs() < f[j].abs());
            if take_e {
                i += 1;
                e.get(i - 1).copied()
            } else {
                j += 1;
                Some(f[j - 1])
            }
        });
        *self = Expansion::summed(merged);
    }

    /// The sum of `values` taken in their order (each at least as large as
    /// the errors before it): each two-sum's nonzero error kept as a
    /// component, the last sum on top.
    fn summed(values: impl Iterator<Item = f64>) -> Expansion {
        let mut h = Expansion::default();
        let mut q = 0.0;
        for v in values {
            let (s, err) = two_sum(q, v);
            h.keep(err);
            q = s;
        }
        h.keep(q);
        h
    }

    /// Appends `x` as the next (larger) component unless it is zero.
    #[inline]
    fn keep(&mut self, x: f64) {
        if x != 0.0 {
            self.0.push(x);
        }
    }

    /// Adds `a · b` of two f64 values, exactly.
    #[inline]
    pub fn add_f64_product(&mut self, a: f64, b: f64) {
        let (p, e) = two_prod(a, b);
        self.grow(e);
        self.grow(p);
    }

    /// The same value in as few components as Shewchuk's Compress leaves
    /// (each at least twice the sum of those below it, so usually one or
    /// two): products of compressed factors then take a handful of
    /// partial products where the grown ones would take dozens.
    ///
    /// The first pass sums from the largest down, keeping a sum wherever
    /// the next component's error does not vanish; the second sums those
    /// from the smallest up, keeping each nonzero error. Exact: every step
    /// is a two-sum.
    pub fn compress(&mut self) {
        let e = &self.0;
        let m = e.len();
        if m < 2 {
            return;
        }
        let mut g: SmallVec<[f64; INLINE]> = SmallVec::from_elem(0.0, m);
        let mut bottom = m - 1;
        let mut q = e[m - 1];
        for i in (0..m - 1).rev() {
            let (s, err) = two_sum(q, e[i]);
            if err != 0.0 {
                g[bottom] = s;
                bottom -= 1;
                q = err;
            } else {
                q = s;
            }
        }
        g[bottom] = q;
        *self = Expansion::summed(g[bottom..].iter().copied());
    }

    /// The value to within a few ulps: the components summed from the
    /// smallest, each below an ulp of the next. Zero only when the value
    /// is zero; not finite when a step overflowed.
    pub fn estimate(&self) -> f64 {
        self.0.iter().fold(0.0, |s, &c| s + c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Exact rational arithmetic on dyadic numbers for the check: every f64
    /// is `m · 2^k`; held as an i128 numerator over a common power of two.
    fn dyadic(x: f64, shift: i32) -> i128 {
        // x · 2^shift, exact for the test's values (a few bits, small
        // exponents).
        let v = x * 2f64.powi(shift);
        assert_eq!(v.fract(), 0.0, "{x} is not a multiple of 2^-{shift}");
        v as i128
    }

    /// `x · y` as a new expansion.
    fn product(x: &Expansion, y: &Expansion) -> Expansion {
        let mut r = Expansion::default();
        r.add_product(x, y, 1.0);
        r
    }

    #[test]
    fn sums_and_products_that_cancel_in_f64_are_exact() {
        // (1e20 + 3) − 1e20 is 3 here, 0 or 16384 in f64.
        let big = 1e20;
        let mut e = Expansion::diff(big, -3.0);
        e.add_scaled(&Expansion::diff(big, 0.0), -1.0);
        assert_eq!(e.estimate(), 3.0);
        // (2^60 + 1)² − 2^120 = 2^61 + 1.
        let a = Expansion::diff(2f64.powi(60), -1.0);
        let mut sq = product(&a, &a);
        sq.add_f64_product(2f64.powi(60), -2f64.powi(60));
        assert_eq!(sq.estimate(), 2f64.powi(61) + 1.0);
        assert_eq!(sq.0.as_slice(), [1.0, 2f64.powi(61)]);
        // Scaling keeps every bit.
        let mut s = Expansion::default();
        s.add_scaled(&Expansion::diff(2f64.powi(70), -0.75), 3.0);
        assert_eq!(s.0.as_slice(), [2.25, 3.0 * 2f64.powi(70)]);
    }

    #[test]
    fn random_small_dyadic_expressions_match_integer_arithmetic() {
        // Values k · 2^-4 with |k| < 2^20 at scales up to 2^40: every
        // product of two differences fits an i128 at a shift of 8.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            state >> 11
        };
        // A running sum of up to three products, merged in as the CSG
        // paths do (`add_product`), checked too.
        let (mut acc, mut acc_want, mut terms) = (Expansion::default(), 0i128, 0);
        for _ in 0..2000 {
            let mut val = || {
                let k = (next() % (1 << 20)) as f64 - (1 << 19) as f64;
                let scale = 2f64.powi((next() % 40) as i32);
                k * scale / 16.0
            };
            let (a, b, c, d) = (val(), val(), val(), val());
            let x = product(&Expansion::diff(a, b), &Expansion::diff(c, d));
            let want = (dyadic(a, 4) - dyadic(b, 4)) * (dyadic(c, 4) - dyadic(d, 4));
            let got: i128 = x.0.iter().map(|&v| dyadic(v, 8)).sum();
            assert_eq!(got, want, "({a} − {b})·({c} − {d})");
            assert!(x.0.windows(2).all(|w| w[0].abs() < w[1].abs()));
            assert!(x.0.iter().all(|&v| v != 0.0));
            // Compressed: the same value, no more components, still
            // increasing and without zeros.
            let mut y = x.clone();
            y.compress();
            let got: i128 = y.0.iter().map(|&v| dyadic(v, 8)).sum();
            assert_eq!(got, want, "compressed ({a} − {b})·({c} − {d})");
            assert!(y.0.len() <= x.0.len());
            assert!(y.0.windows(2).all(|w| w[0].abs() < w[1].abs()));
            assert!(y.0.iter().all(|&v| v != 0.0));
            assert_eq!(y.estimate(), x.estimate());
            if terms == 3 {
                (acc, acc_want, terms) = (Expansion::default(), 0, 0);
            }
            let sign = if next() % 2 == 0 { 1.0 } else { -1.0 };
            acc.add_product(&Expansion::diff(a, b), &Expansion::diff(c, d), sign);
            acc_want += if sign > 0.0 { want } else { -want };
            terms += 1;
            let got: i128 = acc.0.iter().map(|&v| dyadic(v, 8)).sum();
            assert_eq!(got, acc_want, "a running sum of products");
            assert!(
                acc.0.windows(2).all(|w| w[0].abs() < w[1].abs()),
                "{:?}",
                acc.0
            );
            assert!(acc.0.iter().all(|&v| v != 0.0));
        }
    }

    #[test]
    fn compression_keeps_the_value_in_fewer_components() {
        // 2^60 + 2^30 + 1 + 2^-30 grown from many small parts.
        let mut e = Expansion::default();
        for _ in 0..4 {
            e.grow(2f64.powi(58));
            e.grow(2f64.powi(28));
            e.grow(0.25);
            e.grow(2f64.powi(-32));
        }
        let before = e.estimate();
        e.compress();
        assert_eq!(e.estimate(), before);
        let mut sum = 0.0;
        for &c in &e.0 {
            // Each at least twice the sum below it.
            assert!(c.abs() >= 2.0 * sum, "{:?}", e.0);
            sum += c.abs();
        }
        // Zero stays empty; a cancelled value becomes empty.
        let mut z = Expansion::diff(1e20, 1e20);
        z.compress();
        assert!(z.0.is_empty());
    }
}
