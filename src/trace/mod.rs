//! Whitted shading, decomposed into rays that carry everything they need to
//! finish on their own (`RayJob`), so that the same code shades on one node
//! or on a hypercube where rays travel as messages. No threads, no I/O; the
//! accelerator that finds hits is someone else's (`Tracer`).
//!
//! A path's colour is the sum of independent contributions, each a weight
//! times a local term: `ambient·color·scene.ambient` at every hit, a shadow
//! ray per visible light that delivers `(diffuse·color·N·L + specular·
//! (R·V)^shininess)·light.color` attenuated by the `transmit` of every
//! surface it crosses, `background` for rays that leave the scene, and
//! reflected and refracted rays that carry `reflect` and `transmit` as
//! weight (`SCENE_FORMAT.md`). Summing contributions in fixed point
//! (`Film`) makes the image independent of the order they arrive in.

mod film;
mod optics;

pub use film::{FIXED_ONE, Film, collect_parallel, host_cores, map_parallel, prefault};
pub use optics::{Refraction, offset_origin, reflect, refract};

use crate::csg::{Boundary, PrimId};
use crate::geom::{Color, Ray, Vec3};
use crate::scene::Scene;

/// What a ray is for; decides how a hit is treated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum RayKind {
    Primary,
    Shadow,
    Reflected,
    Refracted,
}

impl RayKind {
    pub const ALL: [RayKind; 4] = [
        RayKind::Primary,
        RayKind::Shadow,
        RayKind::Reflected,
        RayKind::Refracted,
    ];

    pub fn index(self) -> usize {
        self as usize
    }

    pub fn name(self) -> &'static str {
        match self {
            RayKind::Primary => "primary",
            RayKind::Shadow => "shadow",
            RayKind::Reflected => "reflected",
            RayKind::Refracted => "refracted",
        }
    }
}

/// A ray with everything it needs to finish: where its contribution goes
/// and with what weight.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RayJob {
    pub ray: Ray,
    pub kind: RayKind,
    /// Pixel index `j·width + i`.
    pub pixel: u32,
    /// Reflection/refraction generations so far (0 for primary rays).
    pub depth: u8,
    /// Colour weight. For a shadow ray, the full contribution it delivers
    /// if it reaches its light (already attenuated so far).
    pub weight: [f32; 3],
    /// Hits count only for `t` below this: 1.0 for shadow rays (the light is
    /// at `origin + dir`), infinity otherwise.
    pub t_max: f64,
    /// The primitive (its index in the whole scene) whose surface the ray
    /// starts on and moves off, where it can never meet it again
    /// (`Primitive::left_behind`): its queries leave it out, which spares
    /// most secondary rays a test, and makes sure no rounding lets a ray
    /// find the surface it leaves. None for primary rays and where the
    /// primitive may be met again.
    pub leaving: Option<PrimId>,
    /// For a shadow ray, the index of the light it goes to (None for other
    /// rays, and past `u16::MAX` lights): the walk then need not find the
    /// light from the ray's end (`Tracer::toward`), a search over the
    /// lights per shadow ray.
    pub light: Option<u16>,
}

impl RayJob {
    pub fn weight(&self) -> Color {
        Color::new(
            self.weight[0] as f64,
            self.weight[1] as f64,
            self.weight[2] as f64,
        )
    }
}

fn to_weight(c: Color) -> [f32; 3] {
    // Held at f32's largest, not rounded to infinity: under mirrors with
    // `reflect` above 1 a weight grows with every bounce (4^64 at depth
    // 64), and an infinite one would make the contributions infinite or
    // NaN. (Weights are never negative: colours and coefficients are not.)
    c.to_array().map(|x| x.min(f64::from(f32::MAX)) as f32)
}

/// The nearest CSG boundary a ray meets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub prim: PrimId,
    pub part: u8,
    /// The surface is a cut made by a subtracted primitive: reverse its normal.
    pub flip: bool,
}

impl From<Boundary> for Hit {
    fn from(b: Boundary) -> Hit {
        Hit {
            t: b.t,
            prim: b.prim,
            part: b.part,
            flip: b.flip,
        }
    }
}

