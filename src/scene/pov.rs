//! POV-Ray 3.7 scene description language (SDL) of a scene model, so that
//! any scene can be cross-checked in the renderer our users know
//! (`hypercast convert SCENE -o OUT.pov`). Owns the mapping of
//! `SCENE_FORMAT.md` onto POV-Ray: camera, lights, materials, primitives,
//! CSG and transforms. Reads a validated model; renders nothing.
//!
//! **Handedness.** Our world is right-handed; POV-Ray's is left-handed.
//! Coordinates are written unchanged and the camera gets `right -x*aspect`:
//! POV-Ray keeps the sign of `right` relative to `up × direction` when it
//! aims the camera with `look_at` and `sky`, so the negated `right` mirrors
//! the image back and a point that appears right of centre here appears
//! right of centre there. Rotations need no change: POV-Ray's `rotate
//! <x, y, z>` turns about x, then y, then z with the same matrices as
//! `Transform.rotate` (its "left-hand rule" is the same matrix seen in a
//! left-handed frame). POV-Ray's `angle` is the horizontal field of view:
//! `2·atan(tan(fov_y/2)·width/height)`, from the camera's own size, so render
//! at that aspect ratio.
//!
//! **Shading** maps Whitted's terms one to one: `ambient` (times the global
//! `ambient_light`), `diffuse`, `phong`/`phong_size` (highlights in the
//! light's colour, as ours), `reflection` (constant, not coloured by the
//! pigment), `interior { ior }`; lights are point lights without fading;
//! `max_trace_level` is `max_depth + 1` (POV-Ray counts the eye ray) and
//! `adc_bailout 0`, because hypercast never cuts a ray off by its weight, so
//! both trace the same ray tree. Transmission is approximate: POV-Ray's
//! `transmit` also dims the surface's own ambient and diffuse by `1 − t`,
//! which the exporter compensates for by dividing them by `1 − t` (when
//! `t < 1`); how POV-Ray attenuates shadows and highlights through glass
//! differs from ours in details.
//!
//! **CSG.** Intersection and difference map to POV-Ray's. Our unions are
//! regularised for solids (inner faces vanish) while surfaces (triangles,
//! polygons, open cylinders and cones) are always kept. POV-Ray's `union`
//! keeps every inner face, its `merge` removes them and also removes
//! surfaces inside solids. The two agree with ours wherever no inner face
//! can be seen, which is decided per top-level object: an object is
//! *careful* when it holds a transmissive material or the eye is inside it
//! (its spans along a ray from the eye, unclipped, contain the eye). In a
//! careful object every union is a `merge` of its solids, its surfaces
//! written beside it; and the top-level objects whose bounds overlap a
//! careful one are written together with it under one `merge` (solids) with
//! their surfaces apart: our meaning exactly. Everything else keeps plain
//! `union`s and separate top-level objects, which POV-Ray renders much
//! faster (a `merge` tests every hit for being inside its siblings), so a
//! scene with one glass is not slowed down everywhere. Assemblies are
//! unions. A box of zero thickness (which bounds nothing here) becomes an
//! empty intersection of two half-spaces.
//!
//! **Materials** inherit as ours do: POV-Ray applies a CSG object's
//! material to every part that has none, so a material is written where
//! the model names it, and top-level objects without one get the default.

use std::fmt::Write as _;
use std::path::Path;

use super::model::{Node, SceneFile, Vector};
use super::nff::number;
use super::{Material, Scene};
use crate::Result;
use crate::csg::{CsgNode, EvalCounts, Evaluator};
use crate::geom::Ray;

/// Writes `model` as a POV-Ray 3.7 scene; `source` names it in the header
/// and in messages. The model is validated first.
pub fn write_pov(model: &SceneFile, source: &Path) -> Result<String> {
    // Every walk below recurses once per tree level: on the loading
    // thread's large stack, like every other walk of a model.
    super::load::on_load_stack(|| {
        let (scene, _) = super::load::compile(model, source)?;
        let plan = TopLevel::plan(&scene, model.objects.len());
        let mut w = PovWriter {
            scene: &scene,
            out: String::new(),
            regularise: false,
        };
        w.header(model, source);
        w.objects(model, &plan);
        Ok(w.out)
    })?
}

/// How the top-level objects are written (see the module docs).
struct TopLevel {
    /// Per object: holds a transmissive material, or the eye.
    careful: Vec<bool>,
    /// Per object: the group it is merged with (the index of the group's
    /// first object), or None for an object written on its own.
    group: Vec<Option<usize>>,
}

