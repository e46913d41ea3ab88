//! The decomposed model of one design point: substructures (operators assembled once) and
//! interfaces (node pairs, nodal areas, normals, laws), built from a scene and parameter values.

use crate::newmark::Newmark;
use std::collections::{BTreeMap, HashMap};

use crate::element::{ElementKind, Material, face_area_and_normal};
use crate::mesh::{Face, Mesh};
use crate::search_direction::{
    SearchDirection, dynamic_search_direction, inertia_search_direction, static_search_direction,
};
use crate::sparse::CsrMatrix;
use glissade_core::point::DesignPoint;
use glissade_core::scene::{
    BodySpec, History, MassMatrix, QoiKind, Resolver, Scale, Scene, SceneError, Substructures, component_index, invalid,
};

/// Interface behaviour (docs/method.md 1), applied node by node in the local stage
/// (`latin::local_stage::apply_law`): core's, made where the scene is checked.
pub use glissade_core::contact::InterfaceLaw;

/// One side of an interface: a substructure and its nodes on the interface (same order on both
/// sides, node `j` of side 1 faces node `j` of side 2).
#[derive(Debug, Clone)]
pub struct InterfaceSide {
    pub substructure: usize,
    /// substructure-local node numbers
    pub nodes: Vec<usize>,
    /// dynamic search direction (traction per velocity, Pa s/m)
    pub k_dynamic: SearchDirection,
    /// static search direction (traction per displacement, Pa/m), for the prestress stage
    pub k_static: SearchDirection,
    /// the search direction's part from node to node on a perfect interface along flat elements
    /// ([`set_along_directions`]): triplets (j, l, value) over the interface's node numbers of
    /// E h_n times the interface's Laplacian (Pa m); the static stage adds it to M_Gamma k, the
    /// dynamic one dt/2 times it. Empty elsewhere.
    pub k_along: Vec<(usize, usize, f64)>,
}

/// An interface between two substructures, or between a substructure and a fixed rigid wall.
#[derive(Debug, Clone)]
pub struct Interface<const D: usize> {
    pub name: String,
    pub law: InterfaceLaw,
    /// one side (rigid wall) or two
    pub sides: Vec<InterfaceSide>,
    /// lumped interface measure M_Gamma per node (area in 3D, length in 2D, 1 in 1D)
    pub area: Vec<f64>,
    /// unit normal per node, from side 1 towards side 2
    pub normal: Vec<[f64; D]>,
    pub coords: Vec<[f64; D]>,
    /// initial normal gap per node
    pub gap0: Vec<f64>,
}

impl<const D: usize> Interface<D> {
    pub fn n_nodes(&self) -> usize {
        self.area.len()
    }
}

/// A prescribed degree of freedom: displacement reached in the static stage, then velocity.
#[derive(Debug, Clone)]
pub struct PrescribedDof {
    pub dof: usize,
    pub static_displacement: f64,
    pub velocity: f64,
    pub history: usize,
}

/// A load on a substructure: nodal forces times a time history.
#[derive(Debug, Clone)]
pub struct NodalLoad {
    pub forces: Vec<(usize, f64)>,
    pub history: usize,
}

/// A substructure: linear elastic, its own mesh, operators assembled once.
#[derive(Debug, Clone)]
pub struct Substructure<const D: usize> {
    pub body: usize,
    /// body node number of each local node
    pub nodes: Vec<usize>,
    pub coords: Vec<[f64; D]>,
    /// connectivity in local node numbers, [`ElementKind::nodes`] per element
    pub connectivity: Vec<usize>,
    pub kind: ElementKind,
    pub material: Material,
    pub stiffness: CsrMatrix,
    pub mass: CsrMatrix,
    pub fixed: Vec<bool>,
    pub prescribed: Vec<PrescribedDof>,
    pub loads: Vec<NodalLoad>,
    pub initial_velocity: [f64; D],
    /// (interface, side) pairs touching this substructure
    pub sides: Vec<(usize, usize)>,
}

impl<const D: usize> Substructure<D> {
    pub fn n_dofs(&self) -> usize {
        self.nodes.len() * D
    }

    /// External nodal forces at time t.
    pub fn external_force(&self, histories: &[History], t: f64, out: &mut [f64]) {
        out.fill(0.0);
        for l in &self.loads {
            let h = histories[l.history].at(t);
            if h != 0.0 {
                for &(dof, f) in &l.forces {
                    out[dof] += h * f;
                }
            }
        }
    }
}

/// What a quantity of interest reads.
#[derive(Debug, Clone)]
pub enum QoiTarget {
    /// the norm of the slip of side b relative to side a, or its `component` (signed)
    Slip {
        interface: usize,
        node: usize,
        component: Option<usize>,
    },
    Displacement {
        substructure: usize,
        dof: usize,
    },
    Velocity {
        substructure: usize,
        dof: usize,
    },
    /// sum over the parts (one per substructure pair) of a named interface
    Force {
        interfaces: std::ops::Range<usize>,
        component: usize,
    },
}

impl<const D: usize> Interface<D> {
    /// The interface's mesh size: the side of a node's share of its measure (none in 1D, where
    /// an interface is a point).
    pub fn mesh_size(&self) -> Option<f64> {
        if D < 2 || self.area.is_empty() {
            return None;
        }
        let mean = self.area.iter().sum::<f64>() / self.area.len() as f64;
        Some(mean.powf(1.0 / (D - 1) as f64))
    }

    /// How far the elements along the interface are from cubes: [`Self::element_depth`] or its
    /// inverse, the larger (none in 1D). A scalar search direction sits between the smallest and
    /// the largest stiffness a side opposes to the interface; elements of aspect ratio a widen
    /// that range about a^2 times (docs/performance.md, "Flat elements along an interface").
    pub fn element_aspect(&self, substructures: &[Substructure<D>]) -> Option<f64> {
        self.element_depth(substructures).map(|r| r.max(1.0 / r))
    }

    /// The depth along the interface's normal of each element with a face on it (its own
    /// length), with the side it is on.
    fn face_depths<'a>(&'a self, substructures: &'a [Substructure<D>]) -> impl Iterator<Item = (usize, f64)> + 'a {
        let normal = self.mean_normal();
        let along = move |x: &[f64; D]| (0..D).map(|c| x[c] * normal[c]).sum::<f64>();
        self.sides.iter().enumerate().flat_map(move |(s, side)| {
            let sub = &substructures[side.substructure];
            let on_side: std::collections::HashSet<usize> = side.nodes.iter().copied().collect();
            sub.connectivity
                .chunks(sub.kind.nodes(D))
                // a face on the interface, not an edge or a corner touching it
                .filter(move |element| element.iter().filter(|n| on_side.contains(n)).count() >= D)
                .map(move |element| {
                    let (lo, hi) = element
                        .iter()
                        .map(|&n| along(&sub.coords[n]))
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
                    (s, hi - lo)
                })
        })
    }

    /// The mean depth along the interface's normal of the elements with a face on it, against
    /// the side of a face (the interface's measure over their number): 1 for cubes, 100 for
    /// elements 100 x deeper than long along the interface (none in 1D).
    pub fn element_depth(&self, substructures: &[Substructure<D>]) -> Option<f64> {
        if D < 2 {
            return None;
        }
        let (depth, faces) = self.face_depths(substructures).fold((0.0, 0usize), |(d, n), (_, h)| (d + h, n + 1));
        if faces == 0 {
            return None;
        }
        let depth = depth / faces as f64;
        let per_side = faces as f64 / self.sides.len() as f64;
        let face = (self.area.iter().sum::<f64>() / per_side).powf(1.0 / (D - 1) as f64);
        (depth > 0.0 && face > 0.0).then(|| depth / face)
    }

