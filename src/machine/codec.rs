//! The wire format. Every message between nodes and the host is encoded
//! and decoded here and nowhere else, in bincode 2's format (variable
//! width integers, little endian), so that the bytes counted per link are real
//! and the codec can be swapped in this one file (bincode is unmaintained;
//! 3.0.0 is a deliberate compile_error release, hence the pin to 2).
//! Messages travel in envelopes of stamped frames (`append_stamped`).
//!
//! Paths travel in a compact form (`wire_routed`; a node writes it with
//! `RaysOut`, packing as it encodes, and reads it with `unpack_rays`), in
//! bincode's format written and read by hand (`Out`, `In`): the same
//! bytes as bincode's serde encoding of `ToNode::Rays`, which the tests
//! check, at a fraction of serde's cost per field; every other message
//! goes through serde. The form leaves out what the receiving node can
//! recompute exactly from what it already holds: a shadow ray's direction
//! (its light's position minus its origin) and `t_max`, every ray's pixel
//! (the path's sample says it), a walk point's super cell (its cell says
//! it).
//!
//! Finished samples travel to the host packed by hand (`pack_done_into`), as
//! one byte string per batch: a record of a few flags and differences
//! where serde wrote every field whole. On the sphereflake at 512x512 and
//! d = 1, the host's link carried 13% fewer bytes (15.7 MB to 13.6 MB).

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::message::{Active, Finished, Part, Path, Routed};
use crate::cells::traverse::RegionRay;
use crate::cells::{CellStructure, Region, WalkPoint};
use crate::csg::PrimId;
use crate::geom::{Ray, Vec3};
use crate::scene::Light;
use crate::trace::{RayJob, RayKind};

/// Variable-width integers: a path's sample number, fixed-point sums,
/// counts and indices are mostly small. Against fixed-width integers they
/// cut the bytes on the wire by 30% (the sphereflake at 1024x1024 on 32
/// nodes: 1.18 GB to 0.83 GB, 208 to 147 bytes per ray), which the
/// modelled links pay for, at 3-6% more host time to encode and decode.
fn config() -> bincode::config::Configuration<bincode::config::LittleEndian, bincode::config::Varint>
{
    bincode::config::standard()
}

/// The bytes of a message.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>, String> {
    bincode::serde::encode_to_vec(msg, config()).map_err(|e| format!("cannot encode: {e}"))
}

/// A message from its bytes; every byte must be used.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, String> {
    let (msg, used) = bincode::serde::decode_from_slice(bytes, config())
        .map_err(|e| format!("cannot decode a message of {} bytes: {e}", bytes.len()))?;
    if used != bytes.len() {
        return Err(format!(
            "a message of {} bytes has {} trailing bytes",
            bytes.len(),
            bytes.len() - used
        ));
    }
    Ok(msg)
}

/// The length of a stamped frame (`append_stamped`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameLen {
    /// What the modelled machine sends: the length header and the body.
    /// Links are charged for these bytes and they are the ones counted.
    pub wire: usize,
    /// What the frame takes in the envelope, the stamp included: the
    /// bytes a node holds while it waits.
    pub held: usize,
}

/// Bytes of a frame's stamp.
const STAMP: usize = 8;