/// The accelerator's interface on one node: a ray in, the nearest CSG hit
/// out. `--accel roth` and `--accel cells` both implement it.
pub trait Tracer {
    /// The nearest boundary with `t_min < t < t_max`.
    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit>;

    /// For a shadow ray toward a light at `t_max`: a boundary with `t_min <
    /// t < t_max` whenever there is one, the nearest when the shadow ray
    /// may need it (a material that transmits light). An accelerator may
    /// answer with another surface when every surface stops the ray; the
    /// reference answers `nearest`.
    fn shadow(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        self.nearest(ray, t_min, t_max)
    }

    /// Work counters so far.
    fn counters(&self) -> crate::render::TraceCounters {
        Default::default()
    }

    /// The primitive the rays of the queries that follow start on and
    /// move off (`RayJob::leaving`, a whole-scene index), set before each
    /// job's queries: every tracer must leave it out, so that all give the
    /// same answers.
    fn leaving(&mut self, prim: Option<PrimId>);

    /// The light the shadow rays of the queries that follow go to
    /// (`RayJob::light`), set before each job's queries. A hint: a tracer
    /// that does not need it, or is not told, finds the same answers.
    fn toward(&mut self, _light: Option<u16>) {}
}

/// Per-kind ray counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCounts(pub [u64; 4]);

impl RayCounts {
    pub fn add(&mut self, k: RayKind) {
        self.0[k.index()] += 1;
    }
    pub fn get(&self, k: RayKind) -> u64 {
        self.0[k.index()]
    }
    pub fn merge(&mut self, o: &RayCounts) {
        for i in 0..4 {
            self.0[i] += o.0[i];
        }
    }
    pub fn total(&self) -> u64 {
        self.0.iter().sum()
    }
}

/// Reflected and refracted rays that carry less than this share of their
/// sample (in every channel) are not spawned: Hall and Greenberg's adaptive
/// tree depth (1983). Whitted's ray tree doubles at every surface that both
/// reflects and transmits, so `max_depth` alone lets a hall of glass grow
/// 2^max_depth rays per sample (`ROBUSTNESS.md` case 26). With the cutoff,
/// and materials whose `reflect + transmit ≤ 1`, a generation's shares sum
/// to at most 1, so it holds fewer than `1 / MIN_WEIGHT` rays: a sample's
/// tree has at most `max_depth / MIN_WEIGHT` secondary rays, whatever
/// `max_depth` allows. The rays left out carry less than 2⁻¹⁶ of their
/// sample, far below one step of an 8-bit image even near black (2⁻¹²
/// linear). The share is of the sample, not of the pixel, so that more
/// samples converge to the same image (`Shader::with_samples`).
pub const MIN_WEIGHT: f64 = 1.0 / 65536.0;

/// Whitted's shading rules over a scene; stateless, shared by every node.
#[derive(Clone, Copy)]
pub struct Shader<'a> {
    pub scene: &'a Scene,
    /// `MIN_WEIGHT` as a ray weight: primary rays weigh `1/spp`.
    min_weight: f64,
}

impl<'a> Shader<'a> {
    /// Shading for renders of one sample per pixel.
    pub fn new(scene: &'a Scene) -> Self {
        Shader::with_samples(scene, 1)
    }

    /// Shading for renders of `spp` samples per pixel, whose primary rays
    /// weigh `1/spp`. Every renderer of the same image must use the same
    /// `spp` here (as it does for the samples), or rays near the cutoff
    /// would be traced by one and not by another.
    pub fn with_samples(scene: &'a Scene, spp: u32) -> Self {
        Shader {
            scene,
            min_weight: MIN_WEIGHT / f64::from(spp.max(1)),
        }
    }

    /// True when a secondary ray of weight `w` is worth tracing (`MIN_WEIGHT`).
    fn carries(&self, w: Color) -> bool {
        w.max_element() >= self.min_weight
    }