    /// Per side, c dt / h: the share of a step a dilatational wave takes to cross the mean depth
    /// h of the side's elements along the normal (`None` for a side without faces on it).
    pub fn transit_ratios(&self, substructures: &[Substructure<D>], dt: f64) -> Vec<Option<f64>> {
        let mut depth = vec![(0.0, 0usize); self.sides.len()];
        for (s, h) in self.face_depths(substructures) {
            depth[s].0 += h;
            depth[s].1 += 1;
        }
        self.sides
            .iter()
            .zip(depth)
            .map(|(side, (h, n))| {
                let c = substructures[side.substructure].material.bar_wave_speed();
                (n > 0 && h > 0.0).then(|| c * dt * n as f64 / h)
            })
            .collect()
    }

    /// The area-weighted mean unit normal (the normal of a flat interface).
    pub fn mean_normal(&self) -> [f64; D] {
        let mut n = [0.0; D];
        for (a, nj) in self.area.iter().zip(&self.normal) {
            for c in 0..D {
                n[c] += a * nj[c];
            }
        }
        let len = n.iter().map(|x| x * x).sum::<f64>().sqrt();
        if len > 0.0 {
            n.iter_mut().for_each(|x| *x /= len);
        }
        n
    }
}

impl QoiTarget {
    pub fn unit(&self) -> QoiUnit {
        match self {
            QoiTarget::Slip { .. } | QoiTarget::Displacement { .. } => QoiUnit::Length,
            QoiTarget::Velocity { .. } => QoiUnit::Velocity,
            QoiTarget::Force { .. } => QoiUnit::Force,
        }
    }
}

/// The physical unit of a QoI: the stopping test compares norms within a unit only.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QoiUnit {
    Length,
    Velocity,
    Force,
}

#[derive(Debug, Clone)]
pub struct Qoi {
    pub name: String,
    pub target: QoiTarget,
}

/// A body of the scene.
#[derive(Debug, Clone)]
pub struct Body<const D: usize> {
    pub name: String,
    pub mesh: Mesh<D>,
    /// element -> global substructure index
    pub partition: Vec<usize>,
}

/// Solver settings with parameters resolved.
#[derive(Debug, Clone)]
pub struct SolverSettings {
    pub tolerance: f64,
    pub max_iterations: usize,
    pub relaxation: f64,
    pub scale: Scale,
    /// the dynamic stage of a warm-started solve stops at tolerance x this
    pub warm_tolerance_ratio: f64,
    /// steps per time window of the dynamic stage (0: the whole interval)
    pub time_window: usize,
    /// a solve in time windows is checked against another windowing (latin/window_check.rs)
    pub window_check: bool,
    /// a whole-interval solve is checked by iterating on to a tenth of its tolerance
    pub whole_interval_check: bool,
    /// the copies of a node substructures share on a wall interface follow the law together
    /// ([`Model::shared_wall_nodes`])
    pub joint_wall_nodes: bool,
}

/// Below this c dt / h at a contact, [`Model::short_step_advice`] speaks.
pub const SHORT_STEP: f64 = 0.3;

/// The whole decomposed problem of one design point.
#[derive(Debug, Clone)]
pub struct Model<const D: usize> {
    pub bodies: Vec<Body<D>>,
    pub substructures: Vec<Substructure<D>>,
    pub interfaces: Vec<Interface<D>>,
    pub histories: Vec<History>,
    pub dt: f64,
    /// the time scheme of the substructures and the interfaces' gaps (`[time] newmark_gamma`)
    pub newmark: Newmark,
    pub steps: usize,
    pub qois: Vec<Qoi>,
    pub settings: SolverSettings,
    pub parameters: DesignPoint,
    /// Nodes a wall interface holds twice or more: (interface, node) of each copy, one group per
    /// physical node ([`shared_wall_nodes`]); the local stage applies the law to each group's
    /// total force. Empty unless `settings.joint_wall_nodes`.
    pub shared_wall_nodes: Vec<Vec<(usize, usize)>>,
}

impl<const D: usize> Model<D> {
    /// Whether a static prestress stage is needed: a prescribed displacement or a load at t = 0.
    pub fn needs_static_stage(&self) -> bool {
        self.substructures.iter().any(|s| {
            s.prescribed.iter().any(|p| p.static_displacement != 0.0)
                || s.loads.iter().any(|l| self.histories[l.history].at(0.0) != 0.0)
        }) || self
            .interfaces
            .iter()
            .any(|i| matches!(i.law, InterfaceLaw::Prestress { shortening } if shortening != 0.0))
    }

    /// What a dynamic stage that does not converge under the trapezoidal rule with a contact
    /// should try first: a little numerical dissipation, which damps the highest modes an impact
    /// excites; measured
    /// (docs/accuracy.md, "The time scheme"; docs/notebook/2026-11-29.md, "Bars under refinement"):
    /// the impact bar at dt / 10 stalled at 1000 iterations and converges in 306 under gamma
    /// 0.55, an aluminium bar of our own in 3D at dt / 4 in 528. `None` where the scheme
    /// already damps or no interface is a contact.
    pub fn scheme_advice(&self) -> Option<String> {
        let contact =
            self.interfaces.iter().any(|i| matches!(i.law, InterfaceLaw::Contact | InterfaceLaw::Friction { .. }));
        (contact && self.newmark == Newmark::TRAPEZOIDAL).then(|| {
            format!(
                "first try a little numerical dissipation, [time] newmark_gamma = {} (undamped, the highest modes an \
                 impact excites keep the iterations from settling; first order in dt: docs/accuracy.md, \"The time \
                 scheme\")",
                glissade_core::accuracy::CONTACT_GAMMA
            )
        })
    }

    pub fn n_dofs(&self) -> usize {
        self.substructures.iter().map(|s| s.n_dofs()).sum()
    }

    /// Where a contact or friction interface meets a time step far shorter than a wave takes to
    /// cross its elements (c dt / h below [`SHORT_STEP`]), the advice to refine the mesh with
    /// the step. A sliding contact's iterations may grow about as h / (c dt) while the mesh stays
    /// and dt falls, and stay flat when both fall together; measured (docs/notebook/2026-11-29.md,
    /// "Refine dt and h together"): the impact bar under gamma 0.55 took 35 iterations at every
    /// level of dt and h halved together, 35 / 61 / 108 / 306 as dt alone fell to dt / 10 (in
    /// windows of one step its work is now flat: [`crate::search_direction::inertia_search_direction`]).
    pub fn short_step_advice(&self) -> Option<String> {
        let (name, ratio) = self
            .interfaces
            .iter()
            .filter(|i| matches!(i.law, InterfaceLaw::Contact | InterfaceLaw::Friction { .. }))
            .flat_map(|i| i.transit_ratios(&self.substructures, self.dt).into_iter().flatten().map(|r| (&i.name, r)))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        (ratio < SHORT_STEP).then(|| {
            format!(
                "the time step is {:.0} x shorter than a wave takes to cross the elements at interface '{name}' \
                 (c dt / h = {ratio:.2}): a sliding contact's iterations may grow about in proportion; refine the mesh across the \
                 interface with the step (c dt / h near 1), or take a longer step (docs/accuracy.md, \"Refine dt and h \
                 together\")",
                1.0 / ratio
            )
        })
    }

    /// Moves the model to another design point that differs only in interface-law parameters
    /// ([`Scene::interface_law_parameters`]): the interfaces' laws change, no operator does.
    pub fn update_interface_laws(&mut self, scene: &Scene, values: &DesignPoint) -> Result<(), SceneError> {
        let r = Resolver { values };
        for (ii, spec) in scene.interfaces.iter().enumerate() {
            let law = glissade_core::check::interface_law(&r, &format!("interfaces[{ii}]"), spec)?;
            for itf in self.interfaces.iter_mut().filter(|itf| itf.name == spec.name) {
                itf.law = law;
            }
        }
        self.parameters = values.clone();
        Ok(())
    }

