//! The checks of a scene that need no solver: the coordinator runs them on every design point
//! of a submission, and a pool before it builds a model, so that a scene a pool would refuse is
//! refused at submit with the pool's message (and not minutes later, behind the queue).
//!
//! [`Scene::check_point`] checks every number at a design point (time, solver, materials,
//! boxes, interface laws); [`Scene::check_meshes`] reads each mesh body's volume and checks
//! its coordinates and elements. The messages are the model's (`glissade-worker`'s
//! `Model::build`), which runs the same rules while it builds.

use crate::contact::{InterfaceLaw, PrakashClifton};
use crate::gmsh::Msh;
use crate::point::DesignPoint;
use crate::scene::{BodySpec, InterfaceSpec, LawSpec, Resolver, Scalar, Scene, SceneError, Substructures, invalid};

/// The useful range of `solver.tangential_factor`: far outside it, the compliances overflow
/// (docs/performance.md).
pub const TANGENTIAL_FACTOR_RANGE: (f64, f64) = (0.01, 100.0);

/// The largest Young's modulus, density and box extent a scene may give (SI: Pa, kg/m^3, m;
/// scenes in mm or MPa fit too): beyond, a stiffness or a mass overflows in the operators long
/// before f64 does, and every pool would refuse the point (issue 48: E = 1e308 and a box of
/// 1e308 m were accepted at submit). Diamond is 1.2e12 Pa, osmium 22,590 kg/m^3.
pub const MAX_YOUNG: f64 = 1e13;
pub const MAX_DENSITY: f64 = 1e6;
pub const MAX_EXTENT: f64 = 1e4;

/// The law of interface `spec` (at `key`) with its numbers, checked: the one rule the submit
/// check and the model's build both follow.
pub fn interface_law(r: &Resolver, key: &str, spec: &InterfaceSpec) -> Result<InterfaceLaw, SceneError> {
    if spec.prestress.is_some() && spec.law != LawSpec::Prestress {
        return Err(invalid(format!("{key}.prestress"), "only law 'prestress' takes a prestress"));
    }
    if spec.prakash_clifton.is_some() && spec.law != LawSpec::Friction {
        return Err(invalid(format!("{key}.prakash_clifton"), "only law 'friction' takes a regularisation"));
    }
    Ok(match spec.law {
        LawSpec::Perfect => InterfaceLaw::Perfect,
        LawSpec::Contact => InterfaceLaw::Contact,
        LawSpec::Friction => {
            let f = spec
                .friction
                .as_ref()
                .ok_or_else(|| invalid(format!("{key}.friction"), "law 'friction' needs a coefficient"))?;
            let f = r.get(&format!("{key}.friction"), f)?;
            if f < 0.0 {
                return Err(invalid(format!("{key}.friction"), format!("must be >= 0, got {f}")));
            }
            let regularisation = match &spec.prakash_clifton {
                Some(pc) => {
                    let positive = |name: &str, s: &Scalar| {
                        let k = format!("{key}.prakash_clifton.{name}");
                        let v = r.get(&k, s)?;
                        if v > 0.0 { Ok(v) } else { Err(invalid(k, format!("must be > 0, got {v}"))) }
                    };
                    Some(PrakashClifton {
                        length: positive("length", &pc.length)?,
                        velocity: positive("velocity", &pc.velocity)?,
                    })
                }
                None => None,
            };
            InterfaceLaw::Friction { coefficient: f, regularisation }
        }
        LawSpec::Prestress => {
            let s = spec
                .prestress
                .as_ref()
                .ok_or_else(|| invalid(format!("{key}.prestress"), "law 'prestress' needs a shortening (m)"))?;
            InterfaceLaw::Prestress { shortening: r.get(&format!("{key}.prestress"), s)? }
        }
    })
}

