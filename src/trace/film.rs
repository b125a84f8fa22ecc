//! Order-independent accumulation of pixel contributions. Contributions are
//! rounded to fixed point (2⁻³² units) and summed as integers, so the sum is
//! the same whatever order rays finish in: the image is bit-identical for
//! every hypercube dimension and thread schedule (`DESIGN.md`).

use crate::geom::Color;

/// Fixed-point scale: 2^32 units per unit of linear radiance.
const SCALE: f64 = 4294967296.0;

/// One unit of linear radiance in fixed point (`SCALE` as an integer).
pub const FIXED_ONE: i64 = 1 << 32;

/// Writes every page of `v` once, so that its memory is mapped now.
///
/// A large zeroed vector comes fresh from the kernel, unmapped; if its
/// first touch is a read (as `+=` is), the kernel maps the shared zero
/// page, and the write after it must replace that mapping in every CPU
/// running the process: a TLB shoot-down, an interrupt to the other
/// cores, dear in a virtual machine. The machine's host adds into its
/// film while the node threads run, and a 1024x1024 film is 6,000 pages:
/// on the 2-core host this cost 14% of the CPU of a render at d = 1.
/// Touched before the node threads start, the pages are mapped at once.
///
/// For a vector that holds default values only (a fresh `vec![0; n]`),
/// which it writes again.
pub fn prefault<T: Default + PartialEq>(v: &mut [T]) {
    const PAGE: usize = 4096;
    let step = (PAGE / std::mem::size_of::<T>().max(1)).max(1);
    for i in (0..v.len()).step_by(step) {
        debug_assert!(v[i] == T::default(), "prefault overwrites a value");
        // Through `black_box`, the compiler cannot know the memory is
        // zero already and leave the store out.
        *std::hint::black_box(&mut v[i]) = T::default();
    }
}

/// The host's cores, as the OS gives them (1 where it cannot say): what
/// the host's threads are sized by, and what the machine's node threads
/// share.
pub fn host_cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Sets `out[per·i .. per·(i + 1)]` by `f(&input[i], ..)` for every `i`,
/// over the host's cores where `input` is an image's worth (an image's
/// conversions after a render, when nothing else runs: a megapixel took
/// 7 ms to make linear and 9 ms to make sRGB bytes on one thread). Each
/// element is mapped alone, so the result is the same on any number of
/// threads; where the OS refuses a thread, the rest is done here.
pub fn map_parallel<T: Sync, U: Send>(
    input: &[T],
    out: &mut [U],
    per: usize,
    f: impl Fn(&T, &mut [U]) + Sync,
) {
    map_parallel_from(input, out, per, 1 << 16, f);
}

/// `f(i)` for every `i` in `0..n`, in order, over the host's cores (each
/// alone, so the same on any number of them): for a few heavy elements,
/// such as the nodes' shares that a machine's plan makes. Where the OS
/// refuses a thread, the rest is done here.
pub fn collect_parallel<U: Send>(n: usize, f: impl Fn(usize) -> U + Sync) -> Vec<U> {
    let input: Vec<usize> = (0..n).collect();
    let mut out: Vec<Option<U>> = (0..n).map(|_| None).collect();
    map_parallel_from(&input, &mut out, 1, 2, |&i, o| o[0] = Some(f(i)));
    out.into_iter()
        .map(|u| u.expect("map_parallel_from maps every element"))
        .collect()
}

