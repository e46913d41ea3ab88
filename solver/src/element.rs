//! Isoparametric Lagrange elements of order 1, generic over the dimension `D`:
//! 2-node bars (D = 1), 4-node quads (D = 2, plane strain), 8-node hexahedra (D = 3), and
//! linear simplices (the 4-node tetrahedra of Gmsh meshes).
//!
//! Tensor elements' local nodes are in tensor order: bit `d` of the local index is the node's
//! side along reference axis `d` (0 -> xi_d = -1, 1 -> xi_d = +1). 2-point Gauss integration,
//! the volumetric part of the stiffness at one point (docs/method.md 2). Simplices are
//! integrated exactly (constant strain).

/// The element family of a mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementKind {
    /// multilinear, `2^D` nodes in tensor order; face `2 axis + side` is normal to `axis`
    Tensor,
    /// linear, `D + 1` nodes (tetrahedra in 3D); face `i` is the one opposite node `i`
    Simplex,
}

impl ElementKind {
    pub const fn nodes(self, dim: usize) -> usize {
        match self {
            ElementKind::Tensor => nodes_per_element(dim),
            ElementKind::Simplex => dim + 1,
        }
    }

    pub const fn faces(self, dim: usize) -> usize {
        match self {
            ElementKind::Tensor => 2 * dim,
            ElementKind::Simplex => dim + 1,
        }
    }

    /// Local nodes of face `local`: in the face's tensor order (tensor elements), in
    /// increasing order (simplices).
    pub fn face_local_nodes(self, dim: usize, local: usize) -> Vec<usize> {
        match self {
            ElementKind::Tensor => face_local_nodes(dim, local / 2, local % 2),
            ElementKind::Simplex => (0..=dim).filter(|&a| a != local).collect(),
        }
    }

    /// Stiffness and consistent mass of one element (see [`element_matrices`]).
    pub fn matrices<const D: usize>(self, x: &[[f64; D]], mat: &Material) -> Result<(Vec<f64>, Vec<f64>), f64> {
        match self {
            ElementKind::Tensor => element_matrices(x, mat),
            ElementKind::Simplex => simplex_matrices(x, mat),
        }
    }
}

/// Isotropic linear elastic material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Young's modulus E (Pa)
    pub young: f64,
    /// Poisson's ratio nu
    pub poisson: f64,
    /// density rho (kg/m^3)
    pub density: f64,
}

impl Material {
    /// Lamé constants (lambda, mu) of the dimension: uniaxial stress for bars (lambda = 0,
    /// 2 mu = E), plane strain in 2D, full 3D otherwise.
    pub fn lame(&self, dim: usize) -> (f64, f64) {
        if dim == 1 {
            return (0.0, 0.5 * self.young);
        }
        let (e, nu) = (self.young, self.poisson);
        (e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), e / (2.0 * (1.0 + nu)))
    }

    /// Bar impedance sqrt(rho E): the search direction k0 of docs/method.md 3.
    pub fn impedance(&self) -> f64 {
        (self.density * self.young).sqrt()
    }

    /// Dilatational (bar) wave speed sqrt(E / rho).
    pub fn bar_wave_speed(&self) -> f64 {
        (self.young / self.density).sqrt()
    }
}

const GAUSS: [f64; 2] = [-0.577_350_269_189_625_8, 0.577_350_269_189_625_8];

/// Number of nodes of the D-dimensional element.
pub const fn nodes_per_element(dim: usize) -> usize {
    1 << dim
}

/// Gauss points (reference coordinates, weight) of a `k`-dimensional reference cube.
pub fn gauss_points(k: usize) -> Vec<(Vec<f64>, f64)> {
    (0..1usize << k).map(|g| ((0..k).map(|d| GAUSS[(g >> d) & 1]).collect(), 1.0)).collect()
}

/// Shape functions of the `k`-dimensional multilinear element at `xi` and their reference
/// derivatives `dn[a][d]`.
pub fn shape(xi: &[f64]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let k = xi.len();
    let nn = 1usize << k;
    let mut n = vec![1.0; nn];
    let mut dn = vec![vec![1.0; k]; nn];
    for a in 0..nn {
        for d in 0..k {
            let s = if (a >> d) & 1 == 1 { 1.0 } else { -1.0 };
            let f = 0.5 * (1.0 + s * xi[d]);
            n[a] *= f;
            for (e, dne) in dn[a].iter_mut().enumerate() {
                *dne *= if e == d { 0.5 * s } else { f };
            }
        }
    }
    (n, dn)
}