/// Appends `body` to `envelope` as one stamped frame: the body's length
/// (LEB128: one byte below 128, two below 16,384), the virtual time at
/// which its sender finishes sending it, which `stamp` computes from the
/// frame's length on the wire, and the body's bytes.
///
/// An envelope is what moves over a link in one transfer: one or more
/// frames, each a message of the modelled machine. The emulation gathers
/// the messages a node sends during a slice of its work into one envelope
/// per link, so that a message costs the host one channel operation per
/// slice, not one each; the modelled costs are the frames' own. The stamp
/// (8 bytes, an f64) is the emulation's, as the envelope is: a message of
/// the modelled machine carries no virtual time, so it is neither charged
/// to the link nor counted (`FrameLen::wire`), though it is held.
pub fn append_stamped<T: Serialize>(
    envelope: &mut Vec<u8>,
    body: &T,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<FrameLen, String> {
    append_frame(envelope, |out| encode_into(out, body), stamp)
}

/// Appends a message's bytes to `out` (`append_frame`'s writer for any
/// message but paths).
pub fn encode_into<T: Serialize>(out: &mut Vec<u8>, body: &T) -> Result<(), String> {
    bincode::serde::encode_into_std_write(body, out, config())
        .map(|_| ())
        .map_err(|e| format!("cannot encode: {e}"))
}

/// `append_stamped` with the body written by `write` (`RaysOut::write`).
pub fn append_frame(
    envelope: &mut Vec<u8>,
    write: impl FnOnce(&mut Vec<u8>) -> Result<(), String>,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<FrameLen, String> {
    // The body goes after the header, whose length depends on the body's:
    // encode it at the end, then move it up behind the header.
    let start = envelope.len();
    const ROOM: usize = LEB128_MAX + STAMP;
    envelope.extend_from_slice(&[0u8; ROOM]);
    if let Err(e) = write(envelope) {
        envelope.truncate(start);
        return Err(e);
    }
    let body_len = envelope.len() - start - ROOM;
    let mut head = [0u8; LEB128_MAX];
    let n = leb128(body_len as u64, &mut head);
    let wire = n + body_len;
    let t = stamp(wire);
    envelope[start..start + n].copy_from_slice(&head[..n]);
    envelope[start + n..start + n + STAMP].copy_from_slice(&t.to_le_bytes());
    envelope.copy_within(start + ROOM..start + ROOM + body_len, start + n + STAMP);
    envelope.truncate(start + wire + STAMP);
    Ok(FrameLen {
        wire,
        held: wire + STAMP,
    })
}

/// Gives the frame that starts at byte `frame` of `envelope` (appended by
/// `append_stamped`) the stamp `t` instead of its own. False if no whole
/// frame starts there.
pub fn restamp(envelope: &mut [u8], frame: usize, t: f64) -> bool {
    let Some((_, n)) = envelope.get(frame..).and_then(read_leb128) else {
        return false;
    };
    match envelope.get_mut(frame + n..frame + n + STAMP) {
        Some(stamp) => {
            stamp.copy_from_slice(&t.to_le_bytes());
            true
        }
        None => false,
    }
}

/// The longest LEB128 form of a u64: 64 bits at 7 a byte.
const LEB128_MAX: usize = 10;

/// `v` in LEB128 at the front of `out` (which has room for `LEB128_MAX`
/// bytes); returns the bytes used.
#[inline(always)]
fn leb128(mut v: u64, out: &mut [u8]) -> usize {
    let mut n = 0;
    while v >= 0x80 {
        out[n] = v as u8 | 0x80;
        v >>= 7;
        n += 1;
    }
    out[n] = v as u8;
    n + 1
}

/// A LEB128 number from the front of `bytes`, and the bytes it used.
#[inline]
fn read_leb128(bytes: &[u8]) -> Option<(u64, usize)> {
    let mut v = 0u64;
    for (i, &b) in bytes.iter().enumerate().take(LEB128_MAX) {
        // The tenth byte holds only the top bit.
        if i == LEB128_MAX - 1 && b > 1 {
            return None;
        }
        v |= u64::from(b & 0x7f) << (7 * i);
        if b & 0x80 == 0 {
            return Some((v, i + 1));
        }
    }
    None
}

/// An envelope of one stamped frame, and the frame's length.
pub fn encode_stamped<T: Serialize>(
    body: &T,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<(Vec<u8>, FrameLen), String> {
    let mut envelope = Vec::new();
    let len = append_stamped(&mut envelope, body, stamp)?;
    Ok((envelope, len))
}

/// The frames of an envelope: each one's stamp and message, in order.
pub fn decode_envelope<T: DeserializeOwned>(bytes: &[u8]) -> Result<Vec<(f64, T)>, String> {
    let mut out = Vec::new();
    for_each_frame(bytes, |stamp, body| {
        out.push((stamp, body));
        Ok(())
    })?;
    Ok(out)
}

/// Hands each frame of an envelope, in order, to `take` as it is decoded,
/// without gathering them first (`decode_envelope`); stops at the first
/// error, of the envelope or of `take`.
pub fn for_each_frame<T: DeserializeOwned>(
    bytes: &[u8],
    mut take: impl FnMut(f64, T) -> Result<(), String>,
) -> Result<(), String> {
    for_each_frame_body(bytes, |stamp, body| take(stamp, decode(body)?))
}

/// Hands each frame of an envelope, in order, to `take` as its stamp and
/// its body's bytes, not decoded (`for_each_frame`; a node reads paths
/// straight from them, `rays_in`).
pub fn for_each_frame_body<'b>(
    mut bytes: &'b [u8],
    mut take: impl FnMut(f64, &'b [u8]) -> Result<(), String>,
) -> Result<(), String> {
    while !bytes.is_empty() {
        let Some((body_len, n)) = read_leb128(bytes) else {
            return Err(format!("a frame of {} bytes has no length", bytes.len()));
        };
        let Some(&stamp) = bytes[n..].first_chunk::<8>() else {
            return Err(format!("a frame of {} bytes has no stamp", bytes.len()));
        };
        let stamp = f64::from_le_bytes(stamp);
        let rest = &bytes[n + 8..];
        let body_len = usize::try_from(body_len).unwrap_or(usize::MAX);
        if body_len > rest.len() {
            return Err(format!(
                "a frame claims {body_len} bytes where {} remain",
                rest.len()
            ));
        }
        take(stamp, &rest[..body_len])?;
        bytes = &rest[body_len..];
    }
    Ok(())
}

/// What a node holds that lets paths leave out what it can recompute.
pub struct PathContext<'a> {
    pub lights: &'a [Light],
    /// Samples per pixel of the pass: a sample's pixel is `sample / spp`.
    pub spp: u32,
    pub cells: &'a CellStructure,
}

/// A batch of paths as they travel, as serde sees it (`pack`): the wire
/// format's definition, whose bytes nodes write and read by hand
/// (`RaysOut::write`, `unpack_rays`; the tests hold the two together).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireBatch(Vec<WireRouted>);

/// A path on the wire, its stack a vector of wire rays (as serde sees
/// it). Written by a node, the stack is packed as it is written
/// (`StackOut`); read, the fields before the rays come alone (`S`, `A`
/// unit, `In::head`) and the rays are unpacked as they are read
/// (`In::routed`). The same bytes: a sequence. (A small vector holding four rays in place, to spare the
/// decoder an allocation per path, made the jagged ball's d = 5 render
/// 3-4% slower: the larger paths cost more to move than the allocations
/// saved.)
#[derive(Clone, Debug, Serialize, Deserialize)]
struct WireRouted<S = Vec<WireJob>, A = WireJob> {
    dest: u16,
    hops: u8,
    sample: u64,
    origin: u16,
    sum: [i64; 3],
    /// `forks << 1 | leaf`.
    flags: u32,
    number: u32,
    /// None for +0.0, the usual start.
    t_min: Option<f64>,
    at: Option<WireAt>,
    active: A,
    stack: S,
}

/// A walk point without its super cell: `cell << 2 | clipped << 1 |
/// region`, and where the ray entered it.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
struct WireAt {
    cell: u32,
    entry: WireEntry,
}

/// A walk point's `t_in`: through which face the ray entered (the
/// receiver recomputes the crossing, `CellStructure::entry_crossing`,
/// where that gives the same bits), or the parameter itself.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
enum WireEntry {
    AcrossX,
    AcrossY,
    AcrossDepth,
    At(f64),
}

/// The faces a walk point may name, with the axis each is across
/// (`CellStructure::entry_crossing`).
const FACES: [(WireEntry, usize); 3] = [
    (WireEntry::AcrossX, 0),
    (WireEntry::AcrossY, 1),
    (WireEntry::AcrossDepth, 2),
];

/// The walk's view of `ray` in `region` (as `CellTracer::walk` makes it).
fn region_ray(ray: &Ray, region: Region, ctx: &PathContext) -> RegionRay {
    RegionRay::new(region, ctx.cells.view.ray(ray))
}

fn pack_entry(w: &WalkPoint, ray: &Ray, ctx: &PathContext) -> WireEntry {
    let rr = region_ray(ray, w.region, ctx);
    FACES
        .into_iter()
        .find(|&(_, axis)| {
            let t = ctx.cells.entry_crossing(&rr, w.super_cell, w.cell, axis);
            t.to_bits() == w.t_in.to_bits()
        })
        .map_or(WireEntry::At(w.t_in), |(face, _)| face)
}

fn unpack_entry(e: WireEntry, w: &WalkPoint, ray: &Ray, ctx: &PathContext) -> f64 {
    let axis = match e {
        WireEntry::At(t) => return t,
        WireEntry::AcrossX => 0,
        WireEntry::AcrossY => 1,
        WireEntry::AcrossDepth => 2,
    };
    let rr = region_ray(ray, w.region, ctx);
    ctx.cells.entry_crossing(&rr, w.super_cell, w.cell, axis)
}

#[derive(Clone, Debug, Serialize, Deserialize)]
enum WireJob {
    /// A shadow ray of the path's pixel toward light `light`: its
    /// direction is the light's position minus its origin, its `t_max` 1
    /// (as `Shader::shade` makes them).
    Shadow {
        light: u32,
        origin: [f64; 3],
        depth: u8,
        weight: [f32; 3],
        leaving: Option<PrimId>,
    },
    /// Any other ray of the path's pixel.
    Ray(WireRay),
    /// A ray of another pixel (the shader makes none; kept so that packing
    /// never loses anything).
    Whole(RayJob),
}

/// A ray of the path's pixel but a shadow ray toward a light
/// (`WireJob::Ray`); `t_max` None for infinity. (A struct in a variant is
/// the same bytes as a variant's fields.)
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
struct WireRay {
    kind: u8,
    origin: [f64; 3],
    dir: [f64; 3],
    depth: u8,
    weight: [f32; 3],
    t_max: Option<f64>,
    leaving: Option<PrimId>,
}

fn same(a: Vec3, b: Vec3) -> bool {
    a.to_array()
        .iter()
        .zip(b.to_array())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

fn kind_code(k: RayKind) -> u8 {
    k.index() as u8
}

fn pack_job(j: &RayJob, pixel: u64, ctx: &PathContext) -> WireJob {
    if u64::from(j.pixel) != pixel {
        return WireJob::Whole(*j);
    }
    let origin = j.ray.origin.to_array();
    // The light by the job's own index where it has one (a search over
    // the lights per shadow ray otherwise), checked all the same.
    let toward = |i: usize| {
        ctx.lights
            .get(i)
            .is_some_and(|l| same(l.position - j.ray.origin, j.ray.dir))
    };
    if j.kind == RayKind::Shadow
        && j.t_max.to_bits() == 1f64.to_bits()
        && let Some(i) = j
            .light
            .map(usize::from)
            .filter(|&i| toward(i))
            .or_else(|| (0..ctx.lights.len()).find(|&i| toward(i)))
    {
        return WireJob::Shadow {
            light: i as u32,
            origin,
            depth: j.depth,
            weight: j.weight,
            leaving: j.leaving,
        };
    }
    WireJob::Ray(WireRay {
        kind: kind_code(j.kind),
        origin,
        dir: j.ray.dir.to_array(),
        depth: j.depth,
        weight: j.weight,
        t_max: (j.t_max != f64::INFINITY).then_some(j.t_max),
        leaving: j.leaving,
    })
}

/// (Inlined into `In::routed` with `In::job` and the readers of
/// fields: `glass.ron`'s CPU at the default topology 0.973-0.977x, seven
/// and five interleaved pairs; `house.ron`'s the same.)
#[inline(always)]
fn unpack_job(w: WireJob, pixel: u32, ctx: &PathContext) -> Result<RayJob, String> {
    Ok(match w {
        WireJob::Shadow {
            light,
            origin,
            depth,
            weight,
            leaving,
        } => {
            let l = ctx
                .lights
                .get(light as usize)
                .ok_or_else(|| format!("a shadow ray toward light {light}, which is not there"))?;
            let origin = Vec3::from_array(origin);
            RayJob {
                ray: Ray::new(origin, l.position - origin),
                kind: RayKind::Shadow,
                pixel,
                depth,
                weight,
                t_max: 1.0,
                leaving,
                light: u16::try_from(light).ok(),
            }
        }
        WireJob::Ray(r) => RayJob {
            ray: Ray::new(Vec3::from_array(r.origin), Vec3::from_array(r.dir)),
            kind: *RayKind::ALL
                .get(r.kind as usize)
                .ok_or_else(|| format!("a ray of kind {}, which is none", r.kind))?,
            pixel,
            depth: r.depth,
            weight: r.weight,
            t_max: r.t_max.unwrap_or(f64::INFINITY),
            leaving: r.leaving,
            light: None,
        },
        WireJob::Whole(j) => j,
    })
}

/// Paths in their wire form, as a batch: what `RaysOut` writes, built
/// whole (the tests' reference for it).
#[cfg(test)]
pub fn pack(paths: &[Routed], ctx: &PathContext) -> WireBatch {
    WireBatch(
        paths
            .iter()
            .map(|r| wire_routed(r, ctx, |st| st.jobs().collect()))
            .collect(),
    )
}

/// `ToNode::Rays(pack(paths, ctx))` as bincode writes it, packed while it
/// is written (`RaysOut::write`): the same bytes
/// (`tests::paths_unpack_exactly_as_packed_and_smaller`), without the
/// batch and a vector per path's stack built first and dropped. At d = 5
/// the allocator and copying took a tenth of the machine's CPU, much of it
/// in such intermediate vectors.
pub struct RaysOut<'a, 'c> {
    pub paths: &'a [Carried],
    pub ctx: &'a PathContext<'c>,
}

/// `ToNode::Rays`'s place among `ToNode`'s variants, as serde numbers them
/// (reordering the variants fails the test that `RaysOut` cites).
const RAYS_VARIANT: u8 = 1;

impl RaysOut<'_, '_> {
    /// Appends the message's bytes to `out` (`append_frame`).
    ///
    /// Written by hand in bincode's own format (`Out`), not through serde:
    /// paths are nearly all the bytes the nodes send and receive, and
    /// serde's calls per field took 15% of a d = 5 render's CPU and 26% of
    /// the house's at the default topology (perf, 2026-12-06).
    pub fn write(&self, out: &mut Vec<u8>) -> Result<(), String> {
        let mut o = Out(out);
        o.byte(RAYS_VARIANT);
        o.uint(self.paths.len() as u64);
        for c in self.paths {
            let r = match c {
                Carried::Path(r) => r,
                Carried::Passing(p) => {
                    o.0.extend_from_slice(&p.bytes);
                    continue;
                }
            };
            // Room for the path's most bytes, so that the writes below
            // do not grow the buffer one by one.
            o.0.reserve(MAX_PATH_HEAD + MAX_JOB_BYTES * (1 + r.path.stack.len()));
            let w = wire_routed(r, self.ctx, |st| st);
            o.uint(w.dest.into());
            o.byte(w.hops);
            o.uint(w.sample);
            o.uint(w.origin.into());
            for c in w.sum {
                o.int(c);
            }
            o.uint(w.flags.into());
            o.uint(w.number.into());
            o.option(w.t_min, Out::f64);
            o.option(w.at, |o, a| {
                o.uint(a.cell.into());
                // `WireEntry`'s variant index, and `At`'s parameter.
                match a.entry {
                    WireEntry::AcrossX => o.byte(0),
                    WireEntry::AcrossY => o.byte(1),
                    WireEntry::AcrossDepth => o.byte(2),
                    WireEntry::At(t) => {
                        o.byte(3);
                        o.f64(t);
                    }
                }
            });
            o.job(&w.active)?;
            o.uint(w.stack.jobs.len() as u64);
            for j in w.stack.jobs() {
                o.job(&j)?;
            }
        }
        Ok(())
    }
}

/// bincode 2's standard encoding (little endian, variable-width integers),
/// written by hand for the paths (`RaysOut::write`; read back by `In`):
/// an integer of up to 250 is one byte, a larger one a marker byte (251,
/// 252, 253) and 2, 4 or 8 bytes; a signed one is zigzagged first; a `u8`
/// is its byte; an option a byte 0 or 1 before its value; an enum its
/// variant index as an integer; a sequence its length as one; floats their
/// bytes.
struct Out<'v>(&'v mut Vec<u8>);

/// The most bytes of a path's fields before its rays (`RaysOut::write`):
/// nine integers of up to 9 bytes (the walk point's cell among them),
/// `hops`, `t_min` (a tag and a float) and the walk point's tag, entry
/// and parameter.
const MAX_PATH_HEAD: usize = 9 * 9 + 1 + (1 + 8) + (1 + 1 + 8);
/// The most bytes of a ray but one sent whole (`WireJob::Ray`).
const MAX_JOB_BYTES: usize = 1 + 1 + 24 + 24 + 1 + 12 + 9 + 6;

/// bincode's markers of a 2-, 4- and 8-byte integer (`Out::uint`).
const U16_MARK: u8 = 251;
const U32_MARK: u8 = 252;
const U64_MARK: u8 = 253;

impl Out<'_> {
    #[inline(always)]
    fn byte(&mut self, b: u8) {
        self.0.push(b);
    }

    #[inline(always)]
    fn uint(&mut self, v: u64) {
        if v < u64::from(U16_MARK) {
            self.0.push(v as u8);
        } else if let Ok(v) = u16::try_from(v) {
            self.0.push(U16_MARK);
            self.0.extend_from_slice(&v.to_le_bytes());
        } else if let Ok(v) = u32::try_from(v) {
            self.0.push(U32_MARK);
            self.0.extend_from_slice(&v.to_le_bytes());
        } else {
            self.0.push(U64_MARK);
            self.0.extend_from_slice(&v.to_le_bytes());
        }
    }

    #[inline(always)]
    fn int(&mut self, v: i64) {
        self.uint(zigzag(v));
    }

    #[inline(always)]
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    #[inline]
    fn f32s(&mut self, v: [f32; 3]) {
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }

    #[inline]
    fn f64s(&mut self, v: [f64; 3]) {
        for x in v {
            self.f64(x);
        }
    }

    #[inline]
    fn option<T>(&mut self, v: Option<T>, put: impl FnOnce(&mut Self, T)) {
        match v {
            None => self.byte(0),
            Some(x) => {
                self.byte(1);
                put(self, x);
            }
        }
    }

    fn job(&mut self, j: &WireJob) -> Result<(), String> {
        let leaving = |o: &mut Self, l: Option<PrimId>| o.option(l, |o, p| o.uint(p.0.into()));
        match *j {
            WireJob::Shadow {
                light,
                origin,
                depth,
                weight,
                leaving: l,
            } => {
                self.byte(0);
                self.uint(light.into());
                self.f64s(origin);
                self.byte(depth);
                self.f32s(weight);
                leaving(self, l);
            }
            WireJob::Ray(r) => {
                self.byte(1);
                self.byte(r.kind);
                self.f64s(r.origin);
                self.f64s(r.dir);
                self.byte(r.depth);
                self.f32s(r.weight);
                self.option(r.t_max, Self::f64);
                leaving(self, r.leaving);
            }
            // Never made by the shader: through serde, as written whole.
            WireJob::Whole(ref job) => {
                self.byte(2);
                encode_into(self.0, job)?;
            }
        }
        Ok(())
    }
}

/// Reads what `Out` writes, as bincode reads it: an integer's marker must
/// fit its type, an option's byte be 0 or 1, a variant index
/// name a variant.
struct In<'b> {
    bytes: &'b [u8],
    at: usize,
}