    /// The contribution of a ray that met nothing below its `t_max`.
    /// Shadow rays deliver their weight; others see the background.
    pub fn miss(&self, job: &RayJob) -> Color {
        match job.kind {
            RayKind::Shadow => job.weight(),
            _ => job.weight() * self.scene.background,
        }
    }

    /// A shadow ray crossing a surface: attenuate by its material's
    /// `transmit`. Returns false when nothing is left to deliver.
    pub fn shadow_crossing(&self, job: &mut RayJob, hit: &Hit) -> bool {
        let m = self
            .scene
            .material(self.scene.primitives[hit.prim.index()].material);
        let w = job.weight() * m.transmit;
        job.weight = to_weight(w);
        job.weight.iter().any(|&c| c > 0.0)
    }

    /// Shades a hit of a primary, reflected or refracted ray: returns the
    /// local contribution and pushes the rays it spawns (shadow rays toward
    /// visible lights, a reflected ray, a refracted ray) into `spawn`.
    pub fn shade(&self, job: &RayJob, hit: &Hit, spawn: &mut impl FnMut(RayJob)) -> Color {
        let scene = self.scene;
        let prim = &scene.primitives[hit.prim.index()];
        let m = scene.material(prim.material);
        let w = job.weight();
        let ray = &job.ray;
        let p = ray.at(hit.t);
        let mut n = prim.normal(ray, hit.t, hit.part);
        if hit.flip {
            n = -n;
        }
        let d = ray.dir.normalize();
        let entering = d.dot(n) <= 0.0;
        // The normal on the side the ray arrives from.
        let nf = if entering { n } else { -n };
        let extent = prim.rounding_size(p, hit.part);
        // Whether `nf` is the primitive's own outward normal (it is the
        // solid's, which is the other way round on a subtracted surface).
        let outward = entering != hit.flip;
        let leaving = |outward| prim.left_behind(outward).then_some(hit.prim);

        let local = w * m.ambient * m.color * scene.ambient;
        for (index, light) in scene.lights.iter().enumerate() {
            let to_light = light.position - p;
            let ndl = nf.dot(to_light);
            if ndl <= 0.0 {
                continue;
            }
            let l = to_light.normalize();
            let cos = nf.dot(l);
            let mut term = m.diffuse * m.color * cos;
            if m.specular > 0.0 {
                let r = reflect(-l, nf);
                let rv = r.dot(-d).max(0.0);
                term += Color::splat(m.specular * rv.powf(m.shininess));
            }
            let c = w * term * light.color;
            if c.max_element() <= 0.0 {
                continue;
            }
            let origin = offset_origin(ray, hit.t, p, nf, extent);
            spawn(RayJob {
                ray: Ray::new(origin, light.position - origin),
                kind: RayKind::Shadow,
                pixel: job.pixel,
                depth: job.depth,
                weight: to_weight(c),
                t_max: 1.0,
                leaving: leaving(outward),
                light: u16::try_from(index).ok(),
            });
        }

        if job.depth as u32 >= scene.max_depth {
            return local;
        }
        let mut reflect_share = m.reflect;
        if m.transmit > 0.0 {
            let eta = if entering { 1.0 / m.ior } else { m.ior };
            match refract(d, nf, eta) {
                Refraction::Transmitted(t) if self.carries(w * m.transmit) => {
                    let origin = offset_origin(ray, hit.t, p, -nf, extent);
                    spawn(RayJob {
                        ray: Ray::new(origin, t),
                        kind: RayKind::Refracted,
                        pixel: job.pixel,
                        depth: job.depth + 1,
                        weight: to_weight(w * m.transmit),
                        t_max: f64::INFINITY,
                        // Off the other side of the surface.
                        leaving: leaving(!outward),
                        light: None,
                    });
                }
                Refraction::Transmitted(_) => {}
                // Total internal reflection: the transmitted share is reflected.
                Refraction::TotalInternal => reflect_share += m.transmit,
            }
        }
        if reflect_share > 0.0 && self.carries(w * reflect_share) {
            let origin = offset_origin(ray, hit.t, p, nf, extent);
            spawn(RayJob {
                ray: Ray::new(origin, reflect(d, nf)),
                kind: RayKind::Reflected,
                pixel: job.pixel,
                depth: job.depth + 1,
                weight: to_weight(w * reflect_share),
                t_max: f64::INFINITY,
                leaving: leaving(outward),
                light: None,
            });
        }
        local
    }

