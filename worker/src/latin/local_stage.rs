//! Local stage: the interface laws in closed form, pointwise in space, stepwise in time
//! (docs/method.md 3, "Local stage"). Pure functions of the linear-stage fields.

use crate::model::InterfaceLaw;

/// Inputs of one interface node at one step: linear-stage fields of both sides, the normal, and
/// the search directions h = 1/k. A rigid wall is side 2 with `h2 = 0` and `w2` its velocity.
#[derive(Debug, Clone, Copy)]
pub struct NodeInput<const D: usize> {
    pub w1: [f64; D],
    pub f1: [f64; D],
    pub w2: [f64; D],
    pub f2: [f64; D],
    pub h1: f64,
    pub h2: f64,
    pub normal: [f64; D],
}

/// Local-stage result at one node and step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeOutput<const D: usize> {
    pub w1: [f64; D],
    pub f1: [f64; D],
    pub w2: [f64; D],
    pub f2: [f64; D],
}

/// How the normal gap follows from velocities: `g = base + weight * n.(W2 - W1)` where `base`
/// holds the gap at the previous step plus the previous step's share (trapezoidal rule,
/// weight dt/2, docs/method.md 2), or the initial gap in the static stage (weight 1, W = displacement).
#[derive(Debug, Clone, Copy)]
pub struct GapRule {
    pub base: f64,
    pub weight: f64,
}

fn dot<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    (0..D).map(|i| a[i] * b[i]).sum()
}

