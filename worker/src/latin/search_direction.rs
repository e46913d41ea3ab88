//! The search directions of the LATIN method (docs/method.md 3): at each interface node,
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
