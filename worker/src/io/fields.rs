//! Field output (`--fields OUT.h5`): displacement and velocity of every node, the stress of every
//! element and what happened on every interface, at every time step,
//! in one HDF5 file plus an XDMF 3 file beside it (`OUT.xdmf`) that ParaView opens as a time
//! series. Layout of the HDF5 file (see also `docs/solution-format.md`):
//!
//! ```text
//! /mesh/coordinates           N x 3 f64   all substructures' nodes, one after the other
//!                                         (interface nodes appear once per substructure)
//! /mesh/topology              E x 2^D i64 node numbers of each element, VTK/XDMF order
//! /mesh/substructure          E i64       substructure of each element
//! /time                       S+1 f64     t_0 .. t_S
//! /fields/displacement/NNNNNN N x 3 f64   step NNNNNN (zero-padded components beyond D)
//! /fields/velocity/NNNNNN     N x 3 f64
//! /fields/stress/NNNNNN       E x 6 f64   each element's stress at its centre (Pa): XDMF's
//!                                         Tensor6 order xx, xy, xz, yy, yz, zz
//! /fields/von_mises/NNNNNN    E f64       its von Mises equivalent (Pa)
//! ```
//!
//! The stress is derived here from the displacements (glissade_solver::element::centre_stress:
//! Hooke's law at the element's centre; plane strain in 2D, a bar's axial stress in 1D).
//!
//! The interfaces' nodes, all interfaces one after the other, and what happened there
//! (glissade_solver::run::InterfaceOutput), with their own XDMF file (`OUT-interfaces.xdmf`, a
//! time series of vertices):
//!
//! ```text
//! /interfaces/coordinates          M x 3 f64
//! /interfaces/interface            M i64     the interface of each node (scene order)
//! /interfaces/names                I str     the interfaces' names
//! /fields/contact_pressure/NNNNNN  M f64     the normal traction pressing the sides together (Pa)
//! /fields/gap/NNNNNN               M f64     the normal gap (m)
//! /fields/slip/NNNNNN              M x 3 f64 the tangential relative displacement since the dynamics began (m)
//! ```
//! Root attributes: `dimension` (i64), `scene_hash`, `solver_version` (strings).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use hdf5::types::VarLenUnicode;

use glissade_solver::element::{self, ElementKind};
use glissade_solver::run::FieldOutput;

