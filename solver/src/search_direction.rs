//! The search directions of the LATIN method (docs/method.md 3), their type and the formulas
//! that choose them (the model stores one per interface side): at each interface node,
//! F^ - F = k (W^ - W) (local stage) and F - F^ = -k (W - W^) (linear stage), with
//! k = k_n n n^T + k_t (I - n n^T): one value along the interface normal n and one across it.
//!
//! Why two: the normal problem of a contact is settled within a few iterations whatever k_n is,
//! while the slip history converges slowly and depends on k_t (docs/performance.md, "Search
//! direction"). On a perfect interface both values are equal and k is a scalar.

/// A search direction k (or, through [`SearchDirection::inverse`], its compliance h = 1/k) as
/// its normal and tangential values. `normal = tangential = 0` is the compliance of a rigid wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchDirection {
    /// k_n, along the interface normal
    pub normal: f64,
    /// k_t, across it
    pub tangential: f64,
}

impl SearchDirection {
    /// The same value along and across the normal.
    pub fn isotropic(k: f64) -> Self {
        Self { normal: k, tangential: k }
    }

    /// Both values times `factor`.
    pub fn scaled(self, factor: f64) -> Self {
        Self { normal: self.normal * factor, tangential: self.tangential * factor }
    }

    /// h = k^-1.
    pub fn inverse(self) -> Self {
        Self { normal: 1.0 / self.normal, tangential: 1.0 / self.tangential }
    }

    /// The value multiplying the normal part (`normal: true`) or the tangential part.
    pub fn part(self, normal: bool) -> f64 {
        if normal { self.normal } else { self.tangential }
    }

    /// k v at a node of unit normal n: k_t v + (k_n - k_t) (n.v) n.
    pub fn apply<const D: usize>(self, n: &[f64; D], v: &[f64; D]) -> [f64; D] {
        let vn: f64 = (0..D).map(|c| n[c] * v[c]).sum();
        std::array::from_fn(|c| self.tangential * v[c] + (self.normal - self.tangential) * vn * n[c])
    }

    /// Entry (a, b) of the matrix k at a node of unit normal n.
    pub fn entry<const D: usize>(self, n: &[f64; D], a: usize, b: usize) -> f64 {
        let delta = if a == b { 1.0 } else { 0.0 };
        self.tangential * delta + (self.normal - self.tangential) * n[a] * n[b]
    }

    /// v . k v.
    pub fn energy<const D: usize>(self, n: &[f64; D], v: &[f64; D]) -> f64 {
        let kv = self.apply(n, v);
        (0..D).map(|c| v[c] * kv[c]).sum()
    }
}

/// The static search direction of one side: E / sqrt(L h), or E / sqrt(L h / a) for elements a
/// times deeper than long (below). The static stage is multiscale
/// (`latin::LatinSolver::new`): its macro problem carries the smooth part of the interface fields,
/// and the direction aims at the rest of the range of stiffnesses a substructure opposes, from
/// E / L (L the assembly's largest extent) for a smooth interface displacement to E / h for one
/// that changes from node to node (h the interface's mesh size); the geometric mean of the
/// range's ends minimises the largest contraction factor |s - k| / (s + k) over it. Measured
/// (docs/performance.md, "Locking, and the static search direction"): 2-10 x fewer static iterations than E / L on
/// every scene, and elements of aspect ratio 100 at an interface converge (none in 5000 with
/// E / L).
/// Elements `depth` (a) times deeper along the interface's normal than long along it oppose a
/// pattern from node to node with about a E / h: there the range's upper end, and the direction
/// E / sqrt(L h / a) (a > 1 only; docs/performance.md, "Flat elements along an interface":
/// prestress iterations 6,384 -> 633 at a = 100).
pub fn static_search_direction(young: f64, assembly_size: f64, mesh_size: Option<f64>, depth: Option<f64>) -> f64 {
    let h = mesh_size.map(|h| h / depth.filter(|a| a.is_finite()).unwrap_or(1.0).max(1.0));
    match h {
        Some(h) if h > 0.0 && h < assembly_size => young / (assembly_size * h).sqrt(),
        _ => young / assembly_size,
    }
}

/// Bounds of the dynamic search direction relative to the impedance sqrt(rho E).
pub const SEARCH_DIRECTION_BOUNDS: (f64, f64) = (1.0, 4.0);