    /// Builds the model of `scene` at the design point `values` (dimension must equal `D`).
    pub fn build(scene: &Scene, values: &DesignPoint) -> Result<Self, SceneError> {
        assert_eq!(scene.dimension, D, "scene dimension must match the model's");
        // the rules on the scene's numbers, in the one place the coordinator runs them too
        scene.check_point(values)?;
        let r = Resolver { values };
        let duration = r.get("time.duration", &scene.time.duration)?;
        let k0_factor = r.get("solver.k0_factor", &scene.solver.k0_factor)?;
        let st = &scene.solver;
        let tangential_factor = st.tangential_factor;
        let settings = SolverSettings {
            tolerance: st.tolerance,
            max_iterations: st.max_iterations,
            relaxation: st.relaxation,
            scale: scene.scale(),
            warm_tolerance_ratio: st.warm_tolerance_ratio,
            time_window: scene.window_steps(),
            window_check: st.window_check.unwrap_or(true),
            whole_interval_check: scene.whole_interval_check(),
            joint_wall_nodes: st.joint_wall_nodes.unwrap_or(D == 3),
        };

        let mut materials = BTreeMap::new();
        for (name, m) in &scene.materials {
            let key = format!("materials.{name}");
            let young = r.get(&format!("{key}.E"), &m.E)?;
            let poisson = r.get(&format!("{key}.nu"), &m.nu)?;
            let density = r.get(&format!("{key}.rho"), &m.rho)?;
            // ranges checked by check_point above
            materials.insert(name.clone(), Material { young, poisson, density });
        }

        // Bodies, meshes, partitions, substructures.
        let mut bodies = Vec::new();
        let mut substructures: Vec<Substructure<D>> = Vec::new();
        let mut body_material = Vec::new();
        if scene.bodies.is_empty() {
            return Err(invalid("bodies", "a scene needs at least one body"));
        }
        for (bi, b) in scene.bodies.iter().enumerate() {
            let key = format!("bodies[{bi}]");
            if scene.bodies[..bi].iter().any(|o| o.name == b.name) {
                return Err(invalid(format!("{key}.name"), format!("duplicate body name '{}'", b.name)));
            }
            let material = *materials
                .get(&b.material)
                .ok_or_else(|| invalid(format!("{key}.material"), format!("unknown material '{}'", b.material)))?;
            let v0 = match &b.initial_velocity {
                Some(v) => r.vector::<D>(&format!("{key}.initial_velocity"), v)?,
                None => [0.0; D],
            };
            let (mesh, parts) = body_mesh::<D>(scene, &r, &key, b)?;
            let offset = substructures.len();
            let partition: Vec<usize> = parts.iter().map(|p| p + offset).collect();
            let n_sub = parts.iter().max().map_or(0, |m| m + 1);
            for s in 0..n_sub {
                let elements: Vec<usize> = (0..partition.len()).filter(|&e| partition[e] == offset + s).collect();
                substructures.push(
                    assemble_substructure(bi, &mesh, &elements, material, v0, scene.time.mass).map_err(|det| {
                        invalid(key.to_string(), format!("element with non-positive Jacobian determinant {det}"))
                    })?,
                );
            }
            body_material.push(material);
            bodies.push(Body { name: b.name.clone(), mesh, partition });
        }
        // L of the static search direction (static_search_direction)
        let assembly_size = {
            let mut s: f64 = 0.0;
            for d in 0..D {
                let lo = bodies.iter().flat_map(|b| b.mesh.nodes.iter()).map(|p| p[d]).fold(f64::INFINITY, f64::min);
                let hi =
                    bodies.iter().flat_map(|b| b.mesh.nodes.iter()).map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
                s = s.max(hi - lo);
            }
            s
        };
        // body node -> local node, per substructure
        let local_of: Vec<HashMap<usize, usize>> =
            substructures.iter().map(|s| s.nodes.iter().enumerate().map(|(l, &g)| (g, l)).collect()).collect();
        let mut interfaces = implicit_interfaces(scene, &bodies, &local_of);
        let interface_index = declared_interfaces(scene, &r, &bodies, &local_of, &mut interfaces)?;
        for (i, itf) in interfaces.iter().enumerate() {
            for (k, s) in itf.sides.iter().enumerate() {
                substructures[s.substructure].sides.push((i, k));
            }
        }

        let histories = boundary_and_loads(scene, &r, &bodies, &local_of, &mut substructures)?;
        let qois =
            quantities_of_interest(scene, &r, &bodies, &interfaces, &interface_index, &substructures, &local_of)?;
        let dt = duration / scene.time.steps as f64;
        let newmark = scene.time.newmark_gamma.map_or(Newmark::TRAPEZOIDAL, Newmark::with_gamma);
        // (a window's duration: the inertia a side opposes is the nodes' over the steps iterated together)
        let window = if settings.time_window > 0 { settings.time_window } else { scene.time.steps };
        let step = (dt, dt * window as f64, newmark.gamma);
        set_search_directions(&mut interfaces, &substructures, (k0_factor, tangential_factor), assembly_size, step);

        let shared_wall_nodes = if settings.joint_wall_nodes {
            shared_wall_nodes(&interfaces, &interface_index, assembly_size)
        } else {
            Vec::new()
        };
        untie_shared_wall_nodes(&mut interfaces, &shared_wall_nodes);
        set_along_directions(&mut interfaces, &substructures);
        Ok(Model {
            shared_wall_nodes,
            bodies,
            substructures,
            interfaces,
            histories,
            dt,
            newmark,
            steps: scene.time.steps,
            qois,
            settings,
            parameters: values.clone(),
        })
    }
}

/// The nodes where the substructures of a body meet a wall interface: each is on the piece of
/// every substructure it belongs to (a declared interface is one piece per substructure), its
/// copies tied by the perfect interfaces between them. Were the law applied to each copy apart,
/// the split of the node's force between the copies would be free (the perfect interface carries
/// any difference), and one copy could slip while the node as a whole sticks: in the 3D sliding
/// block the residual then sat at those nodes alone before the slip's onset, falling 0.2 % per
/// iteration (docs/performance.md, "Nodes two substructures share on a wall"). Groups of
/// (interface, node), by declared interface, in interface order.
fn shared_wall_nodes<const D: usize>(
    interfaces: &[Interface<D>],
    index: &BTreeMap<String, std::ops::Range<usize>>,
    scale: f64,
) -> Vec<Vec<(usize, usize)>> {
    let tol = 1e-9 * scale;
    let mut groups = Vec::new();
    for range in index.values().filter(|r| r.len() > 1 && interfaces[r.start].sides.len() == 1) {
        let mut at: BTreeMap<Vec<i64>, Vec<(usize, usize)>> = BTreeMap::new();
        for i in range.clone() {
            for (j, p) in interfaces[i].coords.iter().enumerate() {
                at.entry(p.iter().map(|x| (x / tol).round() as i64).collect()).or_default().push((i, j));
            }
        }
        groups.extend(at.into_values().filter(|copies| copies.len() > 1));
    }
    groups.sort();
    groups
}