impl Scene {
    /// Every rule on the scene's numbers at the design point `values` (all parameters, as
    /// [`Scene::parameter_values`] gives them).
    pub fn check_point(&self, values: &DesignPoint) -> Result<(), SceneError> {
        let r = Resolver { values };
        let duration = r.get("time.duration", &self.time.duration)?;
        if duration <= 0.0 {
            return Err(invalid("time.duration", "must be > 0"));
        }
        if self.time.steps == 0 {
            return Err(invalid("time.steps", "must be >= 1"));
        }
        if let Some(g) = self.time.newmark_gamma
            && !(0.5..=1.0).contains(&g)
        {
            return Err(invalid(
                "time.newmark_gamma",
                format!("must be in [0.5, 1] (0.5: the trapezoidal rule), got {g}"),
            ));
        }
        if r.get("solver.k0_factor", &self.solver.k0_factor)? <= 0.0 {
            return Err(invalid("solver.k0_factor", "must be > 0"));
        }
        let st = &self.solver;
        if !(st.relaxation > 0.0 && st.relaxation <= 1.0) {
            return Err(invalid("solver.relaxation", "must be in (0, 1]"));
        }
        let (lo, hi) = TANGENTIAL_FACTOR_RANGE;
        if !(lo..=hi).contains(&st.tangential_factor) {
            return Err(invalid("solver.tangential_factor", format!("must be a number in [{lo}, {hi}]")));
        }
        if !(st.warm_tolerance_ratio > 0.0 && st.warm_tolerance_ratio <= 1.0) {
            return Err(invalid("solver.warm_tolerance_ratio", "must be in (0, 1]"));
        }
        for (name, m) in &self.materials {
            let key = format!("materials.{name}");
            let young = r.get(&format!("{key}.E"), &m.E)?;
            let poisson = r.get(&format!("{key}.nu"), &m.nu)?;
            let density = r.get(&format!("{key}.rho"), &m.rho)?;
            if !(young > 0.0 && young <= MAX_YOUNG) {
                return Err(invalid(
                    format!("{key}.E"),
                    format!("must be in (0, {MAX_YOUNG:e}], got {}", number(young)),
                ));
            }
            if !(density > 0.0 && density <= MAX_DENSITY) {
                return Err(invalid(
                    format!("{key}.rho"),
                    format!("must be in (0, {MAX_DENSITY:e}], got {}", number(density)),
                ));
            }
            if !(-1.0 < poisson && poisson < 0.5) {
                return Err(invalid(format!("{key}.nu"), format!("must be in (-1, 0.5), got {poisson}")));
            }
        }
        if self.bodies.is_empty() {
            return Err(invalid("bodies", "a scene needs at least one body"));
        }
        for (bi, b) in self.bodies.iter().enumerate() {
            let key = format!("bodies[{bi}]");
            if self.bodies[..bi].iter().any(|o| o.name == b.name) {
                return Err(invalid(format!("{key}.name"), format!("duplicate body name '{}'", b.name)));
            }
            if !self.materials.contains_key(&b.material) {
                return Err(invalid(format!("{key}.material"), format!("unknown material '{}'", b.material)));
            }
            if let Some(v) = &b.initial_velocity {
                self.vector(&r, &format!("{key}.initial_velocity"), v)?;
            }
            self.check_body(&r, &key, b)?;
        }
        for (ii, spec) in self.interfaces.iter().enumerate() {
            let key = format!("interfaces[{ii}]");
            if self.interfaces[..ii].iter().any(|o| o.name == spec.name) {
                return Err(invalid(format!("{key}.name"), format!("duplicate interface name '{}'", spec.name)));
            }
            interface_law(&r, &key, spec)?;
            // (a gap is read for a wall only)
            if spec.b == "wall"
                && let Some(g) = &spec.gap
                && r.get(&format!("{key}.gap"), g)? < 0.0
            {
                return Err(invalid(format!("{key}.gap"), "an initial gap must be >= 0"));
            }
        }
        for (i, load) in self.loads.iter().enumerate() {
            let key = format!("loads[{i}]");
            if let Some(p) = &load.pressure {
                r.get(&format!("{key}.pressure"), p)?;
            }
            if let Some(t) = &load.traction {
                self.vector(&r, &format!("{key}.traction"), t)?;
            }
            r.history(&format!("{key}.history"), &load.history)?;
        }
        for (i, bc) in self.boundary.iter().enumerate() {
            let key = format!("boundary[{i}]");
            for (what, map) in [("displacement", &bc.displacement), ("velocity", &bc.velocity)] {
                for (c, s) in map.iter().flatten() {
                    r.get(&format!("{key}.{what}.{c}"), s)?;
                }
            }
            r.history(&format!("{key}.history"), &bc.history)?;
        }
        Ok(())
    }

    /// A vector of the scene's dimension, every component resolved.
    fn vector(&self, r: &Resolver, key: &str, v: &[crate::scene::Scalar]) -> Result<(), SceneError> {
        if v.len() != self.dimension {
            let d = self.dimension;
            return Err(invalid(key, format!("expected {d} components (dimension {d}), got {}", v.len())));
        }
        for (i, s) in v.iter().enumerate() {
            r.get(&format!("{key}[{i}]"), s)?;
        }
        Ok(())
    }