/// Errors of writing field output.
#[derive(Debug, thiserror::Error)]
pub enum FieldsError {
    #[error("{0}")]
    Invalid(String),
    #[error("HDF5: {0}")]
    Hdf5(#[from] hdf5::Error),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// Element node order of VTK/XDMF from our tensor order (bit d of the local index = side along
/// axis d): the same for bars, (0,1,3,2) for quads, (0,1,3,2,4,5,7,6) for hexahedra.
pub fn vtk_order(dimension: usize) -> &'static [usize] {
    match dimension {
        1 => &[0, 1],
        2 => &[0, 1, 3, 2],
        _ => &[0, 1, 3, 2, 4, 5, 7, 6],
    }
}

/// XDMF topology type and its extra attributes for a dimension.
fn xdmf_topology(dimension: usize, kind: ElementKind) -> &'static str {
    if kind == ElementKind::Simplex {
        // Gmsh's linear simplices are in VTK's order
        return if dimension == 3 { r#"TopologyType="Tetrahedron""# } else { r#"TopologyType="Triangle""# };
    }
    match dimension {
        1 => r#"TopologyType="Polyline" NodesPerElement="2""#,
        2 => r#"TopologyType="Quadrilateral""#,
        _ => r#"TopologyType="Hexahedron""#,
    }
}

/// The XDMF file written beside `h5`: same stem, extension `.xdmf`.
pub fn xdmf_path(h5: &Path) -> PathBuf {
    h5.with_extension("xdmf")
}

/// All substructures merged into one mesh, and the fields laid out on it.
struct Merged {
    dimension: usize,
    kind: ElementKind,
    coords: Vec<f64>,
    topology: Vec<i64>,
    substructure: Vec<i64>,
    /// first merged node of each substructure
    offsets: Vec<usize>,
    nodes: usize,
    elements: usize,
}

fn merge(f: &FieldOutput) -> Result<Merged, FieldsError> {
    let invalid = |m: String| FieldsError::Invalid(m);
    let Some(first) = f.meshes.first() else {
        return Err(invalid("no substructures to write".into()));
    };
    let d = first.dimension;
    if !(1..=3).contains(&d) {
        return Err(invalid(format!("dimension {d} is not 1, 2 or 3")));
    }
    let kind = first.kind;
    let npe = kind.nodes(d);
    let steps = f.times.len();
    let h = &f.history;
    if h.displacement.len() != f.meshes.len() || h.velocity.len() != f.meshes.len() {
        return Err(invalid(format!(
            "{} substructure meshes but fields of {} and {}",
            f.meshes.len(),
            h.displacement.len(),
            h.velocity.len()
        )));
    }
    let tensor_order = vtk_order(d);
    let order: Vec<usize> = if kind == ElementKind::Tensor { tensor_order.to_vec() } else { (0..npe).collect() };
    let mut m = Merged {
        dimension: d,
        kind,
        coords: Vec::new(),
        topology: Vec::new(),
        substructure: Vec::new(),
        offsets: Vec::new(),
        nodes: 0,
        elements: 0,
    };
    for (s, mesh) in f.meshes.iter().enumerate() {
        let n = mesh.coords.len();
        let ok_fields = [&h.displacement[s], &h.velocity[s]]
            .iter()
            .all(|per_step| per_step.len() == steps && per_step.iter().all(|v| v.len() == n * d));
        if mesh.kind != kind {
            return Err(invalid(format!(
                "substructure {s}: tetrahedra and hexahedra in one output are not supported yet (one grid, one kind)"
            )));
        }
        if mesh.dimension != d || mesh.connectivity.len() % npe != 0 || !ok_fields {
            return Err(invalid(format!(
                "substructure {s}: mesh and fields do not fit ({n} nodes, dimension {}, {} steps)",
                mesh.dimension, steps
            )));
        }
        if let Some(&bad) = mesh.connectivity.iter().find(|&&i| i >= n) {
            return Err(invalid(format!("substructure {s}: element node {bad} out of range ({n} nodes)")));
        }
        m.offsets.push(m.nodes);
        m.coords.extend(mesh.coords.iter().flatten());
        for el in mesh.connectivity.chunks_exact(npe) {
            m.topology.extend(order.iter().map(|&k| (m.nodes + el[k]) as i64));
            m.substructure.push(s as i64);
        }
        m.nodes += n;
        m.elements += mesh.connectivity.len() / npe;
    }
    Ok(m)
}

impl Merged {
    /// One step of a field (`[substructure][step][dof]`) as N x 3, zero-padded.
    fn step(&self, field: &[Vec<Vec<f64>>], step: usize) -> Vec<f64> {
        let d = self.dimension;
        let mut out = vec![0.0; self.nodes * 3];
        for (s, per_step) in field.iter().enumerate() {
            for (i, node) in per_step[step].chunks_exact(d).enumerate() {
                let at = (self.offsets[s] + i) * 3;
                out[at..at + d].copy_from_slice(node);
            }
        }
        out
    }
}

impl Merged {
    /// Each element's stress at its centre at `step` (E x 6, Tensor6 order) and its von Mises
    /// equivalent (E), from the displacements.
    fn stress(&self, f: &FieldOutput, step: usize) -> Result<(Vec<f64>, Vec<f64>), FieldsError> {
        let (mut tensor, mut equivalent) = (Vec::with_capacity(6 * self.elements), Vec::with_capacity(self.elements));
        for (s, mesh) in f.meshes.iter().enumerate() {
            let u = &f.history.displacement[s][step];
            let npe = mesh.kind.nodes(self.dimension);
            for (k, el) in mesh.connectivity.chunks_exact(npe).enumerate() {
                let v = match self.dimension {
                    1 => element_stress::<1>(mesh, el, u),
                    2 => element_stress::<2>(mesh, el, u),
                    _ => element_stress::<3>(mesh, el, u),
                }
                .map_err(|det| {
                    FieldsError::Invalid(format!(
                        "substructure {s}, element {k}: not a valid element (determinant {det:e})"
                    ))
                })?;
                tensor.extend([v[0], v[3], v[5], v[1], v[4], v[2]]);
                equivalent.push(element::von_mises(&v));
            }
        }
        Ok((tensor, equivalent))
    }
}

/// One element's stress (Voigt order), its nodes' coordinates and displacements taken from the
/// padded coordinates and the step's dofs.
fn element_stress<const D: usize>(
    mesh: &glissade_solver::run::SubstructureMesh,
    el: &[usize],
    u: &[f64],
) -> Result<[f64; 6], f64> {
    let x: Vec<[f64; D]> = el.iter().map(|&a| std::array::from_fn(|i| mesh.coords[a][i])).collect();
    let ua: Vec<[f64; D]> = el.iter().map(|&a| std::array::from_fn(|i| u[a * D + i])).collect();
    element::centre_stress(mesh.kind, &x, &ua, &mesh.material)
}

fn step_name(step: usize) -> String {
    format!("{step:06}")
}

/// Writes `fields` to `h5` and the XDMF description beside it (see the module documentation);
/// both atomically. Returns the XDMF path.
pub fn write(h5: &Path, fields: &FieldOutput, scene_hash: &str) -> Result<PathBuf, FieldsError> {
    let xdmf = xdmf_path(h5);
    if xdmf == h5 {
        return Err(FieldsError::Invalid(format!(
            "{}: the field file needs another extension than .xdmf (e.g. .h5), the XDMF file goes beside it",
            h5.display()
        )));
    }
    let h5_name = h5
        .file_name()
        .ok_or_else(|| FieldsError::Invalid(format!("{}: not a file name", h5.display())))?
        .to_string_lossy()
        .into_owned();
    let m = merge(fields)?;
    glissade_core::io::replace_atomically(h5, |tmp, _| write_h5(tmp, &m, fields, scene_hash))?;
    let text = xdmf_text(&m, &fields.times, &h5_name);
    glissade_core::io::write_atomically(&xdmf, |w| {
        w.write_all(text.as_bytes())?;
        Ok::<_, FieldsError>(())
    })?;
    let nodes: usize = fields.interfaces.iter().map(|i| i.coords.len()).sum();
    if nodes > 0 {
        let text = interfaces_xdmf_text(nodes, &fields.times, &h5_name);
        glissade_core::io::write_atomically(&interfaces_xdmf_path(h5), |w| {
            w.write_all(text.as_bytes())?;
            Ok::<_, FieldsError>(())
        })?;
    }
    Ok(xdmf)
}

/// The interfaces' XDMF file beside `h5`: `OUT-interfaces.xdmf`.
pub fn interfaces_xdmf_path(h5: &Path) -> PathBuf {
    let stem = h5.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    h5.with_file_name(format!("{stem}-interfaces.xdmf"))
}

/// The interfaces' nodes and fields (the module documentation's layout), every step.
fn write_interfaces(file: &hdf5::File, f: &FieldOutput) -> Result<(), FieldsError> {
    let steps = f.times.len();
    let bad = |i: &glissade_solver::run::InterfaceOutput| {
        let n = i.coords.len();
        [i.pressure.len(), i.gap.len(), i.slip.len()] != [steps; 3]
            || i.pressure.iter().chain(&i.gap).any(|v| v.len() != n)
            || i.slip.iter().any(|v| v.len() != n)
    };
    if let Some(i) = f.interfaces.iter().find(|i| bad(i)) {
        return Err(FieldsError::Invalid(format!("interface {}: its fields do not fit its nodes or steps", i.name)));
    }
    let m: usize = f.interfaces.iter().map(|i| i.coords.len()).sum();
    if m == 0 {
        return Ok(());
    }
    let group = file.create_group("interfaces")?;
    let coords: Vec<f64> = f.interfaces.iter().flat_map(|i| i.coords.iter().flatten().copied()).collect();
    group.new_dataset::<f64>().shape((m, 3)).create("coordinates")?.write_raw(&coords)?;
    let which: Vec<i64> = f.interfaces.iter().enumerate().flat_map(|(k, i)| vec![k as i64; i.coords.len()]).collect();
    group.new_dataset::<i64>().shape(m).create("interface")?.write_raw(&which)?;
    let names: Vec<VarLenUnicode> = f
        .interfaces
        .iter()
        .map(|i| i.name.parse().map_err(|e| FieldsError::Invalid(format!("interface name {:?}: {e}", i.name))))
        .collect::<Result<_, _>>()?;
    group.new_dataset::<VarLenUnicode>().shape(names.len()).create("names")?.write(&names)?;
    let fields = file.group("fields")?;
    let (pressure, gap, slip) =
        (fields.create_group("contact_pressure")?, fields.create_group("gap")?, fields.create_group("slip")?);
    for step in 0..steps {
        let name = step_name(step);
        let at = |v: fn(&glissade_solver::run::InterfaceOutput, usize) -> Vec<f64>| -> Vec<f64> {
            f.interfaces.iter().flat_map(|i| v(i, step)).collect()
        };
        pressure.new_dataset::<f64>().shape(m).create(name.as_str())?.write_raw(&at(|i, k| i.pressure[k].clone()))?;
        gap.new_dataset::<f64>().shape(m).create(name.as_str())?.write_raw(&at(|i, k| i.gap[k].clone()))?;
        let s = at(|i, k| i.slip[k].iter().flatten().copied().collect());
        slip.new_dataset::<f64>().shape((m, 3)).create(name.as_str())?.write_raw(&s)?;
    }
    Ok(())
}

fn write_h5(path: &Path, m: &Merged, f: &FieldOutput, scene_hash: &str) -> Result<(), FieldsError> {
    let file = hdf5::File::create(path)?;
    {
        let string = |s: &str| -> Result<VarLenUnicode, FieldsError> {
            s.parse().map_err(|e| FieldsError::Invalid(format!("attribute {s:?}: {e}")))
        };
        file.new_attr::<i64>().create("dimension")?.write_scalar(&(m.dimension as i64))?;
        file.new_attr::<VarLenUnicode>().create("scene_hash")?.write_scalar(&string(scene_hash)?)?;
        file.new_attr::<VarLenUnicode>().create("solver_version")?.write_scalar(&string(env!("CARGO_PKG_VERSION"))?)?;

        let mesh = file.create_group("mesh")?;
        mesh.new_dataset::<f64>().shape((m.nodes, 3)).create("coordinates")?.write_raw(&m.coords)?;
        mesh.new_dataset::<i64>()
            .shape((m.elements, m.kind.nodes(m.dimension)))
            .create("topology")?
            .write_raw(&m.topology)?;
        mesh.new_dataset::<i64>().shape(m.elements).create("substructure")?.write_raw(&m.substructure)?;
        file.new_dataset::<f64>().shape(f.times.len()).create("time")?.write_raw(&f.times)?;
        let group = file.create_group("fields")?;
        for (name, field) in [("displacement", &f.history.displacement), ("velocity", &f.history.velocity)] {
            let g = group.create_group(name)?;
            for step in 0..f.times.len() {
                g.new_dataset::<f64>()
                    .shape((m.nodes, 3))
                    .create(step_name(step).as_str())?
                    .write_raw(&m.step(field, step))?;
            }
        }
        let (stress, von_mises) = (group.create_group("stress")?, group.create_group("von_mises")?);
        for step in 0..f.times.len() {
            let (tensor, equivalent) = m.stress(f, step)?;
            let name = step_name(step);
            stress.new_dataset::<f64>().shape((m.elements, 6)).create(name.as_str())?.write_raw(&tensor)?;
            von_mises.new_dataset::<f64>().shape(m.elements).create(name.as_str())?.write_raw(&equivalent)?;
        }
        write_interfaces(&file, f)?;
    }
    file.close()?;
    Ok(())
}

fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

/// XDMF 3: a temporal collection `name` of one uniform grid a step (its time, then what `grid`
/// writes for the step: topology, geometry, attributes), every data item in `h5_name`.
fn temporal_xdmf(name: &str, times: &[f64], h5_name: &str, grid: impl Fn(&str, &Items) -> String) -> String {
    let items = Items { h5: xml_escape(h5_name) };
    let mut x = String::new();
    x.push_str("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n");
    x.push_str("<Xdmf Version=\"3.0\">\n  <Domain>\n");
    let _ = writeln!(x, "    <Grid Name=\"{name}\" GridType=\"Collection\" CollectionType=\"Temporal\">");
    for (step, t) in times.iter().enumerate() {
        let step = step_name(step);
        // writing to a String cannot fail
        let _ = write!(
            x,
            "      <Grid Name=\"step {step}\" GridType=\"Uniform\">\n        <Time Value=\"{t:e}\"/>\n{}      </Grid>\n",
            grid(&step, &items)
        );
    }
    x.push_str("    </Grid>\n  </Domain>\n</Xdmf>\n");
    x
}

/// The HDF5 file's data items, as XDMF names them.
struct Items {
    h5: String,
}

impl Items {
    fn item(&self, dims: &str, kind: &str, path: &str) -> String {
        format!(
            r#"<DataItem Dimensions="{dims}" NumberType="{kind}" Precision="8" Format="HDF">{}:{path}</DataItem>"#,
            self.h5
        )
    }
}

/// The merged mesh's time series: topology, geometry, the nodes' and the elements' fields.
fn xdmf_text(m: &Merged, times: &[f64], h5_name: &str) -> String {
    let (n, e, npe) = (m.nodes, m.elements, m.kind.nodes(m.dimension));
    temporal_xdmf("glissade", times, h5_name, |name, i| {
        format!(
            r#"        <Topology {topo} NumberOfElements="{e}">
          {topology}
        </Topology>
        <Geometry GeometryType="XYZ">
          {coordinates}
        </Geometry>
        <Attribute Name="substructure" AttributeType="Scalar" Center="Cell">
          {substructure}
        </Attribute>
        <Attribute Name="displacement" AttributeType="Vector" Center="Node">
          {displacement}
        </Attribute>
        <Attribute Name="velocity" AttributeType="Vector" Center="Node">
          {velocity}
        </Attribute>
        <Attribute Name="stress" AttributeType="Tensor6" Center="Cell">
          {stress}
        </Attribute>
        <Attribute Name="von_mises" AttributeType="Scalar" Center="Cell">
          {von_mises}
        </Attribute>
"#,
            topo = xdmf_topology(m.dimension, m.kind),
            topology = i.item(&format!("{e} {npe}"), "Int", "/mesh/topology"),
            coordinates = i.item(&format!("{n} 3"), "Float", "/mesh/coordinates"),
            substructure = i.item(&format!("{e}"), "Int", "/mesh/substructure"),
            displacement = i.item(&format!("{n} 3"), "Float", &format!("/fields/displacement/{name}")),
            velocity = i.item(&format!("{n} 3"), "Float", &format!("/fields/velocity/{name}")),
            stress = i.item(&format!("{e} 6"), "Float", &format!("/fields/stress/{name}")),
            von_mises = i.item(&format!("{e}"), "Float", &format!("/fields/von_mises/{name}")),
        )
    })
}

/// The interfaces' nodes' time series: vertices and their fields.
fn interfaces_xdmf_text(nodes: usize, times: &[f64], h5_name: &str) -> String {
    temporal_xdmf("interfaces", times, h5_name, |name, i| {
        format!(
            r#"        <Topology TopologyType="Polyvertex" NumberOfElements="{nodes}" NodesPerElement="1"/>
        <Geometry GeometryType="XYZ">
          {coordinates}
        </Geometry>
        <Attribute Name="interface" AttributeType="Scalar" Center="Node">
          {interface}
        </Attribute>
        <Attribute Name="contact_pressure" AttributeType="Scalar" Center="Node">
          {pressure}
        </Attribute>
        <Attribute Name="gap" AttributeType="Scalar" Center="Node">
          {gap}
        </Attribute>
        <Attribute Name="slip" AttributeType="Vector" Center="Node">
          {slip}
        </Attribute>
"#,
            coordinates = i.item(&format!("{nodes} 3"), "Float", "/interfaces/coordinates"),
            interface = i.item(&format!("{nodes}"), "Int", "/interfaces/interface"),
            pressure = i.item(&format!("{nodes}"), "Float", &format!("/fields/contact_pressure/{name}")),
            gap = i.item(&format!("{nodes}"), "Float", &format!("/fields/gap/{name}")),
            slip = i.item(&format!("{nodes} 3"), "Float", &format!("/fields/slip/{name}")),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glissade_solver::latin::FieldHistory;
    use glissade_solver::run::SubstructureMesh;

    /// Two 2D substructures side by side, one quad each, sharing the nodes at x = 1.
    fn sample() -> FieldOutput {
        let square = |x0: f64| SubstructureMesh {
            dimension: 2,
            kind: ElementKind::Tensor,
            // tensor order: (0,0), (1,0), (0,1), (1,1)
            coords: vec![[x0, 0.0, 0.0], [x0 + 1.0, 0.0, 0.0], [x0, 1.0, 0.0], [x0 + 1.0, 1.0, 0.0]],
            connectivity: vec![0, 1, 2, 3],
            material: element::Material { young: 1e3, poisson: 0.25, density: 1.0 },
        };
        let times = vec![0.0, 0.5, 1.0];
        // value = 1000 s + 100 step + dof, so every entry says where it belongs
        let field = |scale: f64| -> Vec<Vec<Vec<f64>>> {
            (0..2)
                .map(|s| {
                    (0..times.len())
                        .map(|n| (0..8).map(|dof| scale * (1000 * s + 100 * n + dof) as f64).collect())
                        .collect()
                })
                .collect()
        };
        // the glued line x = 1 between them: its two nodes, pressed at 5 Pa then opening
        let interface = glissade_solver::run::InterfaceOutput {
            name: "glue".into(),
            coords: vec![[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
            pressure: (0..times.len()).map(|k| vec![5.0 - k as f64, 5.0 - k as f64]).collect(),
            gap: (0..times.len()).map(|k| vec![0.0, 1e-6 * k as f64]).collect(),
            slip: (0..times.len()).map(|k| vec![[0.0, 2e-6 * k as f64, 0.0]; 2]).collect(),
        };
        FieldOutput {
            meshes: vec![square(0.0), square(1.0)],
            history: FieldHistory { displacement: field(1.0), velocity: field(-1.0) },
            times,
            interfaces: vec![interface],
        }
    }

    #[test]
    fn h5_and_xdmf_of_a_2d_result() {
        let dir = tempfile::tempdir().unwrap();
        let h5 = dir.path().join("out.h5");
        let xdmf = write(&h5, &sample(), "abc").unwrap();
        assert_eq!(xdmf, dir.path().join("out.xdmf"));

        let file = hdf5::File::open(&h5).unwrap();
        let coords = file.dataset("mesh/coordinates").unwrap();
        assert_eq!(coords.shape(), vec![8, 3]);
        let c: Vec<f64> = coords.read_raw().unwrap();
        assert_eq!(&c[5 * 3..6 * 3], &[2.0, 0.0, 0.0]);
        let topo = file.dataset("mesh/topology").unwrap();
        assert_eq!(topo.shape(), vec![2, 4]);
        // counter-clockwise VTK order, second substructure's nodes after the first's
        assert_eq!(topo.read_raw::<i64>().unwrap(), vec![0, 1, 3, 2, 4, 5, 7, 6]);
        assert_eq!(file.dataset("mesh/substructure").unwrap().read_raw::<i64>().unwrap(), vec![0, 1]);
        assert_eq!(file.dataset("time").unwrap().read_raw::<f64>().unwrap(), vec![0.0, 0.5, 1.0]);
        let names = file.group("fields/displacement").unwrap().member_names().unwrap();
        assert_eq!(names, vec!["000000", "000001", "000002"]);
        let u = file.dataset("fields/displacement/000002").unwrap();
        assert_eq!(u.shape(), vec![8, 3]);
        let u: Vec<f64> = u.read_raw().unwrap();
        // merged node 5 = substructure 1, local node 1: dofs 2, 3 at step 2; z padded with 0
        assert_eq!(&u[5 * 3..6 * 3], &[1202.0, 1203.0, 0.0]);
        let v: Vec<f64> = file.dataset("fields/velocity/000001").unwrap().read_raw().unwrap();
        assert_eq!(&v[0..3], &[-100.0, -101.0, 0.0]);
        let hash: VarLenUnicode = file.attr("scene_hash").unwrap().read_scalar().unwrap();
        assert_eq!(hash.as_str(), "abc");

        let text = std::fs::read_to_string(&xdmf).unwrap();
        assert!(text.starts_with("<?xml"));
        assert_eq!(text.matches("<Grid Name=\"step ").count(), 3);
        assert!(text.contains(r#"TopologyType="Quadrilateral" NumberOfElements="2""#));
        assert!(text.contains(
            r#"<DataItem Dimensions="2 4" NumberType="Int" Precision="8" Format="HDF">out.h5:/mesh/topology</DataItem>"#
        ));
        assert!(text.contains(
            r#"<DataItem Dimensions="8 3" NumberType="Float" Precision="8" Format="HDF">out.h5:/fields/velocity/000002</DataItem>"#
        ));
        assert!(text.contains(r#"<Time Value="5e-1"/>"#));
        assert!(text.contains(
            r#"<DataItem Dimensions="2 6" NumberType="Float" Precision="8" Format="HDF">out.h5:/fields/stress/000001</DataItem>"#
        ));
        assert!(text.contains(r#"Name="von_mises" AttributeType="Scalar" Center="Cell""#));
        assert_well_formed(&text);
        // the interface: its nodes and fields, and its own XDMF file
        let ic: Vec<f64> = file.dataset("interfaces/coordinates").unwrap().read_raw().unwrap();
        assert_eq!(ic, [1.0, 0.0, 0.0, 1.0, 1.0, 0.0]);
        let names: Vec<VarLenUnicode> = file.dataset("interfaces/names").unwrap().read_raw().unwrap();
        assert_eq!(names[0].as_str(), "glue");
        let p: Vec<f64> = file.dataset("fields/contact_pressure/000002").unwrap().read_raw().unwrap();
        assert_eq!(p, [3.0, 3.0]);
        let g: Vec<f64> = file.dataset("fields/gap/000001").unwrap().read_raw().unwrap();
        assert_eq!(g, [0.0, 1e-6]);
        let sl: Vec<f64> = file.dataset("fields/slip/000002").unwrap().read_raw().unwrap();
        assert_eq!(sl, [0.0, 4e-6, 0.0, 0.0, 4e-6, 0.0]);
        let itext = std::fs::read_to_string(dir.path().join("out-interfaces.xdmf")).unwrap();
        assert!(itext.contains(r#"TopologyType="Polyvertex" NumberOfElements="2""#), "{itext}");
        assert!(itext.contains("out.h5:/fields/gap/000002"), "{itext}");
        assert_well_formed(&itext);
        // only the three files are left
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
    }

    /// Tags balance (enough of an XML check for text we generate ourselves).
    fn assert_well_formed(text: &str) {
        let mut open: Vec<&str> = Vec::new();
        let mut rest = text;
        while let Some(i) = rest.find('<') {
            let j = rest[i..].find('>').expect("unclosed tag") + i;
            let tag = &rest[i + 1..j];
            rest = &rest[j + 1..];
            if tag.starts_with('?') || tag.ends_with('/') {
                continue;
            }
            let name = tag.trim_start_matches('/').split_whitespace().next().unwrap();
            if tag.starts_with('/') {
                assert_eq!(open.pop(), Some(name), "mismatched </{name}>");
            } else {
                open.push(name);
            }
        }
        assert!(open.is_empty(), "unclosed: {open:?}");
    }

    /// The stress of a uniform stretch, u_x = 0.01 x, written per element at each step: plane
    /// strain under E = 1000, nu = 0.25 gives xx = (lambda + 2 mu) 0.01 = 12, yy = zz =
    /// lambda 0.01 = 4, von Mises 8 (the sample's made-up displacements in the other steps).
    #[test]
    fn the_stress_of_each_element_is_written_beside_the_displacements() {
        let dir = tempfile::tempdir().unwrap();
        let h5 = dir.path().join("out.h5");
        let mut f = sample();
        for (s, mesh) in f.meshes.iter().enumerate() {
            f.history.displacement[s][1] = mesh.coords.iter().flat_map(|p| [0.01 * p[0], 0.0]).collect();
        }
        write(&h5, &f, "abc").unwrap();
        let file = hdf5::File::open(&h5).unwrap();
        let stress: Vec<f64> = file.dataset("fields/stress/000001").unwrap().read_raw().unwrap();
        let expected = [12.0, 0.0, 0.0, 4.0, 0.0, 4.0];
        for el in stress.chunks_exact(6) {
            assert!(el.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-9), "{el:?}");
        }
        let vm: Vec<f64> = file.dataset("fields/von_mises/000001").unwrap().read_raw().unwrap();
        assert!(vm.len() == 2 && vm.iter().all(|v| (v - 8.0).abs() < 1e-9), "{vm:?}");
    }

    #[test]
    fn inconsistent_fields_are_refused_and_leave_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let h5 = dir.path().join("out.h5");
        let mut f = sample();
        f.history.velocity[1][2].pop();
        let err = write(&h5, &f, "abc").unwrap_err();
        assert!(err.to_string().contains("substructure 1"), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let err = write(&dir.path().join("out.xdmf"), &sample(), "abc").unwrap_err();
        assert!(err.to_string().contains(".xdmf"), "{err}");
    }

    #[test]
    fn vtk_order_of_a_hexahedron() {
        // tensor index bits (x, y, z) -> VTK: bottom face counter-clockwise, then the top face
        let bits = |i: usize| (i & 1, (i >> 1) & 1, (i >> 2) & 1);
        let vtk: Vec<_> = vtk_order(3).iter().map(|&i| bits(i)).collect();
        assert_eq!(vtk, vec![(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]);
    }
}