impl TopLevel {
    fn plan(scene: &Scene, objects: usize) -> TopLevel {
        let tree = &scene.tree;
        let nodes = tree.root.map_or(&[][..], |r| tree.children_of(r));
        if nodes.len() != objects {
            // Not the one-node-per-object tree `load` builds: be careful
            // everywhere, which is exact, only slower in POV-Ray.
            return TopLevel {
                careful: vec![true; objects],
                group: vec![Some(0); objects],
            };
        }
        let cam = &scene.camera;
        let ray = Ray::new(cam.eye, cam.look_at - cam.eye);
        let mut eval = Evaluator::new();
        let mut counts = EvalCounts::default();
        let careful: Vec<bool> = nodes
            .iter()
            .map(|&node| {
                let mut stack = vec![node];
                let mut transmissive = false;
                while let Some(n) = stack.pop() {
                    if let CsgNode::Leaf(p) = tree.nodes[n.index()] {
                        let m = scene.material(scene.primitives[p.index()].material);
                        transmissive |= m.transmit > 0.0;
                    }
                    stack.extend_from_slice(tree.children_of(n));
                }
                let spans = eval.evaluate(tree, node, &ray, false, &mut counts, |p| {
                    scene.primitives[p.index()].intersect(&ray)
                });
                let eye_inside = spans
                    .spans
                    .iter()
                    .any(|s| s.enter.t <= 0.0 && s.exit.t >= 0.0);
                transmissive || eye_inside
            })
            .collect();
        // Union-find over "overlaps a careful object".
        let mut parent: Vec<usize> = (0..objects).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let bounds = |i: usize| tree.cull_bounds[nodes[i].index()];
        for i in (0..objects).filter(|&i| careful[i]) {
            for j in 0..objects {
                if j != i && bounds(i).overlaps(&bounds(j)) {
                    let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                    parent[a.max(b)] = a.min(b);
                }
            }
        }
        let mut size = vec![0usize; objects];
        for i in 0..objects {
            let r = root(&mut parent, i);
            size[r] += 1;
        }
        let group = (0..objects)
            .map(|i| {
                let r = root(&mut parent, i);
                (size[r] > 1 || careful[i]).then_some(r)
            })
            .collect();
        TopLevel { careful, group }
    }
}

/// `<x, y, z>`.
fn vector(v: Vector) -> String {
    format!("<{}, {}, {}>", number(v[0]), number(v[1]), number(v[2]))
}

/// Which parts of the tree a pass writes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Part {
    All,
    Solids,
    Surfaces,
}

impl Part {
    /// Whether `node`'s subtree holds anything of this part.
    fn holds(self, node: &Node) -> bool {
        match (self, node) {
            (Part::All, _) => true,
            (_, Node::Union { children, .. } | Node::Assembly { children, .. }) => {
                children.iter().any(|c| self.holds(c))
            }
            (_, Node::Transform { child, .. }) => self.holds(child),
            // Validation keeps surfaces out of intersections and differences.
            (part, Node::Intersection { .. } | Node::Difference { .. }) => part == Part::Solids,
            (part, leaf) => leaf.is_surface() == (part == Part::Surfaces),
        }
    }
}

struct PovWriter<'a> {
    scene: &'a Scene,
    out: String,
    /// The object being written is careful: its unions of solids are
    /// `merge`s (see the module docs).
    regularise: bool,
}