/// Determinant and inverse of a D x D matrix (D <= 3), padded with the identity.
fn det_inv<const D: usize>(j: &[[f64; D]; D]) -> (f64, [[f64; D]; D]) {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for i in 0..D {
        for k in 0..D {
            m[i][k] = j[i][k];
        }
    }
    let c = |r: usize, s: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (s1, s2) = ((s + 1) % 3, (s + 2) % 3);
        m[r1][s1] * m[r2][s2] - m[r1][s2] * m[r2][s1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let mut inv = [[0.0; D]; D];
    for i in 0..D {
        for k in 0..D {
            inv[i][k] = c(k, i) / det;
        }
    }
    (det, inv)
}

/// A multilinear element at one reference point.
struct PointValues<const D: usize> {
    /// shape functions
    n: Vec<f64>,
    /// physical gradients `g[a][i]`
    g: Vec<[f64; D]>,
    /// Jacobian determinant
    det: f64,
}

/// The element with node coordinates `x` at reference point `xi`; the determinant is the error
/// when not positive.
fn shape_gradients<const D: usize>(x: &[[f64; D]], xi: &[f64]) -> Result<PointValues<D>, f64> {
    let nn = nodes_per_element(D);
    let (n, dn) = shape(xi);
    // J[i][d] = dx_i / dxi_d
    let mut jac = [[0.0; D]; D];
    for a in 0..nn {
        for i in 0..D {
            for d in 0..D {
                jac[i][d] += x[a][i] * dn[a][d];
            }
        }
    }
    let (det, inv) = det_inv(&jac);
    if det <= 0.0 || !det.is_finite() {
        return Err(det);
    }
    // physical gradients g[a][i] = sum_d dn[a][d] * (J^-1)[d][i]
    let g = (0..nn)
        .map(|a| {
            let mut gi = [0.0; D];
            for (i, gii) in gi.iter_mut().enumerate() {
                for d in 0..D {
                    *gii += dn[a][d] * inv[d][i];
                }
            }
            gi
        })
        .collect();
    Ok(PointValues { n, g, det })
}

/// Consistent stiffness and mass matrices of one element (dense, `(a*D + i, b*D + j)` order),
/// from its node coordinates in tensor order. Selective reduced integration: the shear part
/// (mu) at the 2^D Gauss points, the volumetric part (lambda) at the centre, so that the element
/// does not lock as nu approaches 1/2 (fully integrated, three-blocks-tiny at nu = 0.499 took
/// 4718 iterations, 169 with this; docs/performance.md, "Locking, and the static search
/// direction"). Constant strains are exact on quadrilaterals and parallelepipeds; on a
/// distorted hexahedron the centre point approximates the mean dilatation.
pub fn element_matrices<const D: usize>(x: &[[f64; D]], mat: &Material) -> Result<(Vec<f64>, Vec<f64>), f64> {
    let nn = nodes_per_element(D);
    let nd = nn * D;
    let (lambda, mu) = mat.lame(D);
    let mut k = vec![0.0; nd * nd];
    let mut m = vec![0.0; nd * nd];
    for (xi, w) in gauss_points(D) {
        let PointValues { n, g, det } = shape_gradients(x, &xi)?;
        let wd = w * det;
        add_stiffness(&mut k, &g, wd, 0.0, mu);
        for a in 0..nn {
            for b in 0..nn {
                for i in 0..D {
                    m[(a * D + i) * nd + b * D + i] += wd * mat.density * n[a] * n[b];
                }
            }
        }
    }
    // one point of weight 2^D, the reference cube's volume
    let PointValues { g, det, .. } = shape_gradients(x, &[0.0; D])?;
    add_stiffness(&mut k, &g, nn as f64 * det, lambda, 0.0);
    Ok((k, m))
}

/// Adds `wd` x the isotropic stiffness density of the physical shape-function gradients `g`.
fn add_stiffness<const D: usize>(k: &mut [f64], g: &[[f64; D]], wd: f64, lambda: f64, mu: f64) {
    let nd = g.len() * D;
    for a in 0..g.len() {
        for b in 0..g.len() {
            let gab: f64 = (0..D).map(|l| g[a][l] * g[b][l]).sum();
            for i in 0..D {
                for j in 0..D {
                    let mut v = lambda * g[a][i] * g[b][j] + mu * g[a][j] * g[b][i];
                    if i == j {
                        v += mu * gab;
                    }
                    k[(a * D + i) * nd + b * D + j] += wd * v;
                }
            }
        }
    }
}

/// Stiffness and consistent mass of a linear simplex (`D + 1` nodes, any order of positive
/// volume): constant strain, and the exact mass rho V (1 + delta_ab) / ((D + 1)(D + 2)).
pub fn simplex_matrices<const D: usize>(x: &[[f64; D]], mat: &Material) -> Result<(Vec<f64>, Vec<f64>), f64> {
    let nn = D + 1;
    let nd = nn * D;
    let (lambda, mu) = mat.lame(D);
    let (volume, g) = simplex_gradients(x)?;
    let mut k = vec![0.0; nd * nd];
    add_stiffness(&mut k, &g, volume, lambda, mu);
    let mut m = vec![0.0; nd * nd];
    let unit = mat.density * volume / ((D + 1) * (D + 2)) as f64;
    for a in 0..nn {
        for b in 0..nn {
            for i in 0..D {
                m[(a * D + i) * nd + b * D + i] = if a == b { 2.0 * unit } else { unit };
            }
        }
    }
    Ok((k, m))
}

/// A linear simplex's volume and its shape functions' (constant) physical gradients; the
/// determinant is the error when not positive.
fn simplex_gradients<const D: usize>(x: &[[f64; D]]) -> Result<(f64, Vec<[f64; D]>), f64> {
    let nn = D + 1;
    // J[i][d] = dx_i / dxi_d = x_{d+1} - x_0; N_0 = 1 - sum xi, N_{d+1} = xi_d
    let mut jac = [[0.0; D]; D];
    for i in 0..D {
        for d in 0..D {
            jac[i][d] = x[d + 1][i] - x[0][i];
        }
    }
    let (det, inv) = det_inv(&jac);
    if det <= 0.0 || !det.is_finite() {
        return Err(det);
    }
    let volume = det / (1..=D).product::<usize>() as f64;
    let g: Vec<[f64; D]> = (0..nn)
        .map(|a| {
            let mut gi = [0.0; D];
            for (i, gii) in gi.iter_mut().enumerate() {
                *gii = match a {
                    0 => -(0..D).map(|d| inv[d][i]).sum::<f64>(),
                    _ => inv[a - 1][i],
                };
            }
            gi
        })
        .collect();
    Ok((volume, g))
}

/// The stress at an element's centre from its nodes' displacements `u` (Voigt order xx, yy,
/// zz, xy, yz, zx; Pa): what ParaView shows of each element. Plane strain in 2D (zz = lambda
/// (exx + eyy)), a bar's axial stress E exx in 1D; the determinant is the error where the
/// element is not valid.
pub fn centre_stress<const D: usize>(
    kind: ElementKind,
    x: &[[f64; D]],
    u: &[[f64; D]],
    mat: &Material,
) -> Result<[f64; 6], f64> {
    let g = match kind {
        ElementKind::Tensor => shape_gradients(x, &[0.0; D])?.g,
        ElementKind::Simplex => simplex_gradients(x)?.1,
    };
    let mut grad = [[0.0; D]; D];
    for (ga, ua) in g.iter().zip(u) {
        for i in 0..D {
            for j in 0..D {
                grad[i][j] += ua[i] * ga[j];
            }
        }
    }
    let strain = |i: usize, j: usize| if i < D && j < D { 0.5 * (grad[i][j] + grad[j][i]) } else { 0.0 };
    let (lambda, mu) = mat.lame(D);
    let trace: f64 = (0..D).map(|i| strain(i, i)).sum();
    let normal = |i: usize| match (i < D, D) {
        (true, _) => lambda * trace + 2.0 * mu * strain(i, i),
        // plane strain: the out-of-plane stress that holds ezz = 0
        (false, 2) => lambda * trace,
        (false, _) => 0.0,
    };
    Ok([normal(0), normal(1), normal(2), 2.0 * mu * strain(0, 1), 2.0 * mu * strain(1, 2), 2.0 * mu * strain(2, 0)])
}

/// The von Mises equivalent stress of a stress in Voigt order.
pub fn von_mises(s: &[f64; 6]) -> f64 {
    let [xx, yy, zz, xy, yz, zx] = *s;
    (0.5 * ((xx - yy).powi(2) + (yy - zz).powi(2) + (zz - xx).powi(2)) + 3.0 * (xy * xy + yz * yz + zx * zx)).sqrt()
}

/// Local nodes of the face of the reference element normal to axis `axis` on side `side`,
/// in the tensor order of the (D-1)-dimensional face element.
pub fn face_local_nodes(dim: usize, axis: usize, side: usize) -> Vec<usize> {
    (0..nodes_per_element(dim)).filter(|a| (a >> axis) & 1 == side).collect()
}

/// Integral of each face shape function over a face (lumped interface "mass" M_Gamma:
/// the nodal area), and the face's unit normal at its centre pointing away from `inside`.
/// Faces of tensor elements come in tensor order; a face of 3 nodes in 3D is a triangle.
pub fn face_area_and_normal<const D: usize>(x: &[[f64; D]], inside: [f64; D]) -> (Vec<f64>, [f64; D]) {
    if D == 3 && x.len() == 3 {
        return triangle_area_and_normal(x, inside);
    }
    let k = D - 1;
    let nn = 1usize << k;
    let mut area = vec![0.0; nn];
    // tangents at the face centre, for the normal
    let (_, dn0) = shape(&vec![0.0; k]);
    let tangent = |dn: &Vec<Vec<f64>>, d: usize| {
        let mut t = [0.0; D];
        for a in 0..nn {
            for i in 0..D {
                t[i] += x[a][i] * dn[a][d];
            }
        }
        t
    };
    for (xi, w) in gauss_points(k) {
        let (n, dn) = shape(&xi);
        let jac = match k {
            0 => 1.0,
            1 => norm(&tangent(&dn, 0)),
            _ => norm(&cross(&tangent(&dn, 0), &tangent(&dn, 1))),
        };
        for a in 0..nn {
            area[a] += w * jac * n[a];
        }
    }
    let mut normal = match k {
        0 => [1.0; D],
        1 => {
            let t = tangent(&dn0, 0);
            let mut nrm = [0.0; D];
            nrm[0] = t[1];
            nrm[1] = -t[0];
            nrm
        }
        _ => cross(&tangent(&dn0, 0), &tangent(&dn0, 1)),
    };
    let centre: Vec<f64> = (0..D).map(|i| x.iter().map(|p| p[i]).sum::<f64>() / nn as f64).collect();
    let outward: f64 = (0..D).map(|i| normal[i] * (centre[i] - inside[i])).sum();
    let len = norm(&normal);
    for v in normal.iter_mut() {
        *v *= outward.signum() / len;
    }
    (area, normal)
}

/// A flat triangle: a third of its area per node, its normal away from `inside`.
fn triangle_area_and_normal<const D: usize>(x: &[[f64; D]], inside: [f64; D]) -> (Vec<f64>, [f64; D]) {
    let edge = |a: usize| {
        let mut t = [0.0; D];
        for i in 0..D {
            t[i] = x[a][i] - x[0][i];
        }
        t
    };
    let mut normal = cross(&edge(1), &edge(2));
    let len = norm(&normal);
    let outward: f64 = (0..D).map(|i| normal[i] * ((x[0][i] + x[1][i] + x[2][i]) / 3.0 - inside[i])).sum();
    for v in normal.iter_mut() {
        *v *= outward.signum() / len;
    }
    (vec![len / 6.0; 3], normal)
}

fn norm<const D: usize>(v: &[f64; D]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Cross product, defined for D = 3 (the only dimension with 2D faces).
fn cross<const D: usize>(a: &[f64; D], b: &[f64; D]) -> [f64; D] {
    let mut c = [0.0; D];
    if D == 3 {
        c[0] = a[1] * b[2] - a[2] * b[1];
        c[1] = a[2] * b[0] - a[0] * b[2];
        c[2] = a[0] * b[1] - a[1] * b[0];
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box<const D: usize>(h: [f64; D]) -> Vec<[f64; D]> {
        (0..nodes_per_element(D))
            .map(|a| {
                let mut p = [0.0; D];
                for d in 0..D {
                    p[d] = if (a >> d) & 1 == 1 { h[d] } else { 0.0 };
                }
                p
            })
            .collect()
    }

    /// Total mass = rho V and rigid translations produce no force, in every dimension.
    fn check_mass_and_rigid_modes<const D: usize>(h: [f64; D]) {
        let mat = Material { young: 2.0e11, poisson: 0.3, density: 7800.0 };
        let x = unit_box(h);
        let (k, m) = element_matrices(&x, &mat).unwrap();
        let nd = nodes_per_element(D) * D;
        let vol: f64 = h.iter().product();
        for i in 0..D {
            let t: Vec<f64> = (0..nd).map(|r| if r % D == i { 1.0 } else { 0.0 }).collect();
            let total: f64 = (0..nd).map(|r| (0..nd).map(|c| t[r] * m[r * nd + c] * t[c]).sum::<f64>()).sum();
            assert!((total - mat.density * vol).abs() < 1e-12 * mat.density * vol);
            let kmax = k.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            for r in 0..nd {
                let f: f64 = (0..nd).map(|c| k[r * nd + c] * t[c]).sum();
                assert!(f.abs() < 1e-13 * kmax, "rigid translation gives force {f} (max entry {kmax})");
            }
        }
    }

    #[test]
    fn mass_and_rigid_modes_all_dimensions() {
        check_mass_and_rigid_modes::<1>([0.3]);
        check_mass_and_rigid_modes::<2>([0.3, 0.2]);
        check_mass_and_rigid_modes::<3>([0.3, 0.2, 0.1]);
    }

    #[test]
    fn bar_stiffness_is_ea_over_l() {
        let mat = Material { young: 7.0, poisson: 0.25, density: 1.0 };
        let (k, m) = element_matrices::<1>(&[[0.0], [2.0]], &mat).unwrap();
        assert!((k[0] - 3.5).abs() < 1e-14 && (k[1] + 3.5).abs() < 1e-14);
        // consistent bar mass rho L / 6 [2 1; 1 2]
        assert!((m[0] - 2.0 / 3.0).abs() < 1e-14 && (m[1] - 1.0 / 3.0).abs() < 1e-14);
    }

    #[test]
    fn uniaxial_strain_energy_matches_3d_with_nu_zero() {
        // Stretch a hexahedron along x by strain e: energy 1/2 E e^2 V when nu = 0.
        let mat = Material { young: 3.0, poisson: 0.0, density: 1.0 };
        let h = [2.0, 0.5, 0.25];
        let x = unit_box(h);
        let (k, _) = element_matrices(&x, &mat).unwrap();
        let e = 0.01;
        let u: Vec<f64> = (0..24).map(|r| if r % 3 == 0 { e * x[r / 3][0] } else { 0.0 }).collect();
        let energy: f64 = 0.5 * (0..24).map(|r| (0..24).map(|c| u[r] * k[r * 24 + c] * u[c]).sum::<f64>()).sum::<f64>();
        let exact = 0.5 * mat.young * e * e * h.iter().product::<f64>();
        assert!((energy - exact).abs() < 1e-13, "{energy} vs {exact}");
    }

    fn energy(k: &[f64], u: &[f64]) -> f64 {
        let nd = u.len();
        0.5 * (0..nd).map(|r| (0..nd).map(|c| u[r] * k[r * nd + c] * u[c]).sum::<f64>()).sum::<f64>()
    }

    /// Selective reduced integration: a uniform dilatation e (every normal strain e) stores the
    /// exact energy 1/2 (D lambda + 2 mu) D e^2 V, while the bending mode u_x = x y (about the
    /// centre) stores an energy that stays finite as nu -> 1/2 (fully integrated, its volumetric
    /// part grows with lambda: the element locks).
    #[test]
    fn dilatation_is_exact_and_bending_does_not_lock() {
        let h = [0.3, 0.2, 0.1];
        let x = unit_box(h);
        let vol: f64 = h.iter().product();
        let e = 1e-3;
        let dilatation: Vec<f64> = (0..24).map(|r| e * x[r / 3][r % 3]).collect();
        // about the centre: (x - h_x / 2)(y - h_y / 2), no uniform strain in it
        let bending: Vec<f64> = (0..24)
            .map(|r| if r % 3 == 0 { (x[r / 3][0] - 0.5 * h[0]) * (x[r / 3][1] - 0.5 * h[1]) } else { 0.0 })
            .collect();
        let mut bending_energy = Vec::new();
        for nu in [0.3, 0.49, 0.4999] {
            let mat = Material { young: 2.0e11, poisson: nu, density: 7800.0 };
            let (k, _) = element_matrices(&x, &mat).unwrap();
            let (lambda, mu) = mat.lame(3);
            let exact = 0.5 * (3.0 * lambda + 2.0 * mu) * 3.0 * e * e * vol;
            let got = energy(&k, &dilatation);
            assert!((got - exact).abs() < 1e-12 * exact, "nu {nu}: dilatation energy {got} vs {exact}");
            bending_energy.push(energy(&k, &bending));
        }
        // lambda grows 1 / (1 - 2 nu): x 36 from 0.49 to 0.4999; mu falls by 13 %
        let growth = bending_energy[2] / bending_energy[1];
        assert!(growth < 1.0, "bending energy grows {growth} x from nu = 0.49 to 0.4999: the element locks");
        assert!(bending_energy[2] > 0.5 * bending_energy[0], "bending keeps its shear stiffness");
    }

    /// A tetrahedron: mass rho V, no force from rigid translations, the uniaxial strain
    /// energy 1/2 E e^2 V at nu = 0, whichever node comes first.
    #[test]
    fn tetrahedron_mass_rigid_modes_and_energy() {
        let mat = Material { young: 3.0, poisson: 0.0, density: 2.0 };
        let x = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]];
        let vol = 2.0 * 1.0 * 0.5 / 6.0;
        for shift in 0..4 {
            // an even permutation keeps the orientation
            let xs: Vec<[f64; 3]> = match shift {
                0 => x.to_vec(),
                1 => vec![x[1], x[2], x[0], x[3]],
                2 => vec![x[2], x[0], x[1], x[3]],
                _ => vec![x[3], x[1], x[0], x[2]],
            };
            let (k, m) = ElementKind::Simplex.matrices(&xs, &mat).unwrap();
            let total: f64 = (0..12)
                .flat_map(|r| (0..12).map(move |c| (r, c)))
                .filter(|(r, c)| r % 3 == 0 && c % 3 == 0)
                .map(|(r, c)| m[r * 12 + c])
                .sum();
            assert!((total - mat.density * vol).abs() < 1e-14, "{total}");
            for r in 0..12 {
                let f: f64 = (0..12).filter(|c| c % 3 == 1).map(|c| k[r * 12 + c]).sum();
                assert!(f.abs() < 1e-14, "rigid translation gives force {f}");
            }
            let e = 0.01;
            let u: Vec<f64> = (0..12).map(|r| if r % 3 == 0 { e * xs[r / 3][0] } else { 0.0 }).collect();
            let energy = 0.5 * (0..12).map(|r| (0..12).map(|c| u[r] * k[r * 12 + c] * u[c]).sum::<f64>()).sum::<f64>();
            assert!((energy - 0.5 * mat.young * e * e * vol).abs() < 1e-15, "{energy}");
        }
        // an inverted tetrahedron is refused
        assert!(simplex_matrices(&[x[1], x[0], x[2], x[3]], &mat).is_err());
    }

    /// A uniform strain, as displacements u = E x at the nodes: every element's centre gives
    /// Hooke's stress exactly (hexahedron, distorted quad, tetrahedron, bar), and von Mises of a
    /// uniaxial stress is its magnitude.
    #[test]
    fn the_stress_at_an_elements_centre_is_hookes_of_a_uniform_strain() {
        let steel = Material { young: 210e9, poisson: 0.3, density: 7800.0 };
        let e = [[1e-3, 2e-4, -5e-4], [2e-4, -3e-4, 1e-4], [-5e-4, 1e-4, 4e-4]];
        let hooke = |d: usize| -> [f64; 6] {
            let (l, m) = steel.lame(d);
            let tr: f64 = (0..d).map(|i| e[i][i]).sum();
            let n = |i: usize| {
                if i < d {
                    l * tr + 2.0 * m * e[i][i]
                } else if d == 2 {
                    l * tr
                } else {
                    0.0
                }
            };
            let t = |i: usize, j: usize| if i < d && j < d { 2.0 * m * e[i][j] } else { 0.0 };
            [n(0), n(1), n(2), t(0, 1), t(1, 2), t(2, 0)]
        };
        fn displaced<const D: usize>(x: &[[f64; D]], e: &[[f64; 3]; 3]) -> Vec<[f64; D]> {
            x.iter().map(|p| std::array::from_fn(|i| (0..D).map(|j| e[i][j] * p[j]).sum())).collect()
        }
        let close = |a: [f64; 6], b: [f64; 6]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6 * 1e8);
        let hex = unit_box([0.02, 0.01, 0.03]);
        let s = centre_stress(ElementKind::Tensor, &hex, &displaced(&hex, &e), &steel).unwrap();
        assert!(close(s, hooke(3)), "{s:?} {:?}", hooke(3));
        let quad = [[0.0, 0.0], [0.012, 0.001], [-0.002, 0.01], [0.011, 0.013]];
        let s = centre_stress(ElementKind::Tensor, &quad, &displaced(&quad, &e), &steel).unwrap();
        assert!(close(s, hooke(2)), "{s:?} {:?}", hooke(2));
        let tet = [[0.0, 0.0, 0.0], [0.01, 0.0, 0.001], [0.002, 0.012, 0.0], [0.001, 0.002, 0.009]];
        let s = centre_stress(ElementKind::Simplex, &tet, &displaced(&tet, &e), &steel).unwrap();
        assert!(close(s, hooke(3)), "{s:?}");
        let bar = [[0.0], [0.5]];
        let s = centre_stress(ElementKind::Tensor, &bar, &displaced(&bar, &e), &steel).unwrap();
        assert!((s[0] - 210e9 * 1e-3).abs() < 1e-3 && s[1..].iter().all(|&x| x == 0.0), "{s:?}");
        assert!((von_mises(&[-7.0, 0.0, 0.0, 0.0, 0.0, 0.0]) - 7.0).abs() < 1e-12);
        assert!((von_mises(&[0.0, 0.0, 0.0, 2.0, 0.0, 0.0]) - 2.0 * 3f64.sqrt()).abs() < 1e-12, "pure shear");
        // an inverted element is refused, not given a stress
        let flipped = [hex[1], hex[0], hex[3], hex[2], hex[5], hex[4], hex[7], hex[6]];
        assert!(centre_stress(ElementKind::Tensor, &flipped, &displaced(&flipped, &e), &steel).is_err());
    }

    #[test]
    fn triangle_faces() {
        let x = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.0]];
        let (a, n) = face_area_and_normal::<3>(&x, [0.5, 0.5, 2.0]);
        assert!(a.iter().all(|v| (v - 1.0).abs() < 1e-15), "{a:?}");
        assert_eq!(n, [0.0, 0.0, -1.0]);
        assert_eq!(ElementKind::Simplex.face_local_nodes(3, 1), vec![0, 2, 3]);
        assert_eq!(ElementKind::Tensor.face_local_nodes(3, 5), face_local_nodes(3, 2, 1));
    }

    #[test]
    fn face_areas_and_normals() {
        let x = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.0], [2.0, 3.0, 1.0]];
        let (a, n) = face_area_and_normal::<3>(&x, [1.0, 1.5, 0.0]);
        assert!(a.iter().all(|v| (v - 1.5).abs() < 1e-14), "{a:?}");
        assert_eq!(n, [0.0, 0.0, 1.0]);
        let (a, n) = face_area_and_normal::<2>(&[[1.0, 0.0], [1.0, 2.0]], [2.0, 1.0]);
        assert!(a.iter().all(|v| (v - 1.0).abs() < 1e-14));
        assert!((n[0] + 1.0).abs() < 1e-14 && n[1].abs() < 1e-14);
        let (a, n) = face_area_and_normal::<1>(&[[4.0]], [3.0]);
        assert_eq!((a, n), (vec![1.0], [1.0]));
        let (_, n) = face_area_and_normal::<1>(&[[4.0]], [5.0]);
        assert_eq!(n, [-1.0]);
    }
}