/// The fewest bytes a ray takes on the wire (`WireJob::Shadow`: its
/// variant, light, origin, depth, weight and an absent `leaving`): a
/// stack's length claims no more rays than its message has room for.
const MIN_JOB_BYTES: usize = 1 + 1 + 24 + 1 + 12 + 1;

impl<'b> In<'b> {
    #[cold]
    fn cut(&self) -> String {
        format!("a batch of paths cut short at byte {}", self.at)
    }

    #[inline(always)]
    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let a = self
            .bytes
            .get(self.at..)
            .and_then(|b| b.first_chunk::<N>())
            .copied()
            .ok_or_else(|| self.cut())?;
        self.at += N;
        Ok(a)
    }

    #[inline(always)]
    fn byte(&mut self) -> Result<u8, String> {
        Ok(self.array::<1>()?[0])
    }

    /// An integer of at most `width` bytes.
    #[inline(always)]
    fn uint(&mut self, width: usize) -> Result<u64, String> {
        let b = self.byte()?;
        let (v, w) = match b {
            U16_MARK => (u64::from(u16::from_le_bytes(self.array()?)), 2),
            U32_MARK => (u64::from(u32::from_le_bytes(self.array()?)), 4),
            U64_MARK => (u64::from_le_bytes(self.array()?), 8),
            b if b < U16_MARK => (u64::from(b), 1),
            b => return Err(format!("an integer marked {b} at byte {}", self.at - 1)),
        };
        if w > width {
            return Err(format!(
                "an integer of {w} bytes where {width} fit, at byte {}",
                self.at
            ));
        }
        Ok(v)
    }

    #[inline(always)]
    fn u16(&mut self) -> Result<u16, String> {
        Ok(self.uint(2)? as u16)
    }

    #[inline(always)]
    fn u32(&mut self) -> Result<u32, String> {
        Ok(self.uint(4)? as u32)
    }

    #[inline(always)]
    fn int(&mut self) -> Result<i64, String> {
        Ok(unzigzag(self.uint(8)?))
    }

    #[inline(always)]
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }

    #[inline(always)]
    fn f32s(&mut self) -> Result<[f32; 3], String> {
        let mut v = [0.0; 3];
        for x in &mut v {
            *x = f32::from_le_bytes(self.array()?);
        }
        Ok(v)
    }

    #[inline(always)]
    fn f64s(&mut self) -> Result<[f64; 3], String> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }

    /// A variant index below `count`.
    #[inline(always)]
    fn variant(&mut self, count: u32, of: &str) -> Result<u32, String> {
        let v = self.u32()?;
        if v < count {
            Ok(v)
        } else {
            Err(format!("{of} of variant {v}, which is none"))
        }
    }

    #[inline(always)]
    fn option<T>(
        &mut self,
        get: impl FnOnce(&mut Self) -> Result<T, String>,
    ) -> Result<Option<T>, String> {
        match self.byte()? {
            0 => Ok(None),
            1 => get(self).map(Some),
            b => Err(format!("an option tagged {b} at byte {}", self.at - 1)),
        }
    }

    #[inline(always)]
    fn job(&mut self) -> Result<WireJob, String> {
        let leaving = |i: &mut Self| i.option(|i| i.u32().map(PrimId));
        Ok(match self.variant(3, "a ray")? {
            0 => WireJob::Shadow {
                light: self.u32()?,
                origin: self.f64s()?,
                depth: self.byte()?,
                weight: self.f32s()?,
                leaving: leaving(self)?,
            },
            1 => WireJob::Ray(WireRay {
                kind: self.byte()?,
                origin: self.f64s()?,
                dir: self.f64s()?,
                depth: self.byte()?,
                weight: self.f32s()?,
                t_max: self.option(Self::f64)?,
                leaving: leaving(self)?,
            }),
            _ => {
                let (job, used) =
                    bincode::serde::decode_from_slice(&self.bytes[self.at..], config())
                        .map_err(|e| format!("cannot decode a ray: {e}"))?;
                self.at += used;
                WireJob::Whole(job)
            }
        })
    }

    /// A path's fields before its rays (`RaysOut::write`).
    fn head(&mut self) -> Result<WireRouted<(), ()>, String> {
        Ok(WireRouted {
            dest: self.u16()?,
            hops: self.byte()?,
            sample: self.uint(8)?,
            origin: self.u16()?,
            sum: [self.int()?, self.int()?, self.int()?],
            flags: self.u32()?,
            number: self.u32()?,
            t_min: self.option(Self::f64)?,
            at: self.option(|i| {
                let cell = i.u32()?;
                let entry = match i.variant(4, "a walk point's entry")? {
                    0 => WireEntry::AcrossX,
                    1 => WireEntry::AcrossY,
                    2 => WireEntry::AcrossDepth,
                    _ => WireEntry::At(i.f64()?),
                };
                Ok(WireAt { cell, entry })
            })?,
            active: (),
            stack: (),
        })
    }

    /// A stack's length, no more than its message has room for.
    fn stack_len(&mut self) -> Result<(u64, usize), String> {
        let n = self.uint(8)?;
        let room = (self.bytes.len() - self.at) / MIN_JOB_BYTES;
        Ok((n, usize::try_from(n).unwrap_or(usize::MAX).min(room)))
    }

    /// A path (`RaysOut::write`), unpacked, `spp` samples to a pixel.
    fn routed(&mut self, spp: u64, ctx: &PathContext) -> Result<Routed, String> {
        let head = self.head()?;
        let pixel = pixel_of(head.sample, spp)?;
        let active = unpack_job(self.job()?, pixel, ctx)?;
        let (n, room) = self.stack_len()?;
        let mut stack = Vec::with_capacity(room);
        for _ in 0..n {
            stack.push(unpack_job(self.job()?, pixel, ctx)?);
        }
        routed_from(head, active, stack, ctx)
    }

    /// A path passing through (`Passing`): read to its end, so that its
    /// bytes are known to be one whole path, and kept as they are.
    fn passing(&mut self) -> Result<Passing, String> {
        let start = self.at;
        let head = self.head()?;
        self.job()?;
        let (n, _) = self.stack_len()?;
        for _ in 0..n {
            self.job()?;
        }
        Ok(Passing {
            dest: head.dest,
            sample: head.sample,
            bytes: self.bytes[start..self.at].into(),
        })
    }
}

