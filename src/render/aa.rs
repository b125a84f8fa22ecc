//! Adaptive supersampling in Whitted's manner (CACM 1980), as passes
//! over an abstract pass renderer. Pass 1 samples every pixel with the base
//! samples per pixel; the pixels whose value differs from a neighbour's by
//! more than a threshold are refined by pass 2, which renders only them,
//! with extra samples; the two passes are combined per pixel in fixed point.
//!
//! Nothing here traces a ray: a pass is "these pixels with N samples each",
//! which the single-node renderer (`render_pass_with`) and the hypercube
//! machine both know how to render. Every decision is a function of the
//! pass-1 film alone, and every sample of a pixel is seeded by (pixel,
//! sample index) alone (`Pass::pixel_jobs`), so the image is bit-identical
//! whatever renders the passes: any thread count, any hypercube dimension.
//!
//! Deviation from Whitted: he sampled pixel corners and subdivided a pixel
//! recursively while its corners differed; we compare pixel values (each
//! the mean of its pass-1 samples) with their four neighbours and refine in
//! one level. One level keeps the number of passes, and so of machine
//! round trips, fixed at two.

use crate::trace::{CameraFrame, FIXED_ONE, Film, RayJob};

#[cfg(test)]
use super::sample_offset_from;

/// A set of pixels of a `width` x `height` image: every pixel, or a list.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PixelSet {
    pub width: u32,
    pub height: u32,
    /// Sorted, distinct pixel indices `j * width + i`; `None`: all pixels.
    list: Option<Vec<u32>>,
}

impl PixelSet {
    /// Every pixel of the image.
    pub fn all(width: u32, height: u32) -> PixelSet {
        PixelSet {
            width,
            height,
            list: None,
        }
    }

    /// The given pixels (sorted and deduplicated here).
    pub fn from_pixels(width: u32, height: u32, mut pixels: Vec<u32>) -> PixelSet {
        pixels.sort_unstable();
        pixels.dedup();
        let n = width as u64 * height as u64;
        assert!(
            pixels.last().is_none_or(|&p| (p as u64) < n),
            "pixel index outside a {width}x{height} image"
        );
        PixelSet {
            width,
            height,
            list: Some(pixels),
        }
    }

    /// The listed pixels, sorted; None for every pixel.
    pub fn list(&self) -> Option<&[u32]> {
        self.list.as_deref()
    }

    /// How many pixels the set holds.
    pub fn len(&self) -> u64 {
        match &self.list {
            None => self.width as u64 * self.height as u64,
            Some(l) => l.len() as u64,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The set's pixels in rows `[y0, y0 + rows)`, in increasing order.
    pub fn in_rows(&self, y0: u32, rows: u32) -> impl Iterator<Item = u32> + '_ {
        let lo = y0 * self.width;
        let hi = (y0 + rows).min(self.height) * self.width;
        let (range, list) = match &self.list {
            None => (lo..hi, None),
            Some(l) => {
                let a = l.partition_point(|&p| p < lo);
                let b = l.partition_point(|&p| p < hi);
                (0..0, Some(&l[a..b]))
            }
        };
        range.chain(list.into_iter().flatten().copied())
    }

    /// Every pixel of the set, in increasing order.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.in_rows(0, self.height)
    }
}

/// One pass: every pixel of `pixels` gets `spp` samples, stratified over
/// the pixel and weighted `1/spp`, so the pass's film holds each of its
/// pixels' mean (and zero elsewhere).
#[derive(Clone, Copy, Debug)]
pub struct Pass<'a> {
    pub pixels: &'a PixelSet,
    /// Samples per pixel in this pass (at least 1).
    pub spp: u32,
    /// Sample index of the pass's first sample: sample `k` of the pass is
    /// the pixel's sample `first_sample + k`, whose jitter is hashed from
    /// (pixel, that index). Passes over one pixel use disjoint indices.
    pub first_sample: u32,
}

impl Pass<'_> {
    /// The primary jobs of one pixel of this pass. Every pass renderer
    /// makes its primary rays here, so they all trace the same samples.
    pub fn pixel_jobs(&self, cam: &CameraFrame, pixel: u32, out: &mut Vec<RayJob>) {
        super::sample_jobs(cam, pixel, self.spp, self.first_sample, out);
    }
}