/// Drops from the perfect interfaces between substructures the nodes whose copies a wall
/// interface holds together ([`shared_wall_nodes`]): the local stage there gives every copy one
/// velocity and balances their forces against the law's (`LatinSolver::shared_wall_stage`),
/// which ties them as the perfect interface would. Tied twice, the split of the node's force
/// between the wall and the perfect interface would be free, a mode the iterations hardly damp
/// (docs/performance.md, "Nodes two substructures share on a wall").
fn untie_shared_wall_nodes<const D: usize>(interfaces: &mut [Interface<D>], groups: &[Vec<(usize, usize)>]) {
    let mut group_of: HashMap<(usize, usize), usize> = HashMap::new();
    for (g, copies) in groups.iter().enumerate() {
        for &(i, j) in copies {
            let side = &interfaces[i].sides[0];
            group_of.insert((side.substructure, side.nodes[j]), g);
        }
    }
    if group_of.is_empty() {
        return;
    }
    for itf in interfaces.iter_mut().filter(|itf| itf.law == InterfaceLaw::Perfect && itf.sides.len() == 2) {
        let tied = |j: usize| {
            let [a, b] = [&itf.sides[0], &itf.sides[1]].map(|s| group_of.get(&(s.substructure, s.nodes[j])));
            a.is_some() && a == b
        };
        let keep: Vec<usize> = (0..itf.n_nodes()).filter(|&j| !tied(j)).collect();
        if keep.len() == itf.n_nodes() {
            continue;
        }
        itf.area = keep.iter().map(|&j| itf.area[j]).collect();
        itf.normal = keep.iter().map(|&j| itf.normal[j]).collect();
        itf.coords = keep.iter().map(|&j| itf.coords[j]).collect();
        itf.gap0 = keep.iter().map(|&j| itf.gap0[j]).collect();
        for side in itf.sides.iter_mut() {
            side.nodes = keep.iter().map(|&j| side.nodes[j]).collect();
        }
    }
}

/// A side of an interface on substructure `s` at these body nodes; its search directions are set
/// once every interface's geometry is known ([`set_search_directions`]).
fn interface_side(local_of: &[HashMap<usize, usize>], s: usize, body_nodes: &[usize]) -> InterfaceSide {
    InterfaceSide {
        substructure: s,
        nodes: body_nodes.iter().map(|g| local_of[s][g]).collect(),
        k_dynamic: SearchDirection::isotropic(1.0),
        k_static: SearchDirection::isotropic(1.0),
        k_along: Vec::new(),
    }
}

/// The perfect interfaces between the substructures of each body (the faces two of them share).
fn implicit_interfaces<const D: usize>(
    scene: &Scene,
    bodies: &[Body<D>],
    local_of: &[HashMap<usize, usize>],
) -> Vec<Interface<D>> {
    let side = |s: usize, body_nodes: &[usize]| interface_side(local_of, s, body_nodes);
    let mut interfaces = Vec::new();
    for (bi, body) in bodies.iter().enumerate() {
        let mut by_key: HashMap<Vec<usize>, Vec<Face>> = HashMap::new();
        for e in 0..body.mesh.n_elements() {
            for f in body.mesh.faces_of(e) {
                let mut key = body.mesh.face_nodes(f);
                key.sort_unstable();
                by_key.entry(key).or_default().push(f);
            }
        }
        let mut groups: BTreeMap<(usize, usize), Vec<Face>> = BTreeMap::new();
        for faces in by_key.values() {
            if let [f1, f2] = faces[..] {
                let (s1, s2) = (body.partition[f1.element], body.partition[f2.element]);
                if s1 != s2 {
                    let (f, pair) = if s1 < s2 { (f1, (s1, s2)) } else { (f2, (s2, s1)) };
                    groups.entry(pair).or_default().push(f);
                }
            }
        }
        for ((s1, s2), mut faces) in groups {
            faces.sort();
            let name = format!("{}:{}-{}", scene.bodies[bi].name, s1, s2);
            let (nodes, area, normal) = face_group_geometry(&body.mesh, &faces);
            let coords: Vec<[f64; D]> = nodes.iter().map(|&n| body.mesh.nodes[n]).collect();
            interfaces.push(Interface {
                name,
                law: InterfaceLaw::Perfect,
                sides: vec![side(s1, &nodes), side(s2, &nodes)],
                gap0: vec![0.0; nodes.len()],
                area,
                normal,
                coords,
            });
        }
    }
    interfaces
}

/// The scene's interfaces between bodies, or with a wall, appended to `interfaces`; each name's
/// range of interfaces there (a declared interface is one per pair of substructures it joins).
fn declared_interfaces<const D: usize>(
    scene: &Scene,
    r: &Resolver,
    bodies: &[Body<D>],
    local_of: &[HashMap<usize, usize>],
    interfaces: &mut Vec<Interface<D>>,
) -> Result<BTreeMap<String, std::ops::Range<usize>>, SceneError> {
    let mut interface_index = BTreeMap::new();
    for (ii, spec) in scene.interfaces.iter().enumerate() {
        let key = format!("interfaces[{ii}]");
        if interface_index.contains_key(&spec.name) {
            return Err(invalid(format!("{key}.name"), format!("duplicate interface name '{}'", spec.name)));
        }
        let law = glissade_core::check::interface_law(r, &key, spec)?;
        let (ba, faces_a) = find_face_set(bodies, &format!("{key}.a"), &spec.a)?;
        let first = interfaces.len();
        let new = Sides { spec, key: &key, law, bodies, local_of, a: (ba, faces_a) };
        if spec.b == "wall" {
            wall_interfaces(&new, r, interfaces)?;
        } else {
            body_interfaces(&new, interfaces)?;
        }
        interface_index.insert(spec.name.clone(), first..interfaces.len());
    }
    Ok(interface_index)
}

/// What the interfaces of one declared interface are built from.
struct Sides<'a, const D: usize> {
    spec: &'a glissade_core::scene::InterfaceSpec,
    key: &'a str,
    law: InterfaceLaw,
    bodies: &'a [Body<D>],
    local_of: &'a [HashMap<usize, usize>],
    /// side 1's body and its faces
    a: (usize, &'a [Face]),
}

impl<const D: usize> Sides<'_, D> {
    /// Side 1's body's mesh.
    fn mesh_a(&self) -> &Mesh<D> {
        &self.bodies[self.a.0].mesh
    }

    /// The side of substructure `s` on the body nodes `body_nodes`.
    fn side(&self, s: usize, body_nodes: &[usize]) -> InterfaceSide {
        interface_side(self.local_of, s, body_nodes)
    }
}

/// A declared interface with a rigid wall: one interface per substructure its faces lie on.
fn wall_interfaces<const D: usize>(
    new: &Sides<D>,
    r: &Resolver,
    interfaces: &mut Vec<Interface<D>>,
) -> Result<(), SceneError> {
    let Sides { spec, key, law, bodies, a: (ba, faces_a), .. } = *new;
    let mesh_a = new.mesh_a();
    if matches!(law, InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. }) {
        return Err(invalid(
            format!("{key}.law"),
            "a glued interface with a wall is a boundary condition: use [[boundary]] (clamped or displacement)",
        ));
    }
    let gap = match &spec.gap {
        Some(g) => r.get(&format!("{key}.gap"), g)?,
        None => 0.0,
    };
    if gap < 0.0 {
        return Err(invalid(format!("{key}.gap"), "an initial gap must be >= 0"));
    }
    let mut groups: BTreeMap<usize, Vec<Face>> = BTreeMap::new();
    for f in faces_a {
        groups.entry(bodies[ba].partition[f.element]).or_default().push(*f);
    }
    for (s1, faces) in groups {
        let (nodes, area, normal) = face_group_geometry(mesh_a, &faces);
        let coords: Vec<[f64; D]> = nodes.iter().map(|&n| mesh_a.nodes[n]).collect();
        interfaces.push(Interface {
            name: spec.name.clone(),
            law,
            sides: vec![new.side(s1, &nodes)],
            gap0: vec![gap; nodes.len()],
            area,
            normal,
            coords,
        });
    }
    Ok(())
}