    /// A box body's extents and counts (a mesh body's are checked by [`Scene::check_meshes`]).
    fn check_body(&self, r: &Resolver, key: &str, b: &BodySpec) -> Result<(), SceneError> {
        let count_key = format!("{key}.substructures");
        if b.mesh.is_some() {
            if b.size.is_some() || b.elements.is_some() || b.origin.is_some() {
                return Err(invalid(key, "a mesh body takes no size, elements or origin"));
            }
            if self.dimension != 3 {
                let d = self.dimension;
                return Err(invalid(format!("{key}.mesh"), format!("mesh bodies need dimension = 3, not {d}")));
            }
            return match &b.substructures {
                Some(Substructures::PerAxis(_)) => {
                    Err(invalid(count_key, "a mesh body takes a number of substructures (substructures = 8)"))
                }
                _ => Ok(()),
            };
        }
        let (Some(size), Some(elements)) = (&b.size, &b.elements) else {
            return Err(invalid(key, "a body is a box (size and elements) or a mesh (mesh = { file, volume })"));
        };
        if let Some(o) = &b.origin {
            self.vector(r, &format!("{key}.origin"), o)?;
        }
        self.vector(r, &format!("{key}.size"), size)?;
        if size.iter().any(|s| r.get("", s).is_ok_and(|s| !(s > 0.0 && s <= MAX_EXTENT))) {
            return Err(invalid(format!("{key}.size"), format!("every extent must be in (0, {MAX_EXTENT:e}]")));
        }
        if let Some(o) = &b.origin
            && o.iter().any(|x| r.get("", x).is_ok_and(|x| x.abs() > MAX_EXTENT))
        {
            return Err(invalid(format!("{key}.origin"), format!("every coordinate must be within {MAX_EXTENT:e}")));
        }
        let counts = self.counts(&format!("{key}.elements"), elements)?;
        let parts = match &b.substructures {
            Some(Substructures::PerAxis(p)) => self.counts(&count_key, p)?,
            Some(Substructures::Count(_)) => {
                let d = self.dimension;
                return Err(invalid(count_key, format!("a box takes a count per axis (substructures = [..; {d}])")));
            }
            None => vec![1; self.dimension],
        };
        for d in 0..self.dimension {
            if parts[d] > counts[d] {
                return Err(invalid(
                    count_key,
                    format!("{} substructures along axis {d} but only {} elements", parts[d], counts[d]),
                ));
            }
        }
        Ok(())
    }

    fn counts(&self, key: &str, v: &[usize]) -> Result<Vec<usize>, SceneError> {
        let d = self.dimension;
        if v.len() != d {
            return Err(invalid(key, format!("expected {d} counts (dimension {d}), got {}", v.len())));
        }
        if let Some(i) = v.iter().position(|&c| c == 0) {
            return Err(invalid(format!("{key}[{i}]"), "counts must be >= 1"));
        }
        Ok(v.to_vec())
    }

    /// Every mesh body's volume read from its attached file: finite coordinates, elements of
    /// positive volume (the Jacobian determinant at the element's centre), at most as many
    /// substructures as elements.
    pub fn check_meshes(&self) -> Result<(), SceneError> {
        for (bi, b) in self.bodies.iter().enumerate() {
            let Some(spec) = &b.mesh else { continue };
            let key = format!("bodies[{bi}]");
            let Some(bytes) = self.meshes.get(&spec.file) else {
                return Err(invalid(
                    format!("{key}.mesh.file"),
                    format!(
                        "mesh file '{}' is not attached to the scene (Scene::read or attach_mesh_bytes)",
                        spec.file
                    ),
                ));
            };
            let volume = Msh::parse(bytes)
                .and_then(|m| m.volume(&spec.volume))
                .map_err(|e| invalid(format!("{key}.mesh"), format!("{}: {e}", spec.file)))?;
            if let Some(p) = volume.nodes.iter().find(|p| p.iter().any(|x| !x.is_finite())) {
                return Err(invalid(format!("{key}.mesh"), format!("{}: a node at {p:?}", spec.file)));
            }
            let per = if volume.hexahedra { 8 } else { 4 };
            let n_elements = volume.connectivity.len() / per;
            for element in volume.connectivity.chunks(per) {
                let x: Vec<[f64; 3]> = element.iter().map(|&n| volume.nodes[n]).collect();
                let det = if volume.hexahedra { hexahedron_centre_det(&x) } else { tetrahedron_det(&x) };
                if det.is_nan() || det <= 0.0 {
                    return Err(invalid(key, format!("element with non-positive Jacobian determinant {det}")));
                }
            }
            if let Some(Substructures::Count(parts)) = b.substructures
                && (parts == 0 || parts > n_elements)
            {
                return Err(invalid(
                    format!("{key}.substructures"),
                    format!("must be 1 to {n_elements} (the elements), got {parts}"),
                ));
            }
        }
        Ok(())
    }
}