impl PovWriter<'_> {
    /// Writes `text` on a line of its own, indented by its level of
    /// nesting up to `load::PRETTY_DEPTH`, as the other scene writers do:
    /// a tree that loads may be 48,000 levels deep, and indenting each of
    /// its lines fully would take billions of spaces.
    fn line(&mut self, indent: usize, text: &str) {
        let indent = 2 * indent.min(crate::scene::load::PRETTY_DEPTH);
        // Writing to a String cannot fail (here and below).
        let _ = writeln!(self.out, "{:indent$}{text}", "");
    }

    fn header(&mut self, model: &SceneFile, source: &Path) {
        let c = &model.camera;
        let aspect = f64::from(c.width) / f64::from(c.height);
        let angle = 2.0
            * ((c.fov_y.to_radians() / 2.0).tan() * aspect)
                .atan()
                .to_degrees();
        let _ = write!(
            self.out,
            "// POV-Ray 3.7 scene written by hypercast from {src}.\n\
             // Render at the camera's aspect ratio, e.g.\n\
             //   povray +I<this file> +W{w} +H{h} -A File_Gamma=sRGB\n\
             // (-A: one ray per pixel, as hypercast's default). The world is\n\
             // right-handed; `right -x*aspect` mirrors POV-Ray's left-handed\n\
             // camera to match, so coordinates are unchanged.\n\
             #version 3.7;\n\n\
             global_settings {{\n  assumed_gamma 1.0\n  ambient_light rgb {amb}\n  \
             max_trace_level {depth}\n  adc_bailout 0\n}}\n\n\
             camera {{\n  perspective\n  location {eye}\n  sky {up}\n  up y\n  \
             right -x*{aspect}\n  angle {angle}\n  look_at {at}\n}}\n\n\
             background {{ rgb {bg} }}\n\n",
            src = source.display(),
            w = c.width,
            h = c.height,
            amb = vector(model.ambient),
            // Our depth counts secondary generations; POV-Ray's the eye ray too.
            depth = model.max_depth + 1,
            eye = vector(c.eye),
            up = vector(c.up),
            aspect = number(aspect),
            angle = number(angle),
            at = vector(c.look_at),
            bg = vector(model.background),
        );
        for l in &model.lights {
            let _ = writeln!(
                self.out,
                "light_source {{ {} color rgb {} }}",
                vector(l.position),
                vector(l.color)
            );
        }
        self.out.push('\n');
        for (i, (m, name)) in self
            .scene
            .materials
            .iter()
            .zip(&self.scene.material_names)
            .enumerate()
        {
            let decl = material(i, m, name);
            self.out.push_str(&decl);
        }
        self.out.push('\n');
    }

    fn objects(&mut self, model: &SceneFile, plan: &TopLevel) {
        for (i, node) in model.objects.iter().enumerate() {
            match plan.group[i] {
                None => {
                    self.regularise = false;
                    self.node(node, 0, Part::All, None, true, &[]);
                }
                // A group is written where its first object stands.
                Some(g) if g == i => self.group(model, plan, g),
                Some(_) => {}
            }
        }
    }

    /// The objects of group `g`: their solids under one `merge` (unions
    /// inside careful objects merged too), their surfaces beside it.
    fn group(&mut self, model: &SceneFile, plan: &TopLevel, g: usize) {
        let members: Vec<usize> = (g..model.objects.len())
            .filter(|&i| plan.group[i] == Some(g))
            .collect();
        let solids: Vec<usize> = members
            .iter()
            .copied()
            .filter(|&i| Part::Solids.holds(&model.objects[i]))
            .collect();
        if !solids.is_empty() {
            self.line(0, "merge {");
            for &i in &solids {
                self.regularise = plan.careful[i];
                self.node(&model.objects[i], 1, Part::Solids, None, true, &[]);
            }
            self.line(0, "}");
        }
        for &i in &members {
            if Part::Surfaces.holds(&model.objects[i]) {
                self.regularise = plan.careful[i];
                self.node(&model.objects[i], 0, Part::Surfaces, None, true, &[]);
            }
        }
    }

    /// Writes the `part` of `node` at `indent`. `chain_material` is the
    /// material of `Transform`s directly above (which POV-Ray, having no
    /// transform node, cannot hold); `top` says no ancestor names one, so a
    /// node without its own gets the default; `outer` are the transforms
    /// directly above, innermost first.
    fn node(
        &mut self,
        node: &Node,
        indent: usize,
        part: Part,
        chain_material: Option<&str>,
        top: bool,
        outer: &[String],
    ) {
        let own = node.material().or(chain_material);
        let material = match own {
            Some(name) => Some(self.material_id(name)),
            None if top => Some(0),
            None => None,
        };
        let mods = |w: &mut Self, indent: usize| {
            if let Some(id) = material {
                w.line(indent, &format!("material {{ HC_M{id} }}"));
            }
            for t in outer {
                w.line(indent, t);
            }
        };
        let open = |w: &mut Self, text: String| w.line(indent, &text);
        match node {
            Node::Transform {
                translate,
                rotate,
                scale,
                child,
                ..
            } => {
                let mut chain = Vec::with_capacity(outer.len() + 1);
                chain.push(transform(*scale, *rotate, *translate));
                chain.extend_from_slice(outer);
                // The child inherits this node's material unless it has one.
                let top = top && own.is_none();
                self.node(child, indent, part, own, top, &chain);
            }
            Node::Union { children, .. }
            | Node::Assembly { children, .. }
            | Node::Intersection { children, .. }
            | Node::Difference { children, .. } => {
                let keyword = match node {
                    Node::Intersection { .. } => "intersection",
                    Node::Difference { .. } => "difference",
                    _ if self.regularise && part == Part::Solids => "merge",
                    _ => "union",
                };
                open(self, format!("{keyword} {{"));
                let inner_top = top && material.is_none();
                // Intersections and differences hold solids only, so
                // every child of theirs passes the filter.
                for child in children.iter().filter(|c| part.holds(c)) {
                    self.node(child, indent + 1, part, None, inner_top, &[]);
                }
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Sphere { center, radius, .. } => {
                open(
                    self,
                    format!("sphere {{ {}, {}", vector(*center), number(*radius)),
                );
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Box { min, max, .. } => {
                if (0..3).any(|k| min[k] == max[k]) {
                    // Bounds no volume, renders as nothing (ROBUSTNESS.md
                    // case 13): an empty solid keeps CSG meaning intact.
                    open(
                        self,
                        "intersection { plane { x, -1 } plane { -x, -1 }  // zero-thickness box: empty"
                            .into(),
                    );
                } else {
                    open(self, format!("box {{ {}, {}", vector(*min), vector(*max)));
                }
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Cylinder {
                base,
                top: t,
                radius,
                capped,
                ..
            } => {
                open(
                    self,
                    format!(
                        "cylinder {{ {}, {}, {}{}",
                        vector(*base),
                        vector(*t),
                        number(*radius),
                        if *capped { "" } else { " open" }
                    ),
                );
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Cone {
                base,
                base_radius,
                top: t,
                top_radius,
                capped,
                ..
            } => {
                open(
                    self,
                    format!(
                        "cone {{ {}, {}, {}, {}{}",
                        vector(*base),
                        number(*base_radius),
                        vector(*t),
                        number(*top_radius),
                        if *capped { "" } else { " open" }
                    ),
                );
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Triangle { a, b, c, .. } => {
                open(
                    self,
                    format!("triangle {{ {}, {}, {}", vector(*a), vector(*b), vector(*c)),
                );
                mods(self, indent + 1);
                self.line(indent, "}");
            }
            Node::Polygon { vertices, .. } => {
                // POV-Ray closes a polygon by repeating its first vertex.
                let mut text = format!("polygon {{ {}", vertices.len() + 1);
                for v in vertices.iter().chain(vertices.first()) {
                    text.push_str(", ");
                    text.push_str(&vector(*v));
                }
                open(self, text);
                mods(self, indent + 1);
                self.line(indent, "}");
            }
        }
    }

    /// The index in `scene.materials` of a material name (the model was
    /// compiled, so it is known; 0, the default, otherwise).
    fn material_id(&self, name: &str) -> usize {
        self.scene
            .material_names
            .iter()
            .position(|n| n == name)
            .unwrap_or(0)
    }
}

/// `Transform`'s scale, rotation and translation, in its order.
fn transform(scale: Vector, rotate: Vector, translate: Vector) -> String {
    let mut t = Vec::new();
    if scale != [1.0; 3] {
        t.push(format!("scale {}", vector(scale)));
    }
    if rotate != [0.0; 3] {
        t.push(format!("rotate {}", vector(rotate)));
    }
    if translate != [0.0; 3] {
        t.push(format!("translate {}", vector(translate)));
    }
    t.join(" ")
}

/// The `#declare` of material `id`, with its name as a comment.
fn material(id: usize, m: &Material, name: &str) -> String {
    let c = m.color.to_array();
    let t = m.transmit;
    // POV-Ray dims a transmitting surface's own light by 1 − t; we do not.
    let undim = if t > 0.0 && t < 1.0 {
        1.0 / (1.0 - t)
    } else {
        1.0
    };
    let pigment = if t > 0.0 {
        format!(
            "rgbt <{}, {}, {}, {}>",
            number(c[0]),
            number(c[1]),
            number(c[2]),
            number(t)
        )
    } else {
        format!("rgb {}", vector(c))
    };
    let mut finish = format!(
        "ambient {} diffuse {}",
        number(m.ambient * undim),
        number(m.diffuse * undim)
    );
    if m.specular > 0.0 {
        let _ = write!(
            finish,
            " phong {} phong_size {}",
            number(m.specular),
            number(m.shininess)
        );
    }
    if m.reflect > 0.0 {
        let _ = write!(finish, " reflection {{ {} }}", number(m.reflect));
    }
    format!(
        "#declare HC_M{id} = material {{  // {name:?}\n  texture {{ pigment {{ {pigment} }} \
         finish {{ {finish} }} }}\n  interior {{ ior {} }}\n}}\n",
        number(m.ior)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneSyntax;
    use crate::scene::load::parse_model_str;

    fn pov(ron: &str) -> String {
        let model = parse_model_str(ron, SceneSyntax::Ron, Path::new("t.ron")).unwrap();
        write_pov(&model, Path::new("t.ron")).unwrap()
    }

    const CAMERA: &str =
        "camera: (eye: (0, -10, 0), look_at: (0, 0, 0), fov_y: 40, width: 64, height: 48)";

    #[test]
    fn angle_is_horizontal_and_right_is_mirrored() {
        let p = pov(&format!(
            "({CAMERA}, objects: [Sphere(center: (0, 0, 0), radius: 1)])"
        ));
        let h = 2.0 * ((20f64.to_radians()).tan() * 4.0 / 3.0).atan().to_degrees();
        assert!(p.contains(&format!("angle {}", number(h))), "{p}");
        assert!(p.contains("right -x*1.3333333333333333"), "{p}");
        assert!(p.contains("max_trace_level 6"), "{p}");
    }

    #[test]
    fn transforms_compose_innermost_first_and_materials_inherit() {
        let p = pov(&format!(
            "({CAMERA}, materials: {{\"a\": (color: (1, 0, 0))}}, objects: [
                Transform(translate: (1, 0, 0), material: \"a\", child:
                    Transform(scale: (2, 2, 2), child: Box(min: (0, 0, 0), max: (1, 1, 1)))),
            ])"
        ));
        let scale = p.find("scale <2, 2, 2>").unwrap();
        let translate = p.find("translate <1, 0, 0>").unwrap();
        assert!(scale < translate, "{p}");
        // "a" is material 1 (0 is the default).
        assert!(p.contains("material { HC_M1 }"), "{p}");
        assert!(!p.contains("material { HC_M0 }"), "{p}");
    }

    #[test]
    fn opaque_scenes_seen_from_outside_use_plain_unions() {
        let p = pov(&format!(
            "({CAMERA}, objects: [Union(children: [Sphere(center: (0, 0, 0), radius: 1),
                Triangle(a: (0, 0, 0), b: (1, 0, 0), c: (0, 0, 1))])])"
        ));
        assert!(p.contains("union {") && !p.contains("merge"), "{p}");
    }

    #[test]
    fn an_eye_inside_a_solid_merges_what_overlaps_it_and_keeps_surfaces_apart() {
        let p = pov(&format!(
            "({CAMERA}, objects: [
                Union(children: [Sphere(center: (0, -9, 0), radius: 0.5),
                    Triangle(a: (0, -9.5, 0), b: (1, -9.5, 0), c: (0, -9.5, 1))]),
                Sphere(center: (0, -10, 0), radius: 3),
                Union(children: [Sphere(center: (0, 5, 0), radius: 1), Sphere(center: (0, 6, 0), radius: 1)]),
            ])"
        ));
        // One top-level merge of the eye's sphere and the union it
        // overlaps (which, the eye being outside it, stays a union), the
        // triangle after it, the far union on its own.
        assert_eq!(p.matches("merge {").count(), 1, "{p}");
        let merge = p.find("merge {").unwrap();
        let union = p.find("union {").unwrap();
        let triangle = p.find("triangle").unwrap();
        let far = p.rfind("union {").unwrap();
        assert!(merge < union && union < triangle && triangle < far, "{p}");
        assert_eq!(p.matches("sphere {").count(), 4);
    }

    #[test]
    fn glass_regularises_unions() {
        let p = pov(&format!(
            "({CAMERA}, materials: {{\"g\": (transmit: 0.5, ior: 1.5, diffuse: 0.2)}},
              objects: [Union(material: \"g\", children: [Sphere(center: (0, 0, 0), radius: 1),
                  Sphere(center: (0.5, 0, 0), radius: 1)])])"
        ));
        assert!(p.contains("merge {"), "{p}");
        assert!(p.contains("rgbt <1, 1, 1, 0.5>"), "{p}");
        assert!(p.contains("diffuse 0.4"), "{p}");
        assert!(p.contains("ior 1.5"), "{p}");
    }
}