/// A declared interface between two bodies whose faces conform: one interface per pair of
/// substructures it joins.
fn body_interfaces<const D: usize>(new: &Sides<D>, interfaces: &mut Vec<Interface<D>>) -> Result<(), SceneError> {
    let Sides { spec, key, law, bodies, local_of, a: (ba, faces_a) } = *new;
    let mesh_a = new.mesh_a();
    if spec.gap.is_some() {
        return Err(invalid(format!("{key}.gap"), "a gap is only allowed with b = \"wall\" (body faces must touch)"));
    }
    let (bb, faces_b) = find_face_set(bodies, &format!("{key}.b"), &spec.b)?;
    if ba == bb {
        return Err(invalid(format!("{key}.b"), "both sides are on the same body"));
    }
    let mesh_b = &bodies[bb].mesh;
    let scale = bbox_size(mesh_a).max(bbox_size(mesh_b));
    let tol = 1e-9 * scale;
    let quant = |p: &[f64; D]| -> Vec<i64> { p.iter().map(|x| (x / tol).round() as i64).collect() };
    let mut node_b: HashMap<Vec<i64>, usize> = HashMap::new();
    let mut face_b: HashMap<Vec<usize>, usize> = HashMap::new();
    for f in faces_b {
        let nodes = mesh_b.face_nodes(*f);
        for &n in &nodes {
            node_b.insert(quant(&mesh_b.nodes[n]), n);
        }
        let mut k = nodes;
        k.sort_unstable();
        face_b.insert(k, bodies[bb].partition[f.element]);
    }
    let mut groups: BTreeMap<(usize, usize), Vec<Face>> = BTreeMap::new();
    for f in faces_a {
        let mut matched = Vec::new();
        let fnodes = mesh_a.face_nodes(*f);
        // names the face by its nodes' coordinates, what the user can find in a viewer
        let nonconforming = |why: String| {
            let at: Vec<[f64; D]> = fnodes.iter().map(|&n| mesh_a.nodes[n]).collect();
            invalid(
                key,
                format!("interface faces do not match: the face of '{}' at {at:?} {why} on '{}'", spec.a, spec.b),
            )
        };
        for &n in &fnodes {
            let p = mesh_a.nodes[n];
            let nb = node_b
                .get(&quant(&p))
                .ok_or_else(|| nonconforming(format!("has a node at {p:?} with no counterpart")))?;
            matched.push(*nb);
        }
        matched.sort_unstable();
        let s2 = face_b.get(&matched).ok_or_else(|| nonconforming("has no conforming face".into()))?;
        groups.entry((bodies[ba].partition[f.element], *s2)).or_default().push(*f);
    }
    if groups.values().map(Vec::len).sum::<usize>() != faces_b.len() {
        return Err(invalid(
            key,
            format!("interface faces do not match: '{}' and '{}' have different numbers of faces", spec.a, spec.b),
        ));
    }
    for ((s1, s2), faces) in groups {
        let (nodes, area, normal) = face_group_geometry(mesh_a, &faces);
        let coords: Vec<[f64; D]> = nodes.iter().map(|&n| mesh_a.nodes[n]).collect();
        let nodes_b: Vec<usize> = coords.iter().map(|p| node_b[&quant(p)]).collect();
        let mut sides = vec![new.side(s1, &nodes), new.side(s2, &nodes_b)];
        sides[1].nodes = nodes_b.iter().map(|g| local_of[s2][g]).collect();
        interfaces.push(Interface {
            name: spec.name.clone(),
            law,
            sides,
            gap0: vec![0.0; nodes.len()],
            area,
            normal,
            coords,
        });
    }
    Ok(())
}

/// Boundary conditions and loads onto the substructures' dofs; the load histories (the first is
/// the constant one).
fn boundary_and_loads<const D: usize>(
    scene: &Scene,
    r: &Resolver,
    bodies: &[Body<D>],
    local_of: &[HashMap<usize, usize>],
    substructures: &mut [Substructure<D>],
) -> Result<Vec<History>, SceneError> {
    let mut histories = vec![History::constant()];
    for (i, bc) in scene.boundary.iter().enumerate() {
        let key = format!("boundary[{i}]");
        let (bi, faces) = find_face_set(bodies, &format!("{key}.face"), &bc.face)?;
        let mut comps: Vec<(usize, f64, f64)> = Vec::new(); // (component, static u, velocity)
        if bc.clamped {
            comps.extend((0..D).map(|c| (c, 0.0, 0.0)));
        }
        for (name, v) in bc.displacement.iter().flatten() {
            let c = component_index(&format!("{key}.displacement.{name}"), name, D)?;
            comps.push((c, r.get(&format!("{key}.displacement.{name}"), v)?, 0.0));
        }
        for (name, v) in bc.velocity.iter().flatten() {
            let c = component_index(&format!("{key}.velocity.{name}"), name, D)?;
            comps.push((c, 0.0, r.get(&format!("{key}.velocity.{name}"), v)?));
        }
        if comps.is_empty() {
            return Err(invalid(key, "a boundary condition needs clamped = true, displacement or velocity"));
        }
        let history = histories.len();
        histories.push(r.history(&format!("{key}.history"), &bc.history)?);
        for f in faces {
            let s = bodies[bi].partition[f.element];
            for n in bodies[bi].mesh.face_nodes(*f) {
                let l = local_of[s][&n];
                for &(c, u, v) in &comps {
                    let dof = l * D + c;
                    let sub = &mut substructures[s];
                    sub.fixed[dof] = true;
                    sub.prescribed.retain(|p| p.dof != dof);
                    sub.prescribed.push(PrescribedDof { dof, static_displacement: u, velocity: v, history });
                }
            }
        }
    }
    for (i, load) in scene.loads.iter().enumerate() {
        let key = format!("loads[{i}]");
        let (bi, faces) = find_face_set(bodies, &format!("{key}.face"), &load.face)?;
        let pressure = match &load.pressure {
            Some(p) => Some(r.get(&format!("{key}.pressure"), p)?),
            None => None,
        };
        let traction = match &load.traction {
            Some(t) => Some(r.vector::<D>(&format!("{key}.traction"), t)?),
            None => None,
        };
        if pressure.is_some() == traction.is_some() {
            return Err(invalid(key, "a load needs exactly one of pressure or traction"));
        }
        let history = histories.len();
        histories.push(r.history(&format!("{key}.history"), &load.history)?);
        let mesh = &bodies[bi].mesh;
        let mut per_sub: BTreeMap<usize, Vec<(usize, f64)>> = BTreeMap::new();
        for f in faces {
            let s = bodies[bi].partition[f.element];
            let fnodes = mesh.face_nodes(*f);
            let x: Vec<[f64; D]> = fnodes.iter().map(|&n| mesh.nodes[n]).collect();
            let (area, normal) = face_area_and_normal(&x, mesh.centroid(f.element));
            let t = match (pressure, traction) {
                (Some(p), _) => normal.map(|n| -p * n),
                (_, Some(t)) => t,
                _ => unreachable!("checked above"),
            };
            for (a, &n) in fnodes.iter().enumerate() {
                for c in 0..D {
                    per_sub.entry(s).or_default().push((local_of[s][&n] * D + c, area[a] * t[c]));
                }
            }
        }
        for (s, forces) in per_sub {
            substructures[s].loads.push(NodalLoad { forces, history });
        }
    }
    Ok(histories)
}

