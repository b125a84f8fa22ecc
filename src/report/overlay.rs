//! The `inspect --overlay` picture: the front region's super cells drawn
//! over a render, each outline coloured by how many primitives reach into
//! the super cell (blue few, red many; empty ones in grey), and, given the
//! mapping, each super cell's inside tinted by the node that owns it.

use crate::cells::{CellStructure, Region};
use crate::trace::CameraFrame;

/// A heat colour for `v` in [0, 1] (linear RGB).
fn heat(v: f64) -> [f32; 3] {
    let v = v.clamp(0.0, 1.0) as f32;
    [
        v.min(0.5) * 2.0,
        (1.0 - (2.0 * v - 1.0).abs()).max(0.0),
        (1.0 - v * 2.0).max(0.0),
    ]
}

/// A colour from hue, saturation and value in [0, 1].
fn hsv(h: f64, s: f64, v: f64) -> [f32; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i64 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r as f32, g as f32, b as f32]
}

/// Draws the super cells of `cs` onto linear pixels `img` (width × height),
/// and returns the most primitives in one super cell: the red end of the
/// outlines' scale, for the key the command prints.
pub fn draw_super_cells(
    img: &mut [[f32; 3]],
    cam: &CameraFrame,
    cs: &CellStructure,
    owner: Option<&[u16]>,
) -> usize {
    let (w, h) = (cam.width as i64, cam.height as i64);
    let front = cs.region(Region::Front);
    let most = front
        .partition
        .leaves
        .iter()
        .map(|l| l.prims.len())
        .max()
        .unwrap_or(1)
        .max(1);
    let max = most as f64;
    // Screen x/z, y/z to pixel coordinates (pixel centres at +0.5).
    let px = |sx: f64| ((sx / cam.half_w + 1.0) * 0.5 * w as f64).clamp(-1.0, w as f64 + 1.0);
    let py = |sy: f64| ((1.0 - sy / cam.half_h) * 0.5 * h as f64).clamp(-1.0, h as f64 + 1.0);
    if let Some(owner) = owner {
        for (s, leaf) in front.partition.leaves.iter().enumerate() {
            let r = leaf.rect;
            let (x0, x1) = (px(r.x0).round() as i64, px(r.x1).round() as i64);
            let (y0, y1) = (py(r.y1).round() as i64, py(r.y0).round() as i64);
            // Golden-ratio hues keep neighbouring node numbers apart.
            let hue = (owner[s] as f64 * 0.618_034).fract();
            let tint = hsv(hue, 0.6, 1.0);
            for y in y0.max(0)..y1.min(h) {
                for x in x0.max(0)..x1.min(w) {
                    let p = &mut img[(y * w + x) as usize];
                    for (c, t) in p.iter_mut().zip(tint) {
                        *c = 0.6 * *c + 0.4 * t;
                    }
                }
            }
        }
    }
    let mut put = |x: i64, y: i64, c: [f32; 3]| {
        if (0..w).contains(&x) && (0..h).contains(&y) {
            img[(y * w + x) as usize] = c;
        }
    };
    for leaf in &front.partition.leaves {
        let r = leaf.rect;
        let c = if leaf.prims.is_empty() {
            [0.25, 0.25, 0.25]
        } else {
            heat(leaf.prims.len() as f64 / max)
        };
        let (x0, x1) = (px(r.x0).round() as i64, px(r.x1).round() as i64);
        let (y0, y1) = (py(r.y1).round() as i64, py(r.y0).round() as i64);
        for x in x0..=x1 {
            put(x, y0, c);
            put(x, y1, c);
        }
        for y in y0..=y1 {
            put(x0, y, c);
            put(x1, y, c);
        }
    }
    most
}