/// A path passing through a node on its way to `dest` (e-cube routing),
/// kept as the bytes it arrived in (`unpack_rays`): the node that passes
/// it on needs only where it goes and its sample (the order of its
/// queue), and writes the bytes out again with one more hop
/// (`Passing::add_hop`). Unpacking and packing it again, as the node that
/// traces it will, took a third of the codec's time where a third of the
/// hops are such passes (`glass.ron`, `house.ron` on 32 nodes).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Passing {
    pub dest: u16,
    pub sample: u64,
    bytes: Box<[u8]>,
}

impl Passing {
    /// The bytes a node holds for it.
    pub fn held(&self) -> usize {
        std::mem::size_of::<Passing>() + self.bytes.len()
    }

    /// Counts one more link crossed: the hop count is the byte after the
    /// destination (one byte below `U16_MARK`, else the marker and two).
    pub fn add_hop(&mut self) -> Result<(), String> {
        let at = if self.bytes[0] < U16_MARK { 1 } else { 3 };
        self.bytes[at] = self.bytes[at]
            .checked_add(1)
            .ok_or("a path past 255 hops")?;
        Ok(())
    }
}

/// A path as a node holds it: its own to trace (or to send on, once
/// traced), or one passing through.
#[derive(Clone, Debug)]
pub enum Carried {
    /// Boxed, so that a passing path, whose bytes are on the heap
    /// already, takes no second allocation where a node queues it.
    Path(Box<Routed>),
    Passing(Passing),
}

impl Carried {
    pub fn dest(&self) -> u16 {
        match self {
            Carried::Path(r) => r.dest,
            Carried::Passing(p) => p.dest,
        }
    }

    pub fn sample(&self) -> u64 {
        match self {
            Carried::Path(r) => r.path.sample,
            Carried::Passing(p) => p.sample,
        }
    }

    /// The bytes a node holds for it (`Path::bytes`, `Passing::held`).
    pub fn held(&self) -> usize {
        match self {
            Carried::Path(r) => r.path.bytes(),
            Carried::Passing(p) => p.held(),
        }
    }

    /// Counts one more link crossed (`Routed::hops`).
    pub fn add_hop(&mut self) -> Result<(), String> {
        match self {
            Carried::Path(r) => {
                r.hops = r.hops.checked_add(1).ok_or("a path past 255 hops")?;
                Ok(())
            }
            Carried::Passing(p) => p.add_hop(),
        }
    }
}