/// The scene's QoIs, each located on an interface node or a body's dof.
fn quantities_of_interest<const D: usize>(
    scene: &Scene,
    r: &Resolver,
    bodies: &[Body<D>],
    interfaces: &[Interface<D>],
    interface_index: &BTreeMap<String, std::ops::Range<usize>>,
    substructures: &[Substructure<D>],
    local_of: &[HashMap<usize, usize>],
) -> Result<Vec<Qoi>, SceneError> {
    let mut qois = Vec::new();
    for (i, q) in scene.qoi.iter().enumerate() {
        let key = format!("qoi[{i}]");
        if scene.qoi[..i].iter().any(|o| o.name == q.name) {
            return Err(invalid(format!("{key}.name"), format!("duplicate QoI name '{}'", q.name)));
        }
        let point = |q: &glissade_core::scene::QoiSpec| -> Result<[f64; D], SceneError> {
            let p = q.point.as_ref().ok_or_else(|| invalid(format!("{key}.point"), "this QoI needs a point"))?;
            r.vector::<D>(&format!("{key}.point"), p)
        };
        let component = |q: &glissade_core::scene::QoiSpec| -> Result<usize, SceneError> {
            let c = q
                .component
                .as_deref()
                .ok_or_else(|| invalid(format!("{key}.component"), "this QoI needs a component (x, y or z)"))?;
            component_index(&format!("{key}.component"), c, D)
        };
        let target = match q.kind {
            QoiKind::Slip | QoiKind::Force => {
                let name = q
                    .interface
                    .as_ref()
                    .ok_or_else(|| invalid(format!("{key}.interface"), "this QoI needs an interface"))?;
                let range = interface_index
                    .get(name)
                    .ok_or_else(|| invalid(format!("{key}.interface"), format!("unknown interface '{name}'")))?
                    .clone();
                if q.kind == QoiKind::Force {
                    QoiTarget::Force { interfaces: range, component: component(q)? }
                } else {
                    let p = point(q)?;
                    let (mut best, mut dist) = ((0, 0), f64::INFINITY);
                    for ii in range {
                        for (j, c) in interfaces[ii].coords.iter().enumerate() {
                            let d = distance(c, &p);
                            if d < dist {
                                (best, dist) = ((ii, j), d);
                            }
                        }
                    }
                    let h = min_spacing(&interfaces[best.0].coords);
                    if dist > 0.5 * h + 1e-12 {
                        return Err(invalid(
                            format!("{key}.point"),
                            format!("{p:?} is not on interface '{name}' (nearest node {dist:.3e} away)"),
                        ));
                    }
                    // a component: the slip vector (tangential already) along an axis, signed
                    let component = match q.component {
                        Some(_) => Some(component(q)?),
                        None => None,
                    };
                    QoiTarget::Slip { interface: best.0, node: best.1, component }
                }
            }
            QoiKind::Displacement | QoiKind::Velocity => {
                let name = q.body.as_ref().ok_or_else(|| invalid(format!("{key}.body"), "this QoI needs a body"))?;
                let bi = bodies
                    .iter()
                    .position(|b| &b.name == name)
                    .ok_or_else(|| invalid(format!("{key}.body"), format!("unknown body '{name}'")))?;
                let p = point(q)?;
                let c = component(q)?;
                let mesh = &bodies[bi].mesh;
                let (n, dist) = mesh
                    .nodes
                    .iter()
                    .enumerate()
                    .map(|(n, x)| (n, distance(x, &p)))
                    .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
                if dist > 1e-6 * bbox_size(mesh) {
                    return Err(invalid(
                        format!("{key}.point"),
                        format!("{p:?} is not a node of body '{name}' (nearest {dist:.3e} away)"),
                    ));
                }
                let s = (0..substructures.len())
                    .find(|&s| substructures[s].body == bi && local_of[s].contains_key(&n))
                    .expect("every node is in a substructure");
                let dof = local_of[s][&n] * D + c;
                if q.kind == QoiKind::Displacement {
                    QoiTarget::Displacement { substructure: s, dof }
                } else {
                    QoiTarget::Velocity { substructure: s, dof }
                }
            }
        };
        qois.push(Qoi { name: q.name.clone(), target });
    }
    Ok(qois)
}

/// Every interface side's search directions, static and dynamic (docs/method.md 3), from the
/// materials and sizes on either side; `factors`: the scene's k0 and tangential factors; `step`:
/// dt, the duration of a time window (the whole interval's without windows) and Newmark's gamma.
fn set_search_directions<const D: usize>(
    interfaces: &mut [Interface<D>],
    substructures: &[Substructure<D>],
    (k0_factor, tangential_factor): (f64, f64),
    assembly_size: f64,
    (dt, window, gamma): (f64, f64, f64),
) {
    for itf in interfaces.iter_mut() {
        let normal = itf.mean_normal();
        let h = itf.mesh_size();
        let depth = itf.element_depth(substructures);
        for side in itf.sides.iter_mut() {
            let young = substructures[side.substructure].material.young;
            side.k_static =
                SearchDirection::isotropic(k0_factor * static_search_direction(young, assembly_size, h, depth));
            let sub = &substructures[side.substructure];
            let k = k0_factor
                * dynamic_search_direction(
                    sub.material.impedance(),
                    sub.material.bar_wave_speed(),
                    sub.depth_along(&normal),
                    dt,
                );
            let inertia = inertia_search_direction(side_mass_per_measure(sub, &side.nodes, &itf.area), gamma, window);
            // the nodes' inertia is the same along every direction: it bounds the tangential part
            // too where the interface carries the tangential velocity (perfect), not where a law
            // sets it (a contact's slip history converges at a rate set by k_t, docs/performance.md)
            let k_n = k.max(k0_factor * inertia);
            let tangential = match itf.law {
                InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. } => k_n,
                InterfaceLaw::Contact | InterfaceLaw::Friction { .. } => k * tangential_factor,
            };
            side.k_dynamic = SearchDirection { normal: k_n, tangential };
        }
    }
}

/// The diagonal of a substructure's mass at a side's interface nodes (the mean over each node's
/// dofs), per unit of the interface's measure `area` (per interface node, in the side's order).
fn side_mass_per_measure<const D: usize>(sub: &Substructure<D>, nodes: &[usize], area: &[f64]) -> f64 {
    let measure: f64 = area.iter().sum();
    if measure <= 0.0 {
        return 0.0;
    }
    let mass: f64 = nodes.iter().map(|&n| (0..D).map(|c| sub.mass.diagonal(n * D + c)).sum::<f64>() / D as f64).sum();
    mass / measure
}

/// The search direction's part from node to node ([`InterfaceSide::k_along`]) on perfect
/// interfaces whose elements are at least [`crate::latin::FLAT_ELEMENTS`] times deeper than
/// long along them. A scalar k cannot serve them: a smooth interface field meets about the
/// impedance (or E / L statically), one that changes from node to node the stiffness of the
/// element layer, about E h_n / h_t^2, a^2 times more (docs/performance.md, "Flat elements along
/// an interface"). k + g M_Gamma^-1 L follows both ends: L the interface's Laplacian, g = E h_n
/// [`ALONG_FACTOR`] with h_n the depth of each face's element.
fn set_along_directions<const D: usize>(interfaces: &mut [Interface<D>], substructures: &[Substructure<D>]) {
    for itf in interfaces.iter_mut() {
        let flat = itf.element_depth(substructures).is_some_and(|a| a >= crate::latin::FLAT_ELEMENTS);
        if !flat || itf.sides.len() != 2 || !matches!(itf.law, InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. }) {
            continue;
        }
        let normal = itf.mean_normal();
        for side in itf.sides.iter_mut() {
            side.k_along = along_triplets(&substructures[side.substructure], &side.nodes, &normal);
        }
    }
}

/// g = ALONG_FACTOR E h_n (measured: docs/performance.md, "Flat elements along an interface").
pub const ALONG_FACTOR: f64 = 1.0 / 3.0;

