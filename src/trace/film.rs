//! Order-independent accumulation of pixel contributions. Contributions are
//! rounded to fixed point (2⁻³² units) and summed as integers, so the sum is
//! the same whatever order rays finish in: the image is bit-identical for
//! every hypercube dimension and thread schedule (`DESIGN.md`).

use crate::geom::Color;

/// Fixed-point scale: 2^32 units per unit of linear radiance.
const SCALE: f64 = 4294967296.0;

/// One unit of linear radiance in fixed point (`SCALE` as an integer).
pub const FIXED_ONE: i64 = 1 << 32;

/// A band of image rows `[y0, y0 + rows)` with fixed-point RGB sums.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Film {
    pub width: u32,
    pub y0: u32,
    pub rows: u32,
    sums: Vec<[i64; 3]>,
}

impl Film {
    pub fn new(width: u32, height: u32) -> Film {
        Film::band(width, 0, height)
    }

    pub fn band(width: u32, y0: u32, rows: u32) -> Film {
        Film {
            width,
            y0,
            rows,
            sums: vec![[0; 3]; width as usize * rows as usize],
        }
    }

    /// The fixed-point value of one contribution.
    pub fn quantize(c: Color) -> [i64; 3] {
        // `as` saturates; NaN would become 0, but shading never produces it
        // (tests assert so).
        debug_assert!(c.is_finite(), "non-finite contribution {c}");
        [
            (c.x * SCALE).round() as i64,
            (c.y * SCALE).round() as i64,
            (c.z * SCALE).round() as i64,
        ]
    }

    /// Adds a contribution to the global pixel index `pixel`.
    pub fn add(&mut self, pixel: u32, c: Color) {
        self.add_fixed(pixel, Film::quantize(c));
    }

    pub fn add_fixed(&mut self, pixel: u32, q: [i64; 3]) {
        let i = pixel as usize - self.y0 as usize * self.width as usize;
        let s = &mut self.sums[i];
        for k in 0..3 {
            s[k] = s[k].wrapping_add(q[k]);
        }
    }

    /// The fixed-point sums of the global pixel index `pixel`.
    pub fn fixed(&self, pixel: u32) -> [i64; 3] {
        self.sums[pixel as usize - self.y0 as usize * self.width as usize]
    }

    /// Replaces the sums of the global pixel index `pixel` (adaptive
    /// antialiasing combines passes per pixel, in fixed point).
    pub fn set_fixed(&mut self, pixel: u32, q: [i64; 3]) {
        let i = pixel as usize - self.y0 as usize * self.width as usize;
        self.sums[i] = q;
    }

    /// Adds another band's sums (which must lie inside this one).
    pub fn merge(&mut self, o: &Film) {
        let off = (o.y0 - self.y0) as usize * self.width as usize;
        for (dst, src) in self.sums[off..].iter_mut().zip(&o.sums) {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = d.wrapping_add(*s);
            }
        }
    }

    /// Linear RGB of every pixel of the band, row-major.
    pub fn to_linear(&self) -> Vec<[f32; 3]> {
        self.sums
            .iter()
            .map(|s| {
                [
                    (s[0] as f64 / SCALE) as f32,
                    (s[1] as f64 / SCALE) as f32,
                    (s[2] as f64 / SCALE) as f32,
                ]
            })
            .collect()
    }

    /// The raw fixed-point sums, for exact comparisons in tests.
    pub fn sums(&self) -> &[[i64; 3]] {
        &self.sums
    }
}