/// The batch of paths in a frame's body, if it is `ToNode::Rays`
/// (`unpack_rays` reads it); None for any other message.
pub fn rays_in(body: &[u8]) -> Option<&[u8]> {
    match body.split_first() {
        Some((&RAYS_VARIANT, batch)) => Some(batch),
        _ => None,
    }
}

/// The paths of a batch (`rays_in`) as node `me` takes them, each handed
/// to `take` as it is read from the bytes, with no decoded batch or
/// per-path vector of wire rays between: a path to `me` exactly as it was
/// packed, any other passing through as its bytes (`Passing`). An error
/// for bytes that are not such a batch, or a path to `me` that names a
/// light, kind or cell the node does not have. Stops at the first error,
/// of the batch or of `take`, the paths before it taken.
pub fn unpack_rays(
    batch: &[u8],
    ctx: &PathContext,
    me: u16,
    mut take: impl FnMut(Carried) -> Result<(), String>,
) -> Result<(), String> {
    let spp = u64::from(ctx.spp.max(1));
    let mut input = In {
        bytes: batch,
        at: 0,
    };
    let n = input.uint(8)?;
    for _ in 0..n {
        // Its destination first, to tell a path to trace here from one
        // passing through (`Passing`).
        let start = input.at;
        let dest = input.u16()?;
        input.at = start;
        take(if dest == me {
            Carried::Path(Box::new(input.routed(spp, ctx)?))
        } else {
            Carried::Passing(input.passing()?)
        })?;
    }
    if input.at != batch.len() {
        return Err(format!(
            "a batch of paths of {} bytes has {} trailing bytes",
            batch.len() + 1,
            batch.len() - input.at
        ));
    }
    Ok(())
}

/// A path's stack, packed as it is written (`wire_routed`).
#[derive(Clone, Copy)]
struct StackOut<'a, 'c> {
    jobs: &'a [RayJob],
    pixel: u64,
    ctx: &'a PathContext<'c>,
}

impl StackOut<'_, '_> {
    fn jobs(&self) -> impl ExactSizeIterator<Item = WireJob> + '_ {
        self.jobs.iter().map(|j| pack_job(j, self.pixel, self.ctx))
    }
}

/// A path's wire form, its stack made by `stack` from the stack still to
/// be packed (`StackOut`): the one place that decides what a path leaves
/// out (`pack`, `RaysOut`).
fn wire_routed<'a, 'c, S>(
    r: &'a Routed,
    ctx: &'a PathContext<'c>,
    stack: impl FnOnce(StackOut<'a, 'c>) -> S,
) -> WireRouted<S> {
    let spp = u64::from(ctx.spp.max(1));
    let p = &r.path;
    let pixel = p.sample / spp;
    let a = &p.active;
    WireRouted {
        dest: r.dest,
        hops: r.hops,
        sample: p.sample,
        origin: p.origin,
        sum: p.sum,
        flags: u32::from(p.forks) << 1 | u32::from(p.leaf),
        number: a.number,
        t_min: (a.t_min.to_bits() != 0f64.to_bits()).then_some(a.t_min),
        at: a.at.map(|w| WireAt {
            cell: w.cell << 2 | u32::from(w.clipped) << 1 | (w.region == Region::Back) as u32,
            entry: pack_entry(&w, &a.job.ray, ctx),
        }),
        active: pack_job(&a.job, pixel, ctx),
        stack: stack(StackOut {
            jobs: &p.stack,
            pixel,
            ctx,
        }),
    }
}

/// The pixel of sample `sample`, `spp` samples to a pixel.
fn pixel_of(sample: u64, spp: u64) -> Result<u32, String> {
    u32::try_from(sample / spp).map_err(|_| format!("sample {sample} is past every pixel"))
}

/// A path from its wire form's fields (`In::head`) and its rays, unpacked.
fn routed_from(
    w: WireRouted<(), ()>,
    job: RayJob,
    stack: Vec<RayJob>,
    ctx: &PathContext,
) -> Result<Routed, String> {
    let at = match w.at {
        None => None,
        Some(a) => {
            let region = if a.cell & 1 == 1 {
                Region::Back
            } else {
                Region::Front
            };
            let cell = a.cell >> 2;
            let clipped = a.cell & 2 != 0;
            let rc = ctx.cells.region(region);
            if cell as usize >= rc.cell_count() {
                return Err(format!("a path at cell {cell}, which is none"));
            }
            let mut p = WalkPoint {
                region,
                super_cell: rc.super_cell_of(cell),
                cell,
                t_in: 0.0,
                clipped,
            };
            p.t_in = unpack_entry(a.entry, &p, &job.ray, ctx);
            Some(p)
        }
    };
    Ok(Routed {
        dest: w.dest,
        hops: w.hops,
        path: Path {
            sample: w.sample,
            origin: w.origin,
            sum: w.sum,
            active: Active {
                job,
                number: w.number,
                t_min: w.t_min.unwrap_or(0.0),
                at,
            },
            stack,
            forks: u16::try_from(w.flags >> 1)
                .map_err(|_| format!("a path with {} forks", w.flags >> 1))?,
            leaf: w.flags & 1 == 1,
        },
    })
}

/// A batch of finished samples as it travels (`pack_done_into`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WireDone(Vec<u8>);

impl Serialize for WireDone {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(&self.0)
    }
}

impl<'de> Deserialize<'de> for WireDone {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Bytes;
        impl serde::de::Visitor<'_> for Bytes {
            type Value = WireDone;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("finished samples as bytes")
            }
            fn visit_bytes<E>(self, v: &[u8]) -> Result<WireDone, E> {
                Ok(WireDone(v.to_vec()))
            }
            fn visit_byte_buf<E>(self, v: Vec<u8>) -> Result<WireDone, E> {
                Ok(WireDone(v))
            }
        }
        d.deserialize_byte_buf(Bytes)
    }
}

/// Flags of a finished sample's record (`pack_done_into`).
const DONE_TRACED: u8 = 1;
const DONE_CREDITED: u8 = 2;
const DONE_LEAF: u8 = 4;
/// The sample's origin is not the sending node, and follows.
const DONE_ORIGIN: u8 = 8;

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    (v >> 1) as i64 ^ -((v & 1) as i64)
}

/// The most bytes of a finished record packed by `pack_done_into`: a
/// flags byte and five numbers of up to `LEB128_MAX` bytes.
const MAX_DONE_RECORD: usize = 1 + 5 * LEB128_MAX;

/// The most bytes a node holds per finished record, in its list of
/// records (`Finished`) or encoded in a message to the host waiting for
/// the host's link: the record itself, and, were it alone in its
/// message, the frame's header (its length, up to `LEB128_MAX` bytes), stamp, the
/// message's tag (1), node (up to 3) and the records' length (up to 5).
/// The host's memory plan sizes the records no credit covers by it
/// (`host::Plan::local_credits`).
pub const DONE_RECORD_BOUND: usize = {
    let encoded = MAX_DONE_RECORD + LEB128_MAX + STAMP + 1 + 3 + 5;
    let decoded = std::mem::size_of::<Finished>();
    if encoded > decoded { encoded } else { decoded }
};

/// The finished samples that node `node` sends, each record a flags byte
/// and LEB128 numbers: its sample as the (zigzag) difference from the
/// record before (a node finishes neighbouring pixels together), its
/// origin only when not `node`, a root's fork count, and its three
/// fixed-point sums (zigzag). Into `w`, whose bytes are replaced: a node
/// packs every batch into the same buffer.
pub fn pack_done_into(node: u16, finished: &[Finished], w: &mut WireDone) {
    let out = &mut w.0;
    out.clear();
    out.reserve(finished.len() * 24);
    let mut prev = 0u64;
    for f in finished {
        let mut rec = [0u8; MAX_DONE_RECORD];
        let mut n = 1;
        let mut put = |v: u64| n += leb128(v, &mut rec[n..]);
        put(zigzag(f.sample.wrapping_sub(prev) as i64));
        prev = f.sample;
        let mut flags = 0;
        if f.traced {
            flags |= DONE_TRACED;
        }
        if f.credited {
            flags |= DONE_CREDITED;
        }
        if f.origin != node {
            flags |= DONE_ORIGIN;
            put(u64::from(f.origin));
        }
        match f.part {
            Part::Leaf => flags |= DONE_LEAF,
            Part::Root { forks } => put(u64::from(forks)),
        }
        for c in f.sum {
            put(zigzag(c));
        }
        rec[0] = flags;
        out.extend_from_slice(&rec[..n]);
    }
}