/// The triplets of sum over the side's faces of E h_n ALONG_FACTOR times the face's Laplacian
/// (2D: 1 / l on its one edge; 3D: the edges of a quadrilateral weighted A / (2 l^2), of a
/// triangle by the cotangents of the opposite angles over 2), over interface node numbers.
fn along_triplets<const D: usize>(
    sub: &Substructure<D>,
    nodes: &[usize],
    normal: &[f64; D],
) -> Vec<(usize, usize, f64)> {
    let index: HashMap<usize, usize> = nodes.iter().enumerate().map(|(j, &n)| (n, j)).collect();
    let young = sub.material.young * ALONG_FACTOR;
    let per = sub.kind.nodes(D);
    let mut t = Vec::new();
    for element in sub.connectivity.chunks(per) {
        let along = |n: usize| (0..D).map(|c| sub.coords[n][c] * normal[c]).sum::<f64>();
        let (lo, hi) = element
            .iter()
            .map(|&n| along(n))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        let g = young * (hi - lo);
        for f in 0..sub.kind.faces(D) {
            let face: Vec<usize> = sub.kind.face_local_nodes(D, f).iter().map(|&a| element[a]).collect();
            let Some(js) = face.iter().map(|n| index.get(n).copied()).collect::<Option<Vec<usize>>>() else {
                continue;
            };
            // in 3 components whatever D
            let x: Vec<[f64; 3]> =
                face.iter().map(|&n| std::array::from_fn(|c| if c < D { sub.coords[n][c] } else { 0.0 })).collect();
            for (a, b, w) in face_laplacian(&x) {
                let (ja, jb, w) = (js[a], js[b], g * w);
                t.extend([(ja, ja, w), (jb, jb, w), (ja, jb, -w), (jb, ja, -w)]);
            }
        }
    }
    t
}

/// The edges (a, b, weight) of one face's Laplacian: a segment's 1 / l; a quadrilateral in tensor
/// order (its sides 0-1, 2-3, 0-2, 1-3) A / (2 l^2) a side, which sums to the five-point
/// Laplacian on a grid of rectangles; a triangle the cotangent of the angle opposite each side
/// over 2, its linear elements' Laplacian (an obtuse angle's negative weight dropped: the
/// operator stays positive).
fn face_laplacian(x: &[[f64; 3]]) -> Vec<(usize, usize, f64)> {
    let minus = |a: [f64; 3], b: [f64; 3]| -> [f64; 3] { std::array::from_fn(|c| a[c] - b[c]) };
    let dot = |a: [f64; 3], b: [f64; 3]| -> f64 { (0..3).map(|c| a[c] * b[c]).sum() };
    let cross =
        |u: [f64; 3], v: [f64; 3]| [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    let squared = |a: usize, b: usize| dot(minus(x[b], x[a]), minus(x[b], x[a]));
    match x.len() {
        2 => vec![(0, 1, 1.0 / squared(0, 1).sqrt())],
        4 => {
            let n = cross(minus(x[1], x[0]), minus(x[2], x[0]));
            let area = dot(n, n).sqrt();
            [(0, 1), (2, 3), (0, 2), (1, 3)].into_iter().map(|(a, b)| (a, b, area / (2.0 * squared(a, b)))).collect()
        }
        3 => [(0, 1, 2), (1, 2, 0), (0, 2, 1)]
            .into_iter()
            .map(|(a, b, c)| {
                let (u, v) = (minus(x[a], x[c]), minus(x[b], x[c]));
                let sine = dot(cross(u, v), cross(u, v)).sqrt();
                (a, b, (0.5 * dot(u, v) / sine.max(f64::MIN_POSITIVE)).max(0.0))
            })
            .collect(),
        _ => Vec::new(),
    }
}

/// Accepted values of `[solver] tangential_factor` (checked by `Scene::check_point`).
pub use glissade_core::check::TANGENTIAL_FACTOR_RANGE;

impl<const D: usize> Substructure<D> {
    /// The substructure's depth along `normal`: the extent of its nodes' projections (NaN when
    /// it has none).
    pub fn depth_along(&self, normal: &[f64; D]) -> f64 {
        let along = |x: &[f64; D]| (0..D).map(|c| x[c] * normal[c]).sum::<f64>();
        let (lo, hi) =
            self.coords.iter().map(along).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        hi - lo
    }
}

/// The mesh of a body (a box or a Gmsh volume) and its partition (element -> substructure of
/// the body).
fn body_mesh<const D: usize>(
    scene: &Scene,
    r: &Resolver,
    key: &str,
    b: &BodySpec,
) -> Result<(Mesh<D>, Vec<usize>), SceneError> {
    let count_key = format!("{key}.substructures");
    if let Some(spec) = &b.mesh {
        if b.size.is_some() || b.elements.is_some() || b.origin.is_some() {
            return Err(invalid(key, "a mesh body takes no size, elements or origin"));
        }
        if D != 3 {
            return Err(invalid(format!("{key}.mesh"), format!("mesh bodies need dimension = 3, not {D}")));
        }
        // The bytes attached to the scene (read next to its file, or carried by the service):
        // a path from elsewhere never opens this machine's files.
        let Some(bytes) = scene.meshes.get(&spec.file) else {
            return Err(invalid(
                format!("{key}.mesh.file"),
                format!("mesh file '{}' is not attached to the scene (Scene::read or attach_mesh_bytes)", spec.file),
            ));
        };
        let mesh3 = crate::gmsh::parse_volume(bytes, &spec.volume)
            .map_err(|e| invalid(format!("{key}.mesh"), format!("{}: {e}", spec.file)))?;
        // D == 3, checked above: the same mesh with its points typed as [f64; D]
        let mesh = Mesh::<D> {
            nodes: mesh3.nodes.iter().map(|p| std::array::from_fn(|d| p[d])).collect(),
            kind: mesh3.kind,
            connectivity: mesh3.connectivity,
            face_sets: mesh3.face_sets,
        };
        let parts = match &b.substructures {
            None => 1,
            Some(Substructures::Count(n)) => *n,
            Some(Substructures::PerAxis(_)) => {
                return Err(invalid(count_key, "a mesh body takes a number of substructures (substructures = 8)"));
            }
        };
        if parts == 0 || parts > mesh.n_elements() {
            return Err(invalid(count_key, format!("must be 1 to {} (the elements), got {parts}", mesh.n_elements())));
        }
        let partition = mesh.graph_partition(parts).map_err(|e| invalid(count_key, e.to_string()))?;
        return Ok((mesh, partition));
    }
    let (Some(size), Some(elements)) = (&b.size, &b.elements) else {
        return Err(invalid(key, "a body is a box (size and elements) or a mesh (mesh = { file, volume })"));
    };
    let origin = match &b.origin {
        Some(o) => r.vector::<D>(&format!("{key}.origin"), o)?,
        None => [0.0; D],
    };
    let size = r.vector::<D>(&format!("{key}.size"), size)?;
    if size.iter().any(|&s| s <= 0.0) {
        return Err(invalid(format!("{key}.size"), "every extent must be > 0"));
    }
    let counts = usize_vector::<D>(&format!("{key}.elements"), elements)?;
    let parts = match &b.substructures {
        Some(Substructures::PerAxis(p)) => usize_vector::<D>(&count_key, p)?,
        Some(Substructures::Count(_)) => {
            return Err(invalid(count_key, format!("a box takes a count per axis (substructures = [..; {D}])")));
        }
        None => [1; D],
    };
    for d in 0..D {
        if parts[d] > counts[d] {
            return Err(invalid(
                count_key,
                format!("{} substructures along axis {d} but only {} elements", parts[d], counts[d]),
            ));
        }
    }
    Ok((Mesh::structured_box(origin, size, counts), Mesh::<D>::box_partition(counts, parts)))
}

fn usize_vector<const D: usize>(key: &str, v: &[usize]) -> Result<[usize; D], SceneError> {
    if v.len() != D {
        return Err(invalid(key, format!("expected {D} counts (dimension {D}), got {}", v.len())));
    }
    let mut out = [0; D];
    for (i, &c) in v.iter().enumerate() {
        if c == 0 {
            return Err(invalid(format!("{key}[{i}]"), "counts must be >= 1"));
        }
        out[i] = c;
    }
    Ok(out)
}

fn distance<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    (0..D).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

fn bbox_size<const D: usize>(mesh: &Mesh<D>) -> f64 {
    let mut s: f64 = 0.0;
    for d in 0..D {
        let lo = mesh.nodes.iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
        let hi = mesh.nodes.iter().map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
        s = s.max(hi - lo);
    }
    s
}

fn min_spacing<const D: usize>(coords: &[[f64; D]]) -> f64 {
    if coords.len() < 2 {
        return f64::INFINITY;
    }
    let mut h = f64::INFINITY;
    for (i, a) in coords.iter().enumerate() {
        for b in &coords[i + 1..] {
            h = h.min(distance(a, b));
        }
    }
    h
}

fn find_face_set<'a, const D: usize>(
    bodies: &'a [Body<D>],
    key: &str,
    spec: &str,
) -> Result<(usize, &'a Vec<Face>), SceneError> {
    let (body, face) = spec
        .split_once('.')
        .ok_or_else(|| invalid(key, format!("'{spec}' is not of the form body.face (e.g. block.z+)")))?;
    let bi =
        bodies.iter().position(|b| b.name == body).ok_or_else(|| invalid(key, format!("unknown body '{body}'")))?;
    let faces = bodies[bi].mesh.face_sets.get(face).ok_or_else(|| {
        invalid(
            key,
            format!(
                "body '{body}' has no face '{face}' (has: {})",
                bodies[bi].mesh.face_sets.keys().cloned().collect::<Vec<_>>().join(", ")
            ),
        )
    })?;
    Ok((bi, faces))
}