/// Applies the interface law to one node (search direction E+: F^ - F = k (W^ - W)).
pub fn apply_law<const D: usize>(law: InterfaceLaw, x: &NodeInput<D>, gap: GapRule) -> NodeOutput<D> {
    let (h1, h2) = (x.h1, x.h2);
    let mut f1h = [0.0; D];
    match law {
        InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. } => {
            // W^1 = W^2 + s n = (k1 W1 + k2 (W2 + s n) - (F1 + F2)) / (k1 + k2), written with h
            // to allow h2 = 0; s is a prestress's shortening (static stage), else none
            for i in 0..D {
                let w2 = match law {
                    InterfaceLaw::Prestress { shortening } => x.w2[i] + shortening * x.normal[i],
                    _ => x.w2[i],
                };
                let w = (h2 * x.w1[i] + h1 * w2 - h1 * h2 * (x.f1[i] + x.f2[i])) / (h1 + h2);
                f1h[i] = x.f1[i] + (w - x.w1[i]) / h1;
            }
        }
        InterfaceLaw::Contact | InterfaceLaw::Friction { .. } => {
            let n = &x.normal;
            // free relative velocity: what n.(W^2 - W^1) would be with F^ = 0
            let mut rel = [0.0; D];
            for i in 0..D {
                rel[i] = (x.w2[i] - x.w1[i]) - (h2 * x.f2[i] - h1 * x.f1[i]);
            }
            let rel_n = dot(&rel, n);
            // A closed gap (base <= 0) is clipped at zero: contact then holds on the velocity level
            // (n.(W^2 - W^1) = 0), without the spurious rebound that closing the trapezoidal gap
            // exactly would give; penetration stays below dt/2 times the approach velocity.
            let trial_gap = gap.base.max(0.0) + gap.weight * rel_n;
            if trial_gap <= 0.0 {
                // contact: the normal force closes the gap exactly
                let f1n = trial_gap / (gap.weight * (h1 + h2));
                let mu = match law {
                    InterfaceLaw::Friction { coefficient } => coefficient,
                    _ => 0.0,
                };
                // stick trial T from zero relative tangential velocity
                let mut t = [0.0; D];
                for i in 0..D {
                    t[i] = (rel[i] - rel_n * n[i]) / (h1 + h2);
                }
                let t_norm = dot(&t, &t).sqrt();
                let threshold = mu * f1n.abs();
                let scale = if t_norm <= threshold { 1.0 } else { threshold / t_norm };
                for i in 0..D {
                    f1h[i] = f1n * n[i] + scale * t[i];
                }
            }
        }
    }
    let mut out = NodeOutput { w1: [0.0; D], f1: f1h, w2: [0.0; D], f2: [0.0; D] };
    for i in 0..D {
        out.f2[i] = -f1h[i];
        out.w1[i] = x.w1[i] + h1 * (f1h[i] - x.f1[i]);
        out.w2[i] = x.w2[i] + h2 * (out.f2[i] - x.f2[i]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(w1: [f64; 2], f1: [f64; 2], w2: [f64; 2], f2: [f64; 2]) -> NodeInput<2> {
        NodeInput { w1, f1, w2, f2, h1: 0.5, h2: 0.25, normal: [0.0, 1.0] }
    }

    fn assert_search_direction(x: &NodeInput<2>, o: &NodeOutput<2>) {
        for i in 0..2 {
            assert!((o.f1[i] - x.f1[i] - (o.w1[i] - x.w1[i]) / x.h1).abs() < 1e-12);
            assert!((o.f2[i] - x.f2[i] - (o.w2[i] - x.w2[i]) / x.h2).abs() < 1e-12);
            assert!((o.f1[i] + o.f2[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn perfect_gives_equal_velocities() {
        let x = input([1.0, 2.0], [0.3, -0.1], [-1.0, 0.5], [0.2, 0.4]);
        let o = apply_law(InterfaceLaw::Perfect, &x, GapRule { base: 0.0, weight: 1.0 });
        assert_search_direction(&x, &o);
        for i in 0..2 {
            assert!((o.w1[i] - o.w2[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn prestress_gives_the_prescribed_jump() {
        let x = input([1.0, 2.0], [0.3, -0.1], [-1.0, 0.5], [0.2, 0.4]);
        let o = apply_law(InterfaceLaw::Prestress { shortening: 0.125 }, &x, GapRule { base: 0.0, weight: 1.0 });
        assert_search_direction(&x, &o);
        // W^2 - W^1 = -s n (n = y)
        assert!((o.w2[0] - o.w1[0]).abs() < 1e-12 && (o.w2[1] - o.w1[1] + 0.125).abs() < 1e-12);
        assert_eq!(InterfaceLaw::Prestress { shortening: 0.125 }.in_dynamics(), InterfaceLaw::Perfect);
    }

    #[test]
    fn separation_gives_zero_force() {
        // side 2 moves away along n
        let x = input([0.0, 0.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0]);
        let o = apply_law(InterfaceLaw::Friction { coefficient: 0.5 }, &x, GapRule { base: 0.0, weight: 0.1 });
        assert_eq!(o.f1, [0.0, 0.0]);
        assert_search_direction(&x, &o);
    }

    #[test]
    fn contact_closes_gap_and_respects_coulomb() {
        // side 2 moves towards side 1 and slides along x
        let x = input([0.0, 0.0], [0.0, 0.0], [3.0, -1.0], [0.0, 0.0]);
        let rule = GapRule { base: 0.0, weight: 0.1 };
        for mu in [0.0, 0.1, 10.0] {
            let o = apply_law(InterfaceLaw::Friction { coefficient: mu }, &x, rule);
            assert_search_direction(&x, &o);
            let gap = rule.base + rule.weight * (o.w2[1] - o.w1[1]);
            assert!(gap.abs() < 1e-12, "gap {gap}");
            assert!(o.f1[1] < 0.0, "compressive normal force on side 1");
            assert!(o.f1[0].abs() <= mu * o.f1[1].abs() * (1.0 + 1e-12));
            let slip = o.w2[0] - o.w1[0];
            if mu == 10.0 {
                assert!(slip.abs() < 1e-12, "sticks at high friction");
            } else {
                // dissipation: friction force on side 1 pulls it along the relative slip
                assert!(o.f1[0] * slip >= 0.0 && slip > 0.0);
            }
        }
    }

    #[test]
    fn rigid_wall_side_keeps_its_velocity() {
        let x = NodeInput { w1: [-2.0], f1: [0.0], w2: [0.0], f2: [0.0], h1: 0.5, h2: 0.0, normal: [-1.0] };
        // side 1 moves along -x towards a wall whose outward normal from side 1 is -x
        let o = apply_law(InterfaceLaw::Contact, &x, GapRule { base: 0.0, weight: 0.1 });
        assert_eq!(o.w2, [0.0]);
        assert!(o.w1[0].abs() < 1e-12, "side 1 stopped by the wall");
        assert!(o.f1[0] > 0.0, "wall pushes along +x");
    }
}