fn det3(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])
}

/// The Jacobian determinant of a 4-node tetrahedron: (x1 - x0, x2 - x0, x3 - x0).
fn tetrahedron_det(x: &[[f64; 3]]) -> f64 {
    let edge = |i: usize| std::array::from_fn(|d| x[i][d] - x[0][d]);
    det3(edge(1), edge(2), edge(3))
}

/// The Jacobian determinant at the centre of an 8-node hexahedron in tensor order (node
/// ix + 2 iy + 4 iz at corner (±1, ±1, ±1)).
fn hexahedron_centre_det(x: &[[f64; 3]]) -> f64 {
    let column = |axis: usize| -> [f64; 3] {
        std::array::from_fn(|d| {
            (0..8).map(|n| if (n >> axis) & 1 == 1 { x[n][d] } else { -x[n][d] }).sum::<f64>() / 8.0
        })
    };
    det3(column(0), column(1), column(2))
}

/// A number in a message: 1e308, not its 309 digits.
fn number(x: f64) -> String {
    if x != 0.0 && (x.abs() >= 1e6 || x.abs() < 1e-3) { format!("{x:e}") } else { format!("{x}") }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = include_str!("../../scenes/three-blocks-tiny.toml");

    fn defaults(scene: &Scene) -> DesignPoint {
        scene.parameter_values(&DesignPoint::new()).unwrap()
    }

    /// Each of the probe's bad scenes, as a change of the tiny scene's text, and the key the
    /// refusal names. Every one was accepted at submit before.
    #[test]
    fn the_probes_bad_scenes_are_refused_naming_the_key() {
        let cases = [
            ("E = 200e9", "E = 0", "materials.outer.E: must be in (0, 1e13], got 0"),
            // issue 48: sizes that overflow the operators, and a name given twice, every pool
            // refused and submit took
            ("E = 200e9", "E = 1e308", "materials.outer.E: must be in (0, 1e13], got 1e308"),
            ("rho = 7800", "rho = 1e300", "materials.outer.rho: must be in (0, 1e6], got 1e300"),
            (
                "size = [0.015, 0.015, 0.03]",
                "size = [1e308, 0.015, 0.03]",
                "bodies[0].size: every extent must be in (0, 1e4]",
            ),
            (
                "name = \"interface2\"",
                "name = \"interface1\"",
                "interfaces[1].name: duplicate interface name 'interface1'",
            ),
            ("nu = 0.3", "nu = 0.5", "materials.outer.nu: must be in (-1, 0.5), got 0.5"),
            (
                "rho = 7800\n\n[materials.middle]",
                "rho = inf\n\n[materials.middle]",
                "materials.outer.rho: inf is not a finite number",
            ),
            ("duration = 2e-4", "duration = nan", "time.duration: NaN is not a finite number"),
            ("duration = 2e-4", "duration = -2e-4", "time.duration: must be > 0"),
            ("steps = 50", "steps = 0", "time.steps: must be >= 1"),
            ("elements = [2, 2, 4]", "elements = [2, 0, 4]", "bodies[0].elements[1]: counts must be >= 1"),
            (
                "substructures = [1, 1, 2]",
                "substructures = [3, 1, 2]",
                "bodies[0].substructures: 3 substructures along axis 0 but only 2 elements",
            ),
            (
                "friction = \"f1\"",
                "friction = \"f9\"",
                "interfaces[0].friction: parameter 'f9' is used but not declared",
            ),
        ];
        for (from, to, message) in cases {
            assert!(TINY.contains(from), "{from}");
            let scene = Scene::parse(&TINY.replacen(from, to, 1)).unwrap();
            let e = scene.check_point(&defaults(&scene)).expect_err(to).to_string();
            assert!(e.starts_with(message), "{to}: {e}");
        }
        let scene = Scene::parse(TINY).unwrap();
        scene.check_point(&defaults(&scene)).unwrap();
        // a parameter's value is checked where it is used: f1 < 0 at one point only
        let mut at = defaults(&scene);
        at.insert("f1", -0.1).unwrap();
        assert!(scene.check_point(&at).unwrap_err().to_string().contains("interfaces[0].friction: must be >= 0"));
    }

    /// A Prakash-Clifton regularisation is read on a friction law, its numbers > 0 (parameters
    /// allowed, and law-only), and refused elsewhere, naming the key.
    #[test]
    fn a_regularisation_is_checked_and_its_parameters_are_law_only() {
        let with =
            |pc: &str| TINY.replacen("friction = \"f1\"", &format!("friction = \"f1\"\nprakash_clifton = {pc}"), 1);
        let scene = Scene::parse(&with("{ length = 3e-5, velocity = 1.0 }")).unwrap();
        let r = Resolver { values: &defaults(&scene) };
        let law = interface_law(&r, "interfaces[0]", &scene.interfaces[0]).unwrap();
        assert_eq!(
            law,
            InterfaceLaw::Friction {
                coefficient: 0.1,
                regularisation: Some(PrakashClifton { length: 3e-5, velocity: 1.0 })
            }
        );
        assert_eq!(
            interface_law(&r, "interfaces[1]", &scene.interfaces[1]).unwrap(),
            InterfaceLaw::Friction { coefficient: 0.1, regularisation: None }
        );
        for (pc, message) in [
            ("{ length = 0, velocity = 1.0 }", "interfaces[0].prakash_clifton.length: must be > 0, got 0"),
            ("{ length = 1e-5, velocity = -1 }", "interfaces[0].prakash_clifton.velocity: must be > 0, got -1"),
            (
                "{ length = \"L\", velocity = 1 }",
                "interfaces[0].prakash_clifton.length: parameter 'L' is used but not declared",
            ),
        ] {
            let scene = Scene::parse(&with(pc)).unwrap();
            let e = scene.check_point(&defaults(&scene)).unwrap_err().to_string();
            assert!(e.starts_with(message), "{pc}: {e}");
        }
        assert!(Scene::parse(&with("{ length = 1e-5 }")).is_err(), "both numbers are needed");
        let contact = with("{ length = 1e-5, velocity = 1 }").replacen("law = \"friction\"", "law = \"contact\"", 1);
        let scene = Scene::parse(&contact).unwrap();
        let e = scene.check_point(&defaults(&scene)).unwrap_err().to_string();
        assert!(e.starts_with("interfaces[0].prakash_clifton: only law 'friction' takes a regularisation"), "{e}");
        // a parameter used only as the law's length is law-only, like a friction coefficient
        let text = with("{ length = \"L\", velocity = 1 }").replacen(
            "[parameters]",
            "[parameters]\nL = { default = 3e-5 }",
            1,
        );
        let scene = Scene::parse(&text).unwrap();
        assert!(scene.interface_law_parameters().contains("L"), "{:?}", scene.interface_law_parameters());
        // absent, it is absent from what the hash is taken of: stored solutions keep their keys
        let canonical = serde_json::to_string(&Scene::parse(TINY).unwrap()).unwrap();
        assert!(!canonical.contains("prakash_clifton"), "{canonical}");
    }

    #[test]
    fn degenerate_and_non_finite_elements_are_refused() {
        let unit = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!((tetrahedron_det(&unit) - 1.0).abs() < 1e-15);
        let flat = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
        assert!(tetrahedron_det(&flat) <= 0.0);
        let nan = [[0.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(tetrahedron_det(&nan).is_nan());
        let cube: Vec<[f64; 3]> =
            (0..8).map(|n| [f64::from(n & 1), f64::from((n >> 1) & 1), f64::from((n >> 2) & 1)]).collect();
        assert!((hexahedron_centre_det(&cube) - 0.125).abs() < 1e-15, "(1/2)^3");
        let mut inverted = cube.clone();
        inverted.swap(0, 1);
        inverted.swap(2, 3);
        inverted.swap(4, 5);
        inverted.swap(6, 7);
        assert!(hexahedron_centre_det(&inverted) < 0.0);
    }

    #[test]
    fn the_shipped_scenes_pass_at_their_defaults() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            // (the paper-size joint's mesh is made by Gmsh, not shipped)
            if path.ends_with("bolted-joint-paper.toml") {
                continue;
            }
            let scene = Scene::read(&path).unwrap();
            scene.check_point(&defaults(&scene)).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            scene.check_meshes().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        }
    }
}