/// Nodes (body numbering, sorted), nodal areas and area-weighted unit normals of a set of faces.
fn face_group_geometry<const D: usize>(mesh: &Mesh<D>, faces: &[Face]) -> (Vec<usize>, Vec<f64>, Vec<[f64; D]>) {
    let mut index: BTreeMap<usize, usize> = BTreeMap::new();
    for f in faces {
        for n in mesh.face_nodes(*f) {
            let len = index.len();
            index.entry(n).or_insert(len);
        }
    }
    let nodes_unsorted: Vec<usize> = {
        let mut v = vec![0; index.len()];
        for (&n, &i) in &index {
            v[i] = n;
        }
        v
    };
    let mut area = vec![0.0; nodes_unsorted.len()];
    let mut normal = vec![[0.0; D]; nodes_unsorted.len()];
    for f in faces {
        let fnodes = mesh.face_nodes(*f);
        let x: Vec<[f64; D]> = fnodes.iter().map(|&n| mesh.nodes[n]).collect();
        let (a, n) = face_area_and_normal(&x, mesh.centroid(f.element));
        for (k, node) in fnodes.iter().enumerate() {
            let i = index[node];
            area[i] += a[k];
            for d in 0..D {
                normal[i][d] += a[k] * n[d];
            }
        }
    }
    for n in normal.iter_mut() {
        let len = n.iter().map(|x| x * x).sum::<f64>().sqrt();
        for v in n.iter_mut() {
            *v /= len;
        }
    }
    // order nodes by body number for a stable layout
    let mut order: Vec<usize> = (0..nodes_unsorted.len()).collect();
    order.sort_by_key(|&i| nodes_unsorted[i]);
    (
        order.iter().map(|&i| nodes_unsorted[i]).collect(),
        order.iter().map(|&i| area[i]).collect(),
        order.iter().map(|&i| normal[i]).collect(),
    )
}

/// Assembles the stiffness and mass (consistent or lumped) of the elements of one substructure.
fn assemble_substructure<const D: usize>(
    body: usize,
    mesh: &Mesh<D>,
    elements: &[usize],
    material: Material,
    initial_velocity: [f64; D],
    mass: MassMatrix,
) -> Result<Substructure<D>, f64> {
    let mut nodes: Vec<usize> = elements.iter().flat_map(|&e| mesh.element(e).iter().copied()).collect();
    nodes.sort_unstable();
    nodes.dedup();
    let local: HashMap<usize, usize> = nodes.iter().enumerate().map(|(l, &g)| (g, l)).collect();
    let nn = mesh.kind.nodes(D);
    let nd = nn * D;
    let mut kt = Vec::with_capacity(elements.len() * nd * nd);
    let mut mt = Vec::with_capacity(elements.len() * nd * nd);
    let mut connectivity = Vec::with_capacity(elements.len() * nn);
    for &e in elements {
        let el = mesh.element(e);
        let x: Vec<[f64; D]> = el.iter().map(|&n| mesh.nodes[n]).collect();
        let (ke, me) = mesh.kind.matrices(&x, &material)?;
        let local = &local;
        let dofs: Vec<usize> = el.iter().flat_map(|n| (0..D).map(move |c| local[n] * D + c)).collect();
        connectivity.extend(el.iter().map(|n| local[n]));
        for r in 0..nd {
            for c in 0..nd {
                if ke[r * nd + c] != 0.0 {
                    kt.push((dofs[r], dofs[c], ke[r * nd + c]));
                }
                if me[r * nd + c] != 0.0 {
                    let column = if mass == MassMatrix::Lumped { dofs[r] } else { dofs[c] };
                    mt.push((dofs[r], column, me[r * nd + c]));
                }
            }
        }
    }
    let n = nodes.len() * D;
    Ok(Substructure {
        body,
        coords: nodes.iter().map(|&g| mesh.nodes[g]).collect(),
        nodes,
        connectivity,
        kind: mesh.kind,
        material,
        stiffness: CsrMatrix::from_triplets(n, kt),
        mass: CsrMatrix::from_triplets(n, mt),
        fixed: vec![false; n],
        prescribed: Vec::new(),
        loads: Vec::new(),
        initial_velocity,
        sides: Vec::new(),
    })
}

#[cfg(test)]
mod face_laplacian_tests {
    use super::face_laplacian;

    /// Each face's Laplacian against its closed form: a segment, a rectangle (the five-point
    /// weights) and a right triangle (the cotangent weights: 1/2 cot 45 on each leg, 0 on the
    /// hypotenuse, which faces the right angle).
    #[test]
    fn face_laplacians_have_their_closed_forms() {
        let weights = |x: &[[f64; 3]]| face_laplacian(x).into_iter().map(|(a, b, w)| ((a, b), w)).collect::<Vec<_>>();
        assert_eq!(weights(&[[0.0; 3], [0.0, 0.25, 0.0]]), vec![((0, 1), 4.0)]);
        // a 2 x 0.5 rectangle in tensor order: sides along 2 weigh 0.5 / 4, sides along 0.5 weigh 2
        let rect = weights(&[[0.0; 3], [2.0, 0.0, 0.0], [0.0, 0.0, 0.5], [2.0, 0.0, 0.5]]);
        for ((a, b), w) in rect {
            let expected = if (a, b) == (0, 1) || (a, b) == (2, 3) { 0.125 } else { 2.0 };
            assert!((w - expected).abs() < 1e-12, "{a}-{b}: {w}");
        }
        // the right isosceles triangle (0, 0), (1, 0), (0, 1): the legs 0-1 and 0-2 face 45
        // degrees (cot 1, weight 1/2), the hypotenuse 1-2 faces the right angle (cot 0)
        let tri = weights(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        for ((a, b), w) in tri {
            let expected = if (a, b) == (1, 2) { 0.0 } else { 0.5 };
            assert!((w - expected).abs() < 1e-12, "{a}-{b}: {w}");
        }
        // an obtuse angle's weight is dropped, not negative
        assert!(face_laplacian(&[[0.0; 3], [2.0, 0.0, 0.0], [1.0, 0.1, 0.0]]).iter().all(|e| e.2 >= 0.0));
    }
}