/// The dynamic search direction of one side: the impedance sqrt(rho E), or, for a substructure
/// that a wave crosses in less than a step (depth L along the interface normal below c dt), the
/// stiffness E dt / L it opposes within one step (= impedance x c dt / L), at most 4 x the
/// impedance. Measured (docs/performance.md, "Search direction"): three-blocks-tiny (c dt / L =
/// 1.35) 211 -> 185 dynamic iterations cold. Below c dt / L = 1 the impedance stays: a 3D box at
/// 0.51 preferred 0.5 x impedance (69 iterations against 131), but the 1D impact bar at 0.04
/// needs the impedance (190 iterations against 643 at 0.25 x, and no convergence in 1000 with 50
/// elements).
pub fn dynamic_search_direction(impedance: f64, wave_speed: f64, depth: f64, dt: f64) -> f64 {
    // a flat (or degenerate, NaN) substructure has no depth to compare c dt with
    if depth.is_nan() || depth <= 0.0 {
        return impedance;
    }
    let ratio = wave_speed * dt / depth;
    impedance * ratio.clamp(SEARCH_DIRECTION_BOUNDS.0, SEARCH_DIRECTION_BOUNDS.1)
}

/// The normal part of a side's dynamic search direction is at least what the side's own
/// interface nodes oppose by their inertia over the steps iterated together (a time window of
/// duration T = n dt; the whole interval without windows): mu / (gamma T), mu the diagonal of the
/// substructure's (consistent) mass at those nodes per unit of interface measure. In windows of
/// one step below c dt / h of about 2 / 3 in 1D (h the elements' depth along the normal; 0.44
/// for quadrilaterals, 0.30 for hexahedra) this exceeds the impedance: a window of one step
/// meets the nodes' inertia before any wave; over a long window or the whole interval it is
/// negligible and the impedance rules. Measured (docs/notebook/2026-11-30.md, "The nodes'
/// inertia in the search direction"): the 1D impact bar's work flat from dt to dt / 10 (22.0,
/// 21.9, 22.7, 22.8 sweeps; 71.6 at dt / 10 before). It bounds the tangential part too on perfect
/// interfaces (our dropped copper block at dt / 10: 87.2 -> 50.7 sweeps), not on contact and
/// friction ones, whose law sets it (friction at dt / 10 was neutral to worse with it).
pub fn inertia_search_direction(mass_per_measure: f64, gamma: f64, window: f64) -> f64 {
    mass_per_measure / (gamma * window)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_and_tangential_parts_are_scaled_apart() {
        let s = 0.5f64.sqrt();
        let n = [s, s, 0.0];
        let k = SearchDirection { normal: 3.0, tangential: 2.0 };
        // along n: 3 v; across n: 2 v
        let along = k.apply(&n, &[1.0, 1.0, 0.0]);
        assert!(along.iter().zip([3.0, 3.0, 0.0]).all(|(a, b)| (a - b).abs() < 1e-14), "{along:?}");
        let across = k.apply(&n, &[1.0, -1.0, 4.0]);
        assert!(across.iter().zip([2.0, -2.0, 8.0]).all(|(a, b)| (a - b).abs() < 1e-14), "{across:?}");
        // the matrix and its action agree, and h k = I
        let v = [0.3, -1.2, 0.7];
        let kv = k.apply(&n, &v);
        for a in 0..3 {
            let row: f64 = (0..3).map(|b| k.entry(&n, a, b) * v[b]).sum();
            assert!((row - kv[a]).abs() < 1e-14);
        }
        let back = k.inverse().apply(&n, &kv);
        assert!(back.iter().zip(v).all(|(a, b)| (a - b).abs() < 1e-14));
        assert!((k.energy(&n, &v) - (0..3).map(|c| v[c] * kv[c]).sum::<f64>()).abs() < 1e-14);
    }

    #[test]
    fn isotropic_is_a_scalar() {
        let k = SearchDirection::isotropic(5.0);
        let n = [0.0, 0.6, 0.8];
        assert_eq!(k.apply(&n, &[1.0, 2.0, 3.0]).map(|x| (x * 1e12).round() / 1e12), [5.0, 10.0, 15.0]);
    }
}