/// Whitted's refinement: which pixels get more samples, and how many.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adaptive {
    /// Refine a pixel when a channel of its value differs from a
    /// 4-neighbour's by more than this, in linear radiance clamped to
    /// [0, 1] (what the display can show); in (0, 1].
    pub threshold: f64,
    /// Samples added to each refined pixel by pass 2.
    pub extra_spp: u32,
}

/// How a render samples its pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampling {
    /// Samples per pixel of pass 1, for every pixel.
    pub spp: u32,
    /// Refinement by a second pass; `None`: one pass.
    pub adaptive: Option<Adaptive>,
}

/// What the adaptive passes did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AaSummary {
    /// Passes rendered (1 or 2).
    pub passes: u32,
    /// Pixels pass 2 refined.
    pub refined_pixels: u64,
    /// Primary samples over all passes.
    pub samples: u64,
}

/// Renders an image by passes: `render_pass` renders one `Pass` and
/// returns a full-size film holding the mean of each of the pass's pixels
/// (or the renderer's error, returned at once). Returns the combined film.
/// Deterministic given deterministic passes.
pub fn render_adaptive<F, E>(
    width: u32,
    height: u32,
    sampling: &Sampling,
    mut render_pass: F,
) -> Result<(Film, AaSummary), E>
where
    F: FnMut(&Pass<'_>) -> Result<Film, E>,
{
    let all = PixelSet::all(width, height);
    let spp = sampling.spp.max(1);
    let mut film = render_pass(&Pass {
        pixels: &all,
        spp,
        first_sample: 0,
    })?;
    let mut summary = AaSummary {
        passes: 1,
        refined_pixels: 0,
        samples: all.len() * spp as u64,
    };
    let Some(adaptive) = sampling.adaptive else {
        return Ok((film, summary));
    };
    let refine = refinement(&film, width, height, adaptive.threshold);
    if refine.is_empty() {
        return Ok((film, summary));
    }
    let extra_spp = adaptive.extra_spp.max(1);
    let extra = render_pass(&Pass {
        pixels: &refine,
        spp: extra_spp,
        first_sample: spp,
    })?;
    combine(&mut film, &extra, &refine, spp, extra_spp);
    summary.passes = 2;
    summary.refined_pixels = refine.len();
    summary.samples += refine.len() * extra_spp as u64;
    Ok((film, summary))
}

/// The pixels to refine: both pixels of every horizontally or vertically
/// adjacent pair whose clamped values differ by more than `threshold` in
/// some channel. Integer comparisons on the fixed-point film, so the
/// decision cannot depend on floating-point evaluation order.
pub fn refinement(film: &Film, width: u32, height: u32, threshold: f64) -> PixelSet {
    let t = (threshold.clamp(0.0, 1.0) * FIXED_ONE as f64).round() as i64;
    let value = |p: u32| film.fixed(p).map(|c| c.clamp(0, FIXED_ONE));
    let differs = |a: [i64; 3], b: [i64; 3]| (0..3).any(|k| (a[k] - b[k]).abs() > t);
    let mut marked = vec![false; width as usize * height as usize];
    for j in 0..height {
        for i in 0..width {
            let p = j * width + i;
            let v = value(p);
            let mut check = |q: u32| {
                if differs(v, value(q)) {
                    marked[p as usize] = true;
                    marked[q as usize] = true;
                }
            };
            if i + 1 < width {
                check(p + 1);
            }
            if j + 1 < height {
                check(p + width);
            }
        }
    }
    let pixels = (0..width * height)
        .filter(|&p| marked[p as usize])
        .collect();
    PixelSet::from_pixels(width, height, pixels)
}

/// Replaces each refined pixel by the mean of all its samples: pass 1's
/// mean weighted by its `spp1` samples, pass 2's by its `spp2`, rounded to
/// the nearest fixed-point unit (in 128 bits: no overflow, no float).
pub fn combine(film: &mut Film, extra: &Film, pixels: &PixelSet, spp1: u32, spp2: u32) {
    let (a, b) = (spp1 as i128, spp2 as i128);
    let n = a + b;
    for p in pixels.iter() {
        let (s1, s2) = (film.fixed(p), extra.fixed(p));
        let mut q = [0i64; 3];
        for k in 0..3 {
            let num = a * s1[k] as i128 + b * s2[k] as i128;
            // Round half away from zero, symmetric for negative sums.
            let r = if num >= 0 {
                (num + n / 2) / n
            } else {
                (num - n / 2) / n
            };
            q[k] = r as i64;
        }
        film.set_fixed(p, q);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Color;

    fn film_of(width: u32, height: u32, values: &[f64]) -> Film {
        let mut f = Film::new(width, height);
        for (p, &v) in values.iter().enumerate() {
            f.add(p as u32, Color::splat(v));
        }
        f
    }

    #[test]
    fn pixel_set_rows_of_a_list_and_of_all() {
        let s = PixelSet::from_pixels(4, 3, vec![9, 1, 5, 1, 11]);
        assert_eq!(s.len(), 4);
        assert_eq!(s.in_rows(0, 1).collect::<Vec<_>>(), vec![1]);
        assert_eq!(s.in_rows(1, 2).collect::<Vec<_>>(), vec![5, 9, 11]);
        assert_eq!(s.in_rows(2, 5).collect::<Vec<_>>(), vec![9, 11]);
        let all = PixelSet::all(4, 3);
        assert_eq!(all.in_rows(2, 1).collect::<Vec<_>>(), vec![8, 9, 10, 11]);
        assert_eq!(all.iter().count(), 12);
    }

    #[test]
    fn refinement_marks_both_sides_of_an_edge_and_nothing_flat() {
        // A 4x2 image, dark left half, bright right half.
        let f = film_of(4, 2, &[0.1, 0.1, 0.9, 0.9, 0.1, 0.1, 0.9, 0.9]);
        let r = refinement(&f, 4, 2, 0.5);
        assert_eq!(r.iter().collect::<Vec<_>>(), vec![1, 2, 5, 6]);
        // Above the contrast: nothing.
        assert!(refinement(&f, 4, 2, 0.85).is_empty());
    }

    #[test]
    fn refinement_ignores_differences_the_display_clamps_away() {
        // 2.0 and 5.0 both show as white.
        let f = film_of(2, 1, &[2.0, 5.0]);
        assert!(refinement(&f, 2, 1, 0.01).is_empty());
    }

    #[test]
    fn combine_weights_passes_by_their_samples() {
        let mut a = film_of(2, 1, &[0.2, 0.2]);
        let b = film_of(2, 1, &[0.6, 0.6]);
        let only_first = PixelSet::from_pixels(2, 1, vec![0]);
        combine(&mut a, &b, &only_first, 1, 3);
        let lin = a.to_linear();
        assert!((lin[0][0] - 0.5).abs() < 1e-6, "{:?}", lin[0]);
        assert!((lin[1][0] - 0.2).abs() < 1e-6, "untouched: {:?}", lin[1]);
    }

    /// A fake pass renderer: a pixel's value is the mean of a step
    /// function at its samples' x offsets, so edges refine.
    #[test]
    fn adaptive_renders_pass_two_only_where_refined_with_fresh_samples() {
        let (w, h) = (6u32, 2u32);
        let mut passes = Vec::new();
        let sampling = Sampling {
            spp: 1,
            adaptive: Some(Adaptive {
                threshold: 0.25,
                extra_spp: 4,
            }),
        };
        let (film, summary) = render_adaptive(w, h, &sampling, |pass| {
            passes.push((pass.pixels.clone(), pass.spp, pass.first_sample));
            let mut f = Film::new(w, h);
            for p in pass.pixels.iter() {
                for k in 0..pass.spp {
                    let (fx, _) = sample_offset_from(p, k, pass.spp, pass.first_sample);
                    let x = (p % w) as f64 + fx;
                    let v = if x < 2.5 { 0.0 } else { 1.0 };
                    f.add(p, Color::splat(v / pass.spp as f64));
                }
            }
            Ok::<_, ()>(f)
        })
        .unwrap();
        assert_eq!(passes.len(), 2);
        assert_eq!((passes[0].1, passes[0].2), (1, 0));
        assert_eq!((passes[1].1, passes[1].2), (4, 1));
        // The edge halves pixel 2 (x in [2, 3)); its centre sample says 1,
        // its left neighbour's 0: both refined, in both rows.
        assert_eq!(passes[1].0.iter().collect::<Vec<_>>(), vec![1, 2, 7, 8]);
        assert_eq!(summary.refined_pixels, 4);
        assert_eq!(summary.samples, 12 + 16);
        let lin = film.to_linear();
        // Pixel 2: its centre (1) and a 2x2 stratification of the pixel,
        // whose left column is dark and right column bright: 3 of 5.
        assert!((lin[2][0] - 0.6).abs() < 1e-6, "{:?}", lin[2]);
        assert_eq!(lin[1][0], 0.0);
        assert_eq!(lin[5][0], 1.0);
    }
}