/// `map_parallel` over the host's cores from `from` elements on (fewer
/// are mapped here).
fn map_parallel_from<T: Sync, U: Send>(
    input: &[T],
    out: &mut [U],
    per: usize,
    from: usize,
    f: impl Fn(&T, &mut [U]) + Sync,
) {
    assert_eq!(out.len(), input.len() * per, "map_parallel: output size");
    let each = |input: &[T], out: &mut [U]| {
        for (x, o) in input.iter().zip(out.chunks_exact_mut(per.max(1))) {
            f(x, o);
        }
    };
    let threads = host_cores();
    if input.len() < from.max(2) || threads < 2 || per == 0 {
        return each(input, out);
    }
    let chunk = input.len().div_ceil(threads);
    // Each part in a slot its thread takes it from, so that a part whose
    // thread the OS refuses is still there to do here.
    type Part<'a, T, U> = std::sync::Mutex<Option<(&'a [T], &'a mut [U])>>;
    let parts: Vec<Part<T, U>> = input
        .chunks(chunk)
        .zip(out.chunks_mut(chunk * per))
        .map(|p| std::sync::Mutex::new(Some(p)))
        .collect();
    let run = |part: &Part<T, U>| {
        // A lock is held only to take the part, which cannot panic; were
        // it poisoned, the part is still taken rather than left undone.
        let taken = part
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some((i, o)) = taken {
            each(i, o);
        }
    };
    std::thread::scope(|s| {
        for part in &parts[1..] {
            let run = &run;
            // Refused: done below.
            let _ = std::thread::Builder::new()
                .name("hypercast-map".into())
                .spawn_scoped(s, move || run(part));
        }
        for part in &parts {
            run(part);
        }
    });
}

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

    /// Makes a new film's memory the process's own now (`prefault`).
    pub fn prefault(&mut self) {
        prefault(&mut self.sums);
    }

    /// The fixed-point value of one contribution.
    pub fn quantize(c: Color) -> [i64; 3] {
        // `as` saturates; NaN would become 0, but shading never produces it
        // (tests assert so).
        debug_assert!(c.is_finite(), "non-finite contribution {c}");
        [
            round_to_i64(c.x * SCALE),
            round_to_i64(c.y * SCALE),
            round_to_i64(c.z * SCALE),
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
        let mut out = vec![[0.0; 3]; self.sums.len()];
        map_parallel(&self.sums, &mut out, 1, |s, o| {
            o[0] = Film::linear(s);
        });
        out
    }

    /// The linear RGB of a pixel's sums (`to_linear`'s, one pixel).
    pub fn linear(sums: &[i64; 3]) -> [f32; 3] {
        sums.map(|v| (v as f64 / SCALE) as f32)
    }

    /// The raw fixed-point sums, for exact comparisons in tests.
    pub fn sums(&self) -> &[[i64; 3]] {
        &self.sums
    }
}

/// `x.round() as i64` (halves away from zero; saturating; NaN to 0)
/// without the call to the C library's `round` that the baseline x86-64
/// target makes of `f64::round`: three per contribution, millions per
/// image. The truncation is exact and so is `x` less it, so comparing the
/// remainder with a half rounds exactly as `round` does.
#[inline]
fn round_to_i64(x: f64) -> i64 {
    let t = x as i64;
    let rest = x - t as f64;
    if rest >= 0.5 {
        t.saturating_add(1)
    } else if rest <= -0.5 {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod rounding_tests {
    use super::round_to_i64;

    #[test]
    fn rounds_as_the_library_does() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            4503599627370497.0,
            9.3e18,
            -9.3e18,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ];
        // Halves, their neighbours and a spread of magnitudes.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..200_000 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let m = (state >> 11) as f64 / (1u64 << 53) as f64;
            let e = (state & 63) as i32 - 8;
            let x = (m - 0.5) * 2f64.powi(e);
            let half = x.trunc() + 0.5f64.copysign(x);
            xs.extend([x, half, half.next_up(), half.next_down()]);
        }
        for x in xs {
            assert_eq!(round_to_i64(x), x.round() as i64, "{x:e}");
        }
    }
}

#[cfg(test)]
mod map_tests {
    use super::{collect_parallel, map_parallel};

    /// Every element mapped once, in place, as a plain loop maps it: for
    /// inputs below and above the size that goes to threads, and with
    /// several outputs per element.
    #[test]
    fn maps_every_element_as_a_loop_does() {
        for n in [0usize, 1, 1000, (1 << 16) - 1, 1 << 16, 300_001] {
            let input: Vec<u64> = (0..n as u64).map(|i| i.wrapping_mul(0x9e37_79b9)).collect();
            let mut out = vec![0u64; 3 * n];
            map_parallel(&input, &mut out, 3, |x, o| {
                o[0] = *x;
                o[1] = x ^ 1;
                o[2] = x.rotate_left(7);
            });
            for (i, x) in input.iter().enumerate() {
                assert_eq!(
                    &out[3 * i..3 * i + 3],
                    &[*x, x ^ 1, x.rotate_left(7)],
                    "n = {n}"
                );
            }
        }
        // A few elements, from 2 on (a plan's nodes), each out of a vector.
        for n in [0usize, 1, 2, 3, 32] {
            let out: Vec<Vec<usize>> = collect_parallel(n, |i| (0..i).collect());
            assert_eq!(out.len(), n);
            for (i, o) in out.iter().enumerate() {
                assert_eq!(o, &(0..i).collect::<Vec<_>>(), "n = {n}");
            }
        }
    }
}