/// The finished samples of a batch from node `node`, exactly as packed,
/// each given to `take` in turn (without a `Vec` per batch: at d = 1 a
/// node sends some 200,000 batches a second of a few samples each); an
/// error for bytes that are not such a batch.
pub fn for_each_done(
    node: u16,
    w: &WireDone,
    mut take: impl FnMut(Finished),
) -> Result<(), String> {
    let bytes = &w.0[..];
    let (mut at, mut prev) = (0, 0u64);
    let cut = || "a finished sample cut short".to_string();
    let small =
        |v: u64, what: &str| u16::try_from(v).map_err(|_| format!("{what} {v} is too large"));
    while let Some(&flags) = bytes.get(at) {
        if flags & !(DONE_TRACED | DONE_CREDITED | DONE_LEAF | DONE_ORIGIN) != 0 {
            return Err(format!("a finished sample with flags {flags:#x}"));
        }
        at += 1;
        let mut next = || {
            let (v, n) = read_leb128(&bytes[at..]).ok_or_else(cut)?;
            at += n;
            Ok::<u64, String>(v)
        };
        let sample = prev.wrapping_add(unzigzag(next()?) as u64);
        prev = sample;
        let origin = if flags & DONE_ORIGIN != 0 {
            small(next()?, "origin")?
        } else {
            node
        };
        let part = if flags & DONE_LEAF != 0 {
            Part::Leaf
        } else {
            Part::Root {
                forks: small(next()?, "fork count")?,
            }
        };
        let sum = [unzigzag(next()?), unzigzag(next()?), unzigzag(next()?)];
        take(Finished {
            sample,
            origin,
            sum,
            traced: flags & DONE_TRACED != 0,
            credited: flags & DONE_CREDITED != 0,
            part,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::message::ToNode;

    fn pack_done(node: u16, finished: &[Finished]) -> WireDone {
        let mut w = WireDone::default();
        pack_done_into(node, finished, &mut w);
        w
    }

    /// `for_each_done` into a `Vec`.
    fn unpack_done(node: u16, w: &WireDone) -> Result<Vec<Finished>, String> {
        let mut out = Vec::new();
        for_each_done(node, w, |f| out.push(f))?;
        Ok(out)
    }

    type Msg = Vec<(u32, f64, Option<String>)>;

    #[test]
    fn finished_samples_unpack_exactly_as_packed_and_smaller() {
        let f = |sample, origin, sum, traced, credited, part| Finished {
            sample,
            origin,
            sum,
            traced,
            credited,
            part,
        };
        let batch = vec![
            f(7, 3, [0, 1, -1], true, true, Part::Root { forks: 0 }),
            f(
                8,
                3,
                [1 << 40, -(1 << 40), 5],
                true,
                false,
                Part::Root { forks: 4 },
            ),
            f(2, 9, [i64::MAX, i64::MIN, 0], false, false, Part::Leaf),
            f(u64::MAX, 65535, [-1, -2, -3], true, false, Part::Leaf),
            f(0, 0, [0; 3], false, true, Part::Root { forks: u16::MAX }),
        ];
        let w = pack_done(3, &batch);
        let back = unpack_done(3, &decode(&encode(&w).unwrap()).unwrap()).unwrap();
        assert_eq!(format!("{back:?}"), format!("{batch:?}"));
        assert!(encode(&w).unwrap().len() < encode(&batch).unwrap().len());
        assert!(unpack_done(3, &WireDone::default()).unwrap().is_empty());
        // Cut short anywhere, or with unknown flags, it is refused.
        for cut in 1..w.0.len() {
            let short = WireDone(w.0[..cut].to_vec());
            assert!(unpack_done(3, &short).map_or(true, |v| v.len() < batch.len()));
        }
        assert!(unpack_done(3, &WireDone(w.0[..w.0.len() - 1].to_vec())).is_err());
        assert!(unpack_done(3, &WireDone(vec![0x10, 0])).is_err());
        // An origin or fork count past 16 bits is refused.
        assert!(
            unpack_done(
                3,
                &WireDone(vec![DONE_ORIGIN, 0, 0x80, 0x80, 4, 0, 0, 0, 0])
            )
            .is_err()
        );
    }

    #[test]
    fn round_trip_and_rejects_garbage() {
        let v: Vec<(u32, f64, Option<String>)> =
            vec![(1, -0.0, None), (7, 1e300, Some("x".into()))];
        let b = encode(&v).unwrap();
        let back: Vec<(u32, f64, Option<String>)> = decode(&b).unwrap();
        assert_eq!(back[0].1.to_bits(), (-0.0f64).to_bits());
        assert_eq!(back, v);
        let mut long = b.clone();
        long.push(0);
        assert!(decode::<Vec<(u32, f64, Option<String>)>>(&long).is_err());
        assert!(decode::<Vec<(u32, f64, Option<String>)>>(&b[..b.len() - 1]).is_err());
        let mut seen = 0;
        let (mut env, len) = encode_stamped(&v, |len| {
            seen = len;
            2.5
        })
        .unwrap();
        // The stamp is held, not sent: the wire has the header and body.
        assert_eq!(seen, len.wire);
        assert_eq!((len.held, env.len()), (len.wire + 8, len.wire + 8));
        assert_eq!(len.wire, 1 + b.len());
        let n = append_stamped(&mut env, &vec![(3u32, 0.5f64, None::<String>)], |_| 4.0).unwrap();
        assert_eq!(env.len(), len.held + n.held);
        let back: Vec<(f64, Msg)> = decode_envelope(&env).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!((back[0].0, &back[0].1), (2.5, &v));
        assert_eq!((back[1].0, back[1].1[0].0), (4.0, 3));
        let short = decode_envelope::<u8>(&[1, 2]).unwrap_err();
        assert!(short.contains("has no stamp"), "{short}");
        assert!(decode_envelope::<u8>(&env[..env.len() - 1]).is_err());
        // A frame's stamp is replaced in place, whichever frame it is, and
        // nothing else changes; no frame starts beyond the envelope.
        let before = env.clone();
        assert!(restamp(&mut env, len.held, 7.0));
        assert!(restamp(&mut env, 0, 6.0));
        let back: Vec<(f64, Msg)> = decode_envelope(&env).unwrap();
        assert_eq!((back[0].0, &back[0].1), (6.0, &v));
        assert_eq!((back[1].0, back[1].1[0].0), (7.0, 3));
        assert_eq!(env.len(), before.len());
        assert!(!restamp(&mut env, before.len(), 1.0));
        assert!(!restamp(&mut env, before.len() - 3, 1.0));
    }

    /// A ball under two lights at 8x8, built into several super cells, so
    /// that rays cross side faces.
    fn ball_scene() -> (crate::scene::Scene, CellStructure) {
        use crate::cells::CellOptions;
        use crate::scene::load::{SceneSyntax, parse_scene_str};
        let scene = parse_scene_str(
            "(camera: (eye: (0, -5, 0), look_at: (0, 0, 0), fov_y: 40, width: 8, height: 8),
              lights: [(position: (0, 0, 5)), (position: (3, -1, 2))],
              objects: [Sphere(center: (0, 0, 0), radius: 1)])",
            SceneSyntax::Ron,
            std::path::Path::new("t.ron"),
        )
        .unwrap();
        let cells = CellStructure::build(
            &scene,
            8,
            8,
            CellOptions {
                min_super_cells: 16,
                ..CellOptions::default()
            },
        )
        .unwrap();
        (scene, cells)
    }

    /// The light the shader names on a shadow ray from `o` along `dir`
    /// (`RayJob::light`): the one it ends at exactly.
    fn light_from(
        scene: &crate::scene::Scene,
        kind: RayKind,
        o: Vec3,
        dir: Vec3,
        t_max: f64,
    ) -> Option<u16> {
        (kind == RayKind::Shadow && t_max == 1.0)
            .then(|| scene.lights.iter().position(|l| l.position - o == dir))
            .flatten()
            .map(|i| i as u16)
    }

    #[test]
    fn paths_unpack_exactly_as_packed_and_smaller() {
        let (scene, cells) = ball_scene();
        let ctx = PathContext {
            lights: &scene.lights,
            spp: 4,
            cells: &cells,
        };
        let (sample, pixel) = (4 * 37 + 3, 37);
        let o = Vec3::new(0.25, -1.0 / 3.0, 1e-300);
        let light_of = |kind, dir, t_max| light_from(&scene, kind, o, dir, t_max);
        let job = |kind, dir: Vec3, pixel, t_max| RayJob {
            ray: Ray::new(o, dir),
            kind,
            pixel,
            depth: 2,
            weight: [0.5, -0.0, f32::MIN_POSITIVE],
            t_max,
            // None, and a whole-scene index past what one byte holds.
            leaving: (t_max == 1.0).then_some(PrimId(70_000)),
            light: light_of(kind, dir, t_max),
        };
        let toward = |i: usize| scene.lights[i].position - o;
        let back = cells.region(Region::Back);
        let last = back.cell_count() as u32 - 1;
        let path = |active, stack, t_min, at| Routed {
            dest: 3,
            hops: 2,
            path: Path {
                sample,
                origin: 7,
                sum: [i64::MIN, 0, -1],
                active: Active {
                    job: active,
                    number: 9,
                    t_min,
                    at,
                },
                stack,
                forks: 4,
                leaf: true,
            },
        };
        let paths = vec![
            // A shadow ray toward each light, and one toward no light.
            path(
                job(RayKind::Shadow, toward(1), pixel, 1.0),
                vec![
                    job(RayKind::Shadow, toward(0), pixel, 1.0),
                    job(RayKind::Shadow, toward(0) * 2.0, pixel, 1.0),
                    job(RayKind::Shadow, toward(0), pixel, 0.5),
                ],
                -0.0,
                Some(WalkPoint {
                    region: Region::Back,
                    super_cell: back.super_cell_of(last),
                    cell: last,
                    t_in: 0.125,
                    clipped: true,
                }),
            ),
            // Reflected and refracted rays, finite and infinite t_max, a ray
            // of another pixel.
            path(
                job(RayKind::Reflected, Vec3::X, pixel, f64::INFINITY),
                vec![
                    job(RayKind::Refracted, -Vec3::Y, pixel, 3.0),
                    job(RayKind::Primary, Vec3::Z, pixel + 1, f64::INFINITY),
                ],
                2.5,
                None,
            ),
        ];
        // Walk points whose entry the receiver recomputes: a cell and face
        // of each axis that the ray crosses.
        let mut paths = paths;
        let front = cells.region(Region::Front);
        let ray = Ray::new(o, Vec3::new(0.3, 1.0, -0.2));
        let rr = RegionRay::new(Region::Front, cells.view.ray(&ray));
        let mut recomputed = [false; 3];
        for s in 0..front.supers.len() as u32 {
            for (axis, done) in recomputed.iter_mut().enumerate() {
                let k = front.cells_of(s).end as u32 - 1;
                let t = cells.entry_crossing(&rr, s, k, axis);
                if *done || !t.is_finite() {
                    continue;
                }
                *done = true;
                let mut p = paths[1].clone();
                p.path.active.job.ray = ray;
                p.path.active.at = Some(WalkPoint {
                    region: Region::Front,
                    super_cell: s,
                    cell: k,
                    t_in: t,
                    clipped: false,
                });
                let packed = pack(std::slice::from_ref(&p), &ctx);
                let entry = packed.0[0].at.unwrap().entry;
                assert!(
                    !matches!(entry, WireEntry::At(_)),
                    "axis {axis}: sent whole"
                );
                paths.push(p);
            }
        }
        assert!(
            recomputed.iter().filter(|&&r| r).count() >= 2,
            "{recomputed:?} {:?} {:?}",
            rr.m,
            front.supers.iter().map(|s| s.rect).collect::<Vec<_>>()
        );
        let batch = pack(&paths, &ctx);
        // A node writes the same bytes as bincode's serde without the batch
        // (`RaysOut`), and reads them back exactly.
        let streamed = rays_bytes(&paths, &ctx);
        assert_eq!(streamed, encode(&ToNode::Rays(batch.clone())).unwrap());
        let ToNode::Rays(again) = decode::<ToNode>(&streamed).unwrap() else {
            panic!("streamed paths decode as another message");
        };
        assert_eq!(format!("{again:?}"), format!("{batch:?}"));
        let back_again = read_rays(&streamed, &ctx, 3).unwrap();
        assert_eq!(format!("{paths:?}"), format!("{back_again:?}"));
        for r in &back_again {
            // Its memory is counted by its capacity (`Path::bytes`).
            assert_eq!(r.path.stack.capacity(), r.path.stack.len());
        }
        for (a, b) in paths.iter().zip(&back_again) {
            let (a, b) = (&a.path, &b.path);
            assert_eq!(a.active.t_min.to_bits(), b.active.t_min.to_bits());
            for (x, y) in
                std::iter::once((&a.active.job, &b.active.job)).chain(a.stack.iter().zip(&b.stack))
            {
                assert!(same(x.ray.dir, y.ray.dir) && same(x.ray.origin, y.ray.origin));
                assert_eq!(x.weight.map(f32::to_bits), y.weight.map(f32::to_bits));
            }
        }
        // Smaller than the paths themselves on the wire.
        assert!(streamed.len() + 100 < encode(&paths).unwrap().len());
        // A light or cell the node does not have is an error, not a panic.
        let one_light = PathContext {
            lights: &scene.lights[..1],
            ..ctx
        };
        assert!(read_rays(&streamed, &one_light, 3).is_err());
        let mut far = paths[0].clone();
        far.path.active.at.as_mut().unwrap().cell = last + 1;
        assert!(read_rays(&rays_bytes(&[far], &ctx), &ctx, 3).is_err());
    }

    /// `RaysOut::write`'s bytes for paths a node holds decoded.
    fn rays_bytes(paths: &[Routed], ctx: &PathContext) -> Vec<u8> {
        carried_bytes(
            &paths
                .iter()
                .map(|r| Carried::Path(Box::new(r.clone())))
                .collect::<Vec<_>>(),
            ctx,
        )
    }

    /// `RaysOut::write`'s bytes.
    fn carried_bytes(paths: &[Carried], ctx: &PathContext) -> Vec<u8> {
        let mut out = Vec::new();
        RaysOut { paths, ctx }.write(&mut out).unwrap();
        out
    }

    /// `unpack_rays` of a message's bytes by node `me`, gathered.
    fn read_carried(bytes: &[u8], ctx: &PathContext, me: u16) -> Result<Vec<Carried>, String> {
        let batch = rays_in(bytes).ok_or("not a batch of paths")?;
        let mut paths = Vec::new();
        unpack_rays(batch, ctx, me, |c| {
            paths.push(c);
            Ok(())
        })?;
        Ok(paths)
    }

    /// `read_carried` of paths to `me` alone.
    fn read_rays(bytes: &[u8], ctx: &PathContext, me: u16) -> Result<Vec<Routed>, String> {
        read_carried(bytes, ctx, me)?
            .into_iter()
            .map(|c| match c {
                Carried::Path(r) => Ok(*r),
                Carried::Passing(p) => Err(format!("a path to {} passing", p.dest)),
            })
            .collect()
    }

    /// Paths read by hand (`unpack_rays`) as bincode's serde reads them,
    /// whatever their numbers' widths; and bytes cut short, lengthened or
    /// changed are an error or other paths, never a panic.
    #[test]
    fn paths_are_read_by_hand_as_serde_reads_them() {
        let (scene, cells) = ball_scene();
        let ctx = PathContext {
            lights: &scene.lights,
            spp: 2,
            cells: &cells,
        };
        let o = Vec3::new(0.5, -2.0, 0.25);
        let job = |kind, dir, pixel, t_max, leaving| RayJob {
            ray: Ray::new(o, dir),
            kind,
            pixel,
            depth: 3,
            weight: [0.25, 1.0, 0.5],
            t_max,
            leaving,
            light: light_from(&scene, kind, o, dir, t_max),
        };
        let mut paths = Vec::new();
        // Numbers on every side of each width's marker.
        let widths = [
            0u64,
            250,
            251,
            65_535,
            65_536,
            u64::from(u32::MAX),
            u64::MAX,
        ];
        for (i, &v) in widths.iter().enumerate() {
            let pixel = u32::try_from(v / 2).unwrap_or(u32::MAX - 1);
            let sample = 2 * u64::from(pixel) + (v & 1);
            let small = u16::try_from(v).unwrap_or(u16::MAX);
            let shadow = job(
                RayKind::Shadow,
                scene.lights[i % 2].position - o,
                pixel,
                1.0,
                u32::try_from(v).ok().map(PrimId),
            );
            paths.push(Routed {
                dest: small,
                hops: i as u8,
                path: Path {
                    sample,
                    origin: small,
                    sum: [v as i64, -(v as i64), i64::MIN + i as i64],
                    active: Active {
                        job: if i % 2 == 0 {
                            shadow
                        } else {
                            job(RayKind::Reflected, Vec3::Y, pixel, 2.0, None)
                        },
                        number: u32::try_from(v).unwrap_or(u32::MAX),
                        t_min: if i % 3 == 0 { 0.0 } else { 0.5 },
                        at: None,
                    },
                    stack: (0..i)
                        .map(|k| match k % 3 {
                            0 => shadow,
                            1 => job(RayKind::Refracted, -Vec3::Z, pixel, f64::INFINITY, None),
                            _ => job(RayKind::Primary, Vec3::X, pixel ^ 1, 3.0, None),
                        })
                        .collect(),
                    forks: small,
                    leaf: i % 2 == 1,
                },
            });
        }
        let bytes = rays_bytes(&paths, &ctx);
        let batch = pack(&paths, &ctx);
        assert_eq!(bytes, encode(&ToNode::Rays(batch)).unwrap());
        // Node 65535 unpacks the paths to it, and keeps the others, passing
        // through, as their own bytes: written on with a hop more, they are
        // the bytes of the path with a hop more.
        let me = u16::MAX;
        let read = read_carried(&bytes, &ctx, me).unwrap();
        assert_eq!(read.len(), paths.len());
        let mut passing = 0;
        for (c, r) in read.iter().zip(&paths) {
            let mut on = r.clone();
            on.hops += 1;
            let mut c = c.clone();
            c.add_hop().unwrap();
            assert_eq!(carried_bytes(&[c.clone()], &ctx), rays_bytes(&[on], &ctx));
            match c {
                Carried::Path(mut q) => {
                    assert_eq!(r.dest, me);
                    q.hops -= 1;
                    assert_eq!(format!("{q:?}"), format!("{r:?}"));
                }
                Carried::Passing(p) => {
                    passing += 1;
                    assert_ne!(r.dest, me);
                    assert_eq!((p.dest, p.sample), (r.dest, r.path.sample));
                    assert!(p.held() <= r.path.bytes());
                }
            }
        }
        assert!(passing >= 3 && passing < paths.len(), "{passing}");
        // Every cut is an error; so is a byte more.
        for n in 1..bytes.len() {
            assert!(read_carried(&bytes[..n], &ctx, me).is_err(), "cut at {n}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(read_carried(&longer, &ctx, me).is_err());
        // Any byte changed: bytes serde cannot read, the hand reader
        // refuses too; what it reads, serde reads as paths with the same
        // numbers and as many rays. (It also refuses lights, kinds and
        // cells the node does not have, which serde's form does not know
        // of; and packing again may choose a shorter form of a ray than
        // the changed bytes have, so whole batches are not compared.)
        let mut both = 0;
        for n in 1..bytes.len() {
            for x in [1u8, 2, 4, 7, 0x80, 0xff] {
                let mut b = bytes.clone();
                b[n] ^= x;
                let hand = read_carried(&b, &ctx, me);
                match decode::<ToNode>(&b) {
                    Ok(ToNode::Rays(WireBatch(w))) => {
                        let Ok(p) = hand else { continue };
                        both += 1;
                        // A path passing through: where it goes and its
                        // sample; one unpacked: its numbers too.
                        let numbers = |c: &Carried| {
                            let Carried::Path(r) = c else {
                                return (c.dest(), c.sample(), None);
                            };
                            let q = &r.path;
                            let flags = u32::from(q.forks) << 1 | u32::from(q.leaf);
                            let t = q.active.t_min;
                            let t_min = (t.to_bits() != 0).then_some(t.to_bits());
                            let n = (r.hops, q.origin, q.sum, flags, q.active.number);
                            (r.dest, q.sample, Some((n, t_min, q.stack.len())))
                        };
                        let wire = |r: &WireRouted| {
                            if r.dest != me {
                                return (r.dest, r.sample, None);
                            }
                            let n = (r.hops, r.origin, r.sum, r.flags, r.number);
                            let t_min = r.t_min.filter(|t| t.to_bits() != 0).map(f64::to_bits);
                            (r.dest, r.sample, Some((n, t_min, r.stack.len())))
                        };
                        let ours: Vec<_> = p.iter().map(numbers).collect();
                        let serde: Vec<_> = w.iter().map(wire).collect();
                        assert_eq!(ours, serde, "byte {n} ^ {x:#x}");
                    }
                    _ => assert!(hand.is_err(), "byte {n} ^ {x:#x}"),
                }
            }
        }
        assert!(
            both > bytes.len(),
            "{both} of {} changes read",
            6 * bytes.len()
        );
    }

    /// The host's memory plan counts a path at most twice its decoded
    /// bytes, for its decoded and its encoded form at once
    /// (`host::path_bound`), with its stack's capacity at most the stack's
    /// length bound: so a path's frame, alone in its message (the most
    /// header per path), must never take more than the path decoded with
    /// a stack of exactly its length. Checked with every field at its
    /// largest wire form: numbers at the most bytes their encoding takes,
    /// the entry parameter sent whole, rays of another pixel (sent whole).
    #[test]
    fn a_paths_frame_is_never_larger_than_the_path_decoded() {
        let (scene, cells) = ball_scene();
        let ctx = PathContext {
            lights: &scene.lights,
            spp: 1,
            cells: &cells,
        };
        let job = |pixel| RayJob {
            ray: Ray::new(Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.4, 0.5, 0.6)),
            kind: RayKind::Reflected,
            pixel,
            depth: u8::MAX,
            weight: [1.0; 3],
            t_max: 0.7,
            leaving: Some(PrimId(u32::MAX)),
            light: None,
        };
        let front = cells.region(Region::Front);
        for n in 0..=16 {
            let r = Routed {
                dest: u16::MAX,
                hops: u8::MAX,
                path: Path {
                    sample: u64::MAX,
                    origin: u16::MAX,
                    sum: [i64::MIN; 3],
                    active: Active {
                        job: job(0),
                        number: u32::MAX,
                        t_min: 0.3,
                        at: Some(WalkPoint {
                            region: Region::Front,
                            super_cell: 0,
                            cell: front.cell_count() as u32 - 1,
                            t_in: 0.123_456_789,
                            clipped: true,
                        }),
                    },
                    stack: (0..n).map(|_| job(u32::MAX)).collect(),
                    forks: u16::MAX,
                    leaf: true,
                },
            };
            let paths = [Carried::Path(Box::new(r))];
            let out = RaysOut {
                paths: &paths,
                ctx: &ctx,
            };
            let mut frame = Vec::new();
            let len = append_frame(&mut frame, |b| out.write(b), |_| 0.0).unwrap();
            let decoded = std::mem::size_of::<Path>() + n * std::mem::size_of::<RayJob>();
            assert!(
                len.held <= decoded,
                "{n} rays: frame {} bytes, decoded {decoded}",
                len.held
            );
            // Passing through a node, the path is held as its bytes: no
            // more than decoded either.
            let mut bytes = Vec::new();
            out.write(&mut bytes).unwrap();
            let [Carried::Passing(p)] = &read_carried(&bytes, &ctx, 0).unwrap()[..] else {
                panic!("a path to node {} does not pass node 0", u16::MAX);
            };
            assert!(p.held() <= decoded, "{n} rays: held {}", p.held());
        }
    }
}
