//! The flat per-object-colour variant of a scene, for comparing renderers
//! pixel by pixel (`hypercast convert --flat`, the POV-Ray cross-check):
//! every primitive gets a material of its own whose colour encodes its
//! number, lit by ambient light alone (ambient 1, nothing else, no lights),
//! so a pixel's colour says which primitive it sees and nothing about
//! shading. Both renderers get the same model; only the geometry, the
//! camera and CSG decide the picture. Owns the colour code and its inverse.
//!
//! The code: primitive `k` (1-based, in depth-first order of the model; 0
//! is the background, black) gets colour digits in base `LEVELS` of
//! `k · STRIDE mod CODES`, each digit `d` the linear value `d / (LEVELS −
//! 1)`. Levels 1/39 apart survive 8-bit sRGB and 16-bit linear files with
//! room to spare; the stride (coprime to `CODES`) gives neighbouring
//! primitives unlike colours, so a flat image is readable by eye.

use std::collections::BTreeMap;

use super::model::{Material, Node, SceneFile, Vector};
use crate::{Error, Result};

/// Values per colour channel.
pub const LEVELS: u32 = 40;
/// Distinct codes: the background and at most `CODES − 1` primitives.
pub const CODES: u32 = LEVELS * LEVELS * LEVELS;
/// Multiplier scattering consecutive numbers over the codes; coprime to
/// `CODES` (= 2^9 · 5^3), so the map is a bijection.
const STRIDE: u32 = 40_503;
/// `STRIDE`'s inverse modulo `CODES`.
const STRIDE_INVERSE: u32 = inverse(STRIDE, CODES);

/// `a⁻¹ mod m` by the extended Euclidean algorithm (`a`, `m` coprime).
const fn inverse(a: u32, m: u32) -> u32 {
    let (mut r0, mut r1) = (m as i64, a as i64);
    let (mut t0, mut t1) = (0i64, 1i64);
    while r1 != 0 {
        let q = r0 / r1;
        (r0, r1) = (r1, r0 - q * r1);
        (t0, t1) = (t1, t0 - q * t1);
    }
    t0.rem_euclid(m as i64) as u32
}

/// The linear colour of primitive number `k` (0: the background).
pub fn color(k: u32) -> Vector {
    let code = (u64::from(k) * u64::from(STRIDE) % u64::from(CODES)) as u32;
    let digit = |i: u32| f64::from(code / LEVELS.pow(i) % LEVELS) / f64::from(LEVELS - 1);
    [digit(0), digit(1), digit(2)]
}

/// The primitive number whose colour is nearest to a linear colour.
pub fn number(linear: [f32; 3]) -> u32 {
    let digit = |c: f32| ((c.clamp(0.0, 1.0) * (LEVELS - 1) as f32).round() as u32).min(LEVELS - 1);
    let code = digit(linear[0]) + LEVELS * (digit(linear[1]) + LEVELS * digit(linear[2]));
    (u64::from(code) * u64::from(STRIDE_INVERSE) % u64::from(CODES)) as u32
}

/// The flat variant of a model: the same camera, geometry and tree; each
/// primitive's material replaced by its own flat colour (`p1`, `p2`, … in
/// depth-first order), operators' materials dropped, no lights, a black
/// background, white ambient light and no recursion. Refuses a model with
/// `CODES` primitives or more (their colours would repeat).
pub fn flat_model(model: &SceneFile) -> Result<SceneFile> {
    // Renumbering walks the tree: on the loading thread's large stack.
    super::load::on_load_stack(|| {
        let mut count = 0u32;
        let objects = model
            .objects
            .iter()
            .map(|n| relabel(n, &mut count))
            .collect();
        if count >= CODES {
            return Err(Error::Usage(format!(
                "the scene has {count} primitives; flat colours tell at most {} apart",
                CODES - 1
            )));
        }
        let materials = (1..=count)
            .map(|k| {
                let m = Material {
                    color: Some(color(k)),
                    ambient: Some(1.0),
                    diffuse: Some(0.0),
                    specular: Some(0.0),
                    reflect: Some(0.0),
                    transmit: Some(0.0),
                    ..Material::default()
                };
                (format!("p{k}"), m)
            })
            .collect::<BTreeMap<_, _>>();
        Ok(SceneFile {
            camera: model.camera.clone(),
            background: color(0),
            ambient: [1.0; 3],
            lights: Vec::new(),
            materials,
            objects,
            max_depth: 0,
        })
    })?
}

/// `node` with every leaf's material `p<k>` (numbered from `count + 1`)
/// and no material on operators.
fn relabel(node: &Node, count: &mut u32) -> Node {
    let children = |cs: &[Node], count: &mut u32| cs.iter().map(|c| relabel(c, count)).collect();
    match node {
        Node::Union { children: cs, .. } => Node::Union {
            children: children(cs, count),
            material: None,
        },
        Node::Intersection { children: cs, .. } => Node::Intersection {
            children: children(cs, count),
            material: None,
        },
        Node::Difference { children: cs, .. } => Node::Difference {
            children: children(cs, count),
            material: None,
        },
        Node::Assembly { children: cs, .. } => Node::Assembly {
            children: children(cs, count),
            material: None,
        },
        Node::Transform {
            translate,
            rotate,
            scale,
            child,
            ..
        } => Node::Transform {
            translate: *translate,
            rotate: *rotate,
            scale: *scale,
            child: Box::new(relabel(child, count)),
            material: None,
        },
        leaf => {
            *count += 1;
            let mut n = leaf.clone();
            *n.material_mut() = Some(format!("p{count}"));
            n
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_decode_to_their_number_and_the_background_is_black() {
        assert_eq!(color(0), [0.0; 3]);
        for k in (0..CODES).step_by(7).chain([1, 2, CODES - 1]) {
            let c = color(k).map(|x| x as f32);
            assert_eq!(number(c), k, "{k}: {c:?}");
        }
        assert_eq!(
            (u64::from(STRIDE) * u64::from(STRIDE_INVERSE)) % u64::from(CODES),
            1
        );
    }

    #[test]
    fn neighbours_get_unlike_colours() {
        let (a, b) = (color(1), color(2));
        let d: f64 = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum();
        assert!(d > 0.3, "{a:?} {b:?}");
    }

    #[test]
    fn every_leaf_gets_its_own_material_and_operators_none() {
        let model = crate::r#gen::random_csg(3, 30, &Default::default());
        let flat = flat_model(&model).unwrap();
        let (scene, _) =
            crate::scene::load::compile_model(&flat, std::path::Path::new("flat")).unwrap();
        assert!(flat.lights.is_empty());
        let mut ids: Vec<u32> = scene.primitives.iter().map(|p| p.material.0).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), scene.primitives.len());
        assert_eq!(flat.materials.len(), scene.primitives.len());
        for m in flat.materials.values() {
            assert_eq!(m.ambient, Some(1.0));
        }
    }
}