    /// Traces one job to completion on a synchronous tracer, depth first,
    /// delivering contributions to `film`. Used by single-node renders; the
    /// hypercube runs the same rules one message at a time.
    pub fn run_path(
        &self,
        tracer: &mut impl Tracer,
        first: RayJob,
        film: &mut Film,
        counts: &mut RayCounts,
        stack: &mut Vec<RayJob>,
    ) {
        stack.clear();
        stack.push(first);
        while let Some(mut job) = stack.pop() {
            counts.add(job.kind);
            tracer.leaving(job.leaving);
            tracer.toward(job.light);
            if job.kind == RayKind::Shadow {
                let mut t = 0.0;
                let delivered = loop {
                    match tracer.shadow(&job.ray, t, job.t_max) {
                        None => break true,
                        Some(h) => {
                            if !self.shadow_crossing(&mut job, &h) {
                                break false;
                            }
                            t = h.t;
                        }
                    }
                };
                if delivered {
                    film.add(job.pixel, self.miss(&job));
                }
                continue;
            }
            match tracer.nearest(&job.ray, 0.0, job.t_max) {
                None => film.add(job.pixel, self.miss(&job)),
                Some(h) => {
                    let c = self.shade(&job, &h, &mut |j| stack.push(j));
                    film.add(job.pixel, c);
                }
            }
        }
    }
}

/// A pinhole camera's primary rays (`SCENE_FORMAT.md`: pixel (i, j), i to
/// the right and j downwards, sampled at its centre).
#[derive(Clone, Copy, Debug)]
pub struct CameraFrame {
    pub eye: Vec3,
    /// Unit right, up and forward vectors (right-handed world).
    pub right: Vec3,
    pub up: Vec3,
    pub forward: Vec3,
    /// Half extents of the image plane at distance 1.
    pub half_w: f64,
    pub half_h: f64,
    pub width: u32,
    pub height: u32,
}

impl CameraFrame {
    pub fn new(scene: &Scene, width: u32, height: u32) -> CameraFrame {
        let c = &scene.camera;
        let forward = (c.look_at - c.eye).normalize();
        let right = forward.cross(c.up).normalize();
        let up = right.cross(forward);
        let half_h = (c.fov_y.to_radians() / 2.0).tan();
        let half_w = half_h * width as f64 / height as f64;
        CameraFrame {
            eye: c.eye,
            right,
            up,
            forward,
            half_w,
            half_h,
            width,
            height,
        }
    }

    /// Screen coordinates (x/z, y/z in the camera frame) of the point
    /// (i + fx, j + fy) of the image, fx, fy in [0, 1).
    pub fn screen(&self, i: u32, j: u32, fx: f64, fy: f64) -> (f64, f64) {
        let sx = (2.0 * (i as f64 + fx) / self.width as f64 - 1.0) * self.half_w;
        let sy = (1.0 - 2.0 * (j as f64 + fy) / self.height as f64) * self.half_h;
        (sx, sy)
    }

    /// The ray through screen point (sx, sy): its camera-frame direction is
    /// exactly (sx, sy, 1).
    pub fn ray(&self, sx: f64, sy: f64) -> Ray {
        Ray::new(self.eye, self.right * sx + self.up * sy + self.forward)
    }

    /// The primary job of pixel (i, j) for one sample at offset (fx, fy),
    /// weighted `1/spp`.
    pub fn primary(&self, i: u32, j: u32, fx: f64, fy: f64, weight: f64) -> RayJob {
        let (sx, sy) = self.screen(i, j, fx, fy);
        RayJob {
            ray: self.ray(sx, sy),
            kind: RayKind::Primary,
            pixel: j * self.width + i,
            depth: 0,
            weight: [weight as f32; 3],
            t_max: f64::INFINITY,
            leaving: None,
            light: None,
        }
    }
}
