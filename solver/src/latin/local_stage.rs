//! Local stage: the interface laws in closed form, pointwise in space, stepwise in time
//! (docs/method.md 3, "Local stage"). Pure functions of the linear-stage fields.

use glissade_core::contact::PrakashClifton;

use crate::model::InterfaceLaw;
use crate::search_direction::SearchDirection;

/// Inputs of one interface node at one step: linear-stage fields of both sides, the normal, and
/// the search directions as compliances h = 1/k (normal and tangential values). A rigid wall is
/// side 2 with `h2 = 0` and `w2` its velocity.
#[derive(Debug, Clone, Copy)]
pub struct NodeInput<const D: usize> {
    pub w1: [f64; D],
    pub f1: [f64; D],
    pub w2: [f64; D],
    pub f2: [f64; D],
    pub h1: SearchDirection,
    pub h2: SearchDirection,
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

/// How a step's normal gap follows from velocities: `g = base + weight * n.(W2 - W1)`, `base`
/// from the node's [`NodeMemory`] (the time scheme's weight, dt/2 for the trapezoidal rule,
/// docs/method.md 2; the scheme's acceleration term, 0 for the trapezoidal rule and
/// -0.004 dt^2 a for gamma 0.6, is left out of the gap; in the static
/// stage the initial gap, weight 1, W = displacement), and the step `dt` the memory moves on by.
#[derive(Debug, Clone, Copy)]
pub struct GapRule {
    pub weight: f64,
    pub dt: f64,
    /// the step's normal velocity's share of the next step's base: dt (1 - beta / gamma), dt/2
    /// for the trapezoidal rule; 0 in the static stage
    pub carry: f64,
}

/// What the law of one node carries from a step to the next: the gap rule's base (the gap at the
/// previous step plus that step's share, dt/2 times its normal velocity) and, under a
/// Prakash-Clifton law, the normal force the friction follows and the last slip rate (`None`
/// before the first step: the friction then follows that step's normal force, a state at rest).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeMemory {
    pub base: f64,
    pub followed: Option<f64>,
    pub slip_rate: f64,
}

impl NodeMemory {
    /// A node at rest with gap base `base`.
    pub fn new(base: f64) -> Self {
        Self { base, followed: None, slip_rate: 0.0 }
    }
}

fn dot<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    (0..D).map(|i| a[i] * b[i]).sum()
}

/// Applies the interface law to one node: perfect (or a prestress's held jump), or unilateral
/// contact with Coulomb friction ([`coulomb_contact`], frictionless for `Contact`), on the
/// search direction E+: F^ - F = k (W^ - W), k with a normal and a
/// tangential value: the law is solved on the normal and the tangential parts apart, each with
/// its own scalar h. Moves the node's `memory` on to the next step.
pub fn apply_law<const D: usize>(
    law: InterfaceLaw,
    x: &NodeInput<D>,
    gap: GapRule,
    memory: &mut NodeMemory,
) -> NodeOutput<D> {
    let (h1, h2) = (x.h1, x.h2);
    let n = &x.normal;
    let mut f1h = [0.0; D];
    match law {
        InterfaceLaw::Perfect | InterfaceLaw::Prestress { .. } => {
            // W^1 = W^2 + s n = (k1 W1 + k2 (W2 + s n) - (F1 + F2)) / (k1 + k2), written with h
            // to allow h2 = 0, on the normal part (along n) and the tangential part (the rest)
            // apart; s is a prestress's shortening (static stage), else none
            let shortening = match law {
                InterfaceLaw::Prestress { shortening } => shortening,
                _ => 0.0,
            };
            let w2_target: [f64; D] = std::array::from_fn(|i| x.w2[i] + shortening * n[i]);
            let split = |v: &[f64; D]| -> ([f64; D], [f64; D]) {
                let vn = dot(v, n);
                let along: [f64; D] = std::array::from_fn(|i| vn * n[i]);
                (along, std::array::from_fn(|i| v[i] - along[i]))
            };
            let parts = [split(&x.w1), split(&w2_target), split(&x.f1), split(&x.f2)];
            for normal in [true, false] {
                let pick = |p: &([f64; D], [f64; D])| if normal { p.0 } else { p.1 };
                let (w1, w2, f1, f2) = (pick(&parts[0]), pick(&parts[1]), pick(&parts[2]), pick(&parts[3]));
                let (h1, h2) = (h1.part(normal), h2.part(normal));
                for i in 0..D {
                    let w = (h2 * w1[i] + h1 * w2[i] - h1 * h2 * (f1[i] + f2[i])) / (h1 + h2);
                    f1h[i] += f1[i] + (w - w1[i]) / h1;
                }
            }
        }
        InterfaceLaw::Contact => f1h = coulomb_contact(x, 0.0, None, gap, memory),
        InterfaceLaw::Friction { coefficient, regularisation } => {
            f1h = coulomb_contact(x, coefficient, regularisation, gap, memory)
        }
    }
    let f2h: [f64; D] = std::array::from_fn(|i| -f1h[i]);
    let d1 = h1.apply(n, &std::array::from_fn(|i| f1h[i] - x.f1[i]));
    let d2 = h2.apply(n, &std::array::from_fn(|i| f2h[i] - x.f2[i]));
    let out = NodeOutput {
        w1: std::array::from_fn(|i| x.w1[i] + d1[i]),
        f1: f1h,
        w2: std::array::from_fn(|i| x.w2[i] + d2[i]),
        f2: f2h,
    };
    let rel: [f64; D] = std::array::from_fn(|i| out.w2[i] - out.w1[i]);
    let vn = dot(n, &rel);
    memory.base += gap.weight * vn + gap.carry * vn;
    // the Prakash-Clifton law's rate, read at the next step (no other law reads it)
    if matches!(law, InterfaceLaw::Friction { regularisation: Some(_), .. }) {
        memory.slip_rate = (dot(&rel, &rel) - vn * vn).max(0.0).sqrt();
    }
    out
}

/// Unilateral contact with Coulomb friction of coefficient `mu` (0: frictionless) at one node:
/// the force on side 1. Where the trial gap closes, the normal force closes it exactly; the
/// tangential force is the stick trial's, scaled back to the cone mu |F_n| where it lies outside
/// (sliding); where the gap opens, no force. Under a Prakash-Clifton `regularisation` the cone
/// is mu N* instead, N* following |F_n| with a lag (kept in `memory`), at most 2 |F_n|
/// ([`glissade_core::contact::LAG_CAP`]).
fn coulomb_contact<const D: usize>(
    x: &NodeInput<D>,
    mu: f64,
    regularisation: Option<PrakashClifton>,
    gap: GapRule,
    memory: &mut NodeMemory,
) -> [f64; D] {
    let (h1, h2) = (x.h1, x.h2);
    let n = &x.normal;
    let mut f1h = [0.0; D];
    // free relative velocity: what W^2 - W^1 would be with F^ = 0
    let (hf1, hf2) = (h1.apply(n, &x.f1), h2.apply(n, &x.f2));
    let mut rel = [0.0; D];
    for i in 0..D {
        rel[i] = (x.w2[i] - x.w1[i]) - (hf2[i] - hf1[i]);
    }
    let rel_n = dot(&rel, n);
    // A closed gap (base <= 0) is clipped at zero: contact then holds on the velocity level
    // (n.(W^2 - W^1) = 0), without the spurious rebound that closing the trapezoidal gap
    // exactly would give; penetration stays below dt/2 times the approach velocity.
    let trial_gap = memory.base.max(0.0) + gap.weight * rel_n;
    // contact: the normal force closes the gap exactly
    let f1n = if trial_gap <= 0.0 { trial_gap / (gap.weight * (h1.normal + h2.normal)) } else { 0.0 };
    let normal = match regularisation {
        Some(law) => law.step(&mut memory.followed, f1n.abs(), memory.slip_rate, gap.dt),
        None => f1n.abs(),
    };
    if trial_gap <= 0.0 {
        // stick trial T from zero relative tangential velocity
        let mut t = [0.0; D];
        for i in 0..D {
            t[i] = (rel[i] - rel_n * n[i]) / (h1.tangential + h2.tangential);
        }
        let t_norm = dot(&t, &t).sqrt();
        let threshold = mu * normal;
        let scale = if t_norm <= threshold { 1.0 } else { threshold / t_norm };
        for i in 0..D {
            f1h[i] = f1n * n[i] + scale * t[i];
        }
    }
    f1h
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(w1: [f64; 2], f1: [f64; 2], w2: [f64; 2], f2: [f64; 2]) -> NodeInput<2> {
        NodeInput {
            w1,
            f1,
            w2,
            f2,
            h1: SearchDirection::isotropic(0.5),
            h2: SearchDirection::isotropic(0.25),
            normal: [0.0, 1.0],
        }
    }

    /// F^ - F = k (W^ - W) on both sides, k = h^-1 with its normal and tangential values, and
    /// F^1 + F^2 = 0.
    fn assert_search_direction<const D: usize>(x: &NodeInput<D>, o: &NodeOutput<D>) {
        let n = &x.normal;
        for (h, w, wh, f, fh) in [(x.h1, x.w1, o.w1, x.f1, o.f1), (x.h2, x.w2, o.w2, x.f2, o.f2)] {
            let dw = h.inverse().apply(n, &std::array::from_fn(|i| wh[i] - w[i]));
            for i in 0..D {
                assert!((fh[i] - f[i] - dw[i]).abs() < 1e-12, "{fh:?} - {f:?} != k ({wh:?} - {w:?})");
            }
        }
        for i in 0..D {
            assert!((o.f1[i] + o.f2[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn perfect_gives_equal_velocities() {
        let x = input([1.0, 2.0], [0.3, -0.1], [-1.0, 0.5], [0.2, 0.4]);
        let o = apply_law(
            InterfaceLaw::Perfect,
            &x,
            GapRule { weight: 1.0, dt: 0.0, carry: 0.0 },
            &mut NodeMemory::new(0.0),
        );
        assert_search_direction(&x, &o);
        for i in 0..2 {
            assert!((o.w1[i] - o.w2[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn prestress_gives_the_prescribed_jump() {
        let x = input([1.0, 2.0], [0.3, -0.1], [-1.0, 0.5], [0.2, 0.4]);
        let o = apply_law(
            InterfaceLaw::Prestress { shortening: 0.125 },
            &x,
            GapRule { weight: 1.0, dt: 0.0, carry: 0.0 },
            &mut NodeMemory::new(0.0),
        );
        assert_search_direction(&x, &o);
        // W^2 - W^1 = -s n (n = y)
        assert!((o.w2[0] - o.w1[0]).abs() < 1e-12 && (o.w2[1] - o.w1[1] + 0.125).abs() < 1e-12);
        assert_eq!(InterfaceLaw::Prestress { shortening: 0.125 }.in_dynamics(), InterfaceLaw::Perfect);
    }

    #[test]
    fn separation_gives_zero_force() {
        // side 2 moves away along n
        let x = input([0.0, 0.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0]);
        let o = apply_law(
            InterfaceLaw::Friction { coefficient: 0.5, regularisation: None },
            &x,
            GapRule { weight: 0.1, dt: 0.2, carry: 0.1 },
            &mut NodeMemory::new(0.0),
        );
        assert_eq!(o.f1, [0.0, 0.0]);
        assert_search_direction(&x, &o);
    }

    #[test]
    fn contact_closes_gap_and_respects_coulomb() {
        // side 2 moves towards side 1 and slides along x
        let x = input([0.0, 0.0], [0.0, 0.0], [3.0, -1.0], [0.0, 0.0]);
        let rule = GapRule { weight: 0.1, dt: 0.2, carry: 0.1 };
        for mu in [0.0, 0.1, 10.0] {
            let o = apply_law(
                InterfaceLaw::Friction { coefficient: mu, regularisation: None },
                &x,
                rule,
                &mut NodeMemory::new(0.0),
            );
            assert_search_direction(&x, &o);
            let gap = rule.weight * (o.w2[1] - o.w1[1]);
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

    /// Under a Prakash-Clifton law the cone is mu N*, N* moved one step from the node's memory
    /// towards this step's |F_n| (at the last slip rate); the memory then holds N*, the slip
    /// rate of the output and the gap rule's next base.
    #[test]
    fn a_regularised_cone_follows_the_normal_force_with_a_lag() {
        let x = input([0.0, 0.0], [0.0, 0.0], [3.0, -1.0], [0.0, 0.0]);
        let rule = GapRule { weight: 0.1, dt: 0.2, carry: 0.1 };
        let coulomb = apply_law(
            InterfaceLaw::Friction { coefficient: 0.3, regularisation: None },
            &x,
            rule,
            &mut NodeMemory::new(0.0),
        );
        let normal = coulomb.f1[1].abs();
        let law = PrakashClifton { length: 2.0, velocity: 0.5 };
        let mut memory = NodeMemory { base: 0.0, followed: Some(normal / 4.0), slip_rate: 1.5 };
        let o =
            apply_law(InterfaceLaw::Friction { coefficient: 0.3, regularisation: Some(law) }, &x, rule, &mut memory);
        assert_search_direction(&x, &o);
        let followed = law.follow(normal / 4.0, normal, 1.5, 0.2);
        assert!(followed > normal / 4.0 && followed < normal);
        assert_eq!(o.f1[1], coulomb.f1[1], "the normal force is Coulomb's");
        assert!((o.f1[0].abs() - 0.3 * followed).abs() < 1e-12, "{} against {}", o.f1[0], 0.3 * followed);
        assert_eq!(memory.followed, Some(followed));
        let slip = o.w2[0] - o.w1[0];
        assert!((memory.slip_rate - slip.abs()).abs() < 1e-12 && slip > 0.0);
        let vn = o.w2[1] - o.w1[1];
        assert!((memory.base - (0.1 + 0.1) * vn).abs() < 1e-12, "base {} for vn {vn}", memory.base);
        // a normal force fallen far below the one followed draws the cone at 2 |F_n| at most
        let mut memory = NodeMemory { base: 0.0, followed: Some(100.0 * normal), slip_rate: 0.0 };
        let o =
            apply_law(InterfaceLaw::Friction { coefficient: 0.3, regularisation: Some(law) }, &x, rule, &mut memory);
        assert!((o.f1[0].abs() - 0.3 * 2.0 * normal).abs() < 1e-12, "{} against {}", o.f1[0], 0.6 * normal);
        assert!(memory.followed.unwrap() > 2.0 * normal, "the memory keeps N* itself");
        // with no memory yet it follows this step's force: Coulomb's cone
        let o = apply_law(
            InterfaceLaw::Friction { coefficient: 0.3, regularisation: Some(law) },
            &x,
            rule,
            &mut NodeMemory::new(0.0),
        );
        assert_eq!(o, coulomb);
    }

    #[test]
    fn rigid_wall_side_keeps_its_velocity() {
        let x = NodeInput {
            w1: [-2.0],
            f1: [0.0],
            w2: [0.0],
            f2: [0.0],
            h1: SearchDirection::isotropic(0.5),
            h2: SearchDirection::isotropic(0.0),
            normal: [-1.0],
        };
        // side 1 moves along -x towards a wall whose outward normal from side 1 is -x
        let o = apply_law(
            InterfaceLaw::Contact,
            &x,
            GapRule { weight: 0.1, dt: 0.2, carry: 0.1 },
            &mut NodeMemory::new(0.0),
        );
        assert_eq!(o.w2, [0.0]);
        assert!(o.w1[0].abs() < 1e-12, "side 1 stopped by the wall");
        assert!(o.f1[0] > 0.0, "wall pushes along +x");
    }

    #[test]
    fn tangential_and_normal_directions_apart_on_an_oblique_normal() {
        // a 3D node whose normal is along no axis, k_t = 3 k_n on side 1, k_t = k_n / 2 on side 2
        let s = 1.0 / 3.0f64.sqrt();
        let normal = [s, -s, s];
        let h1 = SearchDirection { normal: 1.0, tangential: 3.0 }.inverse();
        let h2 = SearchDirection { normal: 2.0, tangential: 1.0 }.inverse();
        let rule = GapRule { weight: 0.1, dt: 0.2, carry: 0.1 };
        let dot3 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|i| a[i] * b[i]).sum::<f64>();
        // perfect: equal velocities
        let x = NodeInput {
            w1: [1.0, 0.2, -0.3],
            f1: [0.4, 0.0, 1.0],
            w2: [-0.5, 0.7, 0.1],
            f2: [0.1, -0.2, 0.3],
            h1,
            h2,
            normal,
        };
        let o = apply_law(InterfaceLaw::Perfect, &x, rule, &mut NodeMemory::new(0.0));
        assert_search_direction(&x, &o);
        assert!((0..3).all(|i| (o.w1[i] - o.w2[i]).abs() < 1e-12), "{o:?}");
        // side 2 pushed into side 1 (against n) and dragged across it
        let x = NodeInput { w1: [0.0; 3], f1: [0.0; 3], w2: [-1.0, 2.0, 0.5], f2: [0.0; 3], h1, h2, normal };
        for mu in [0.0, 0.2, 50.0] {
            let o = apply_law(
                InterfaceLaw::Friction { coefficient: mu, regularisation: None },
                &x,
                rule,
                &mut NodeMemory::new(0.0),
            );
            assert_search_direction(&x, &o);
            let rel: [f64; 3] = std::array::from_fn(|i| o.w2[i] - o.w1[i]);
            let rel_n = dot3(&rel, &normal);
            assert!((rule.weight * rel_n).abs() < 1e-12, "gap closed: {rel_n}");
            let fn1 = dot3(&o.f1, &normal);
            assert!(fn1 < 0.0, "compressive");
            let ft: [f64; 3] = std::array::from_fn(|i| o.f1[i] - fn1 * normal[i]);
            let ft_norm = dot3(&ft, &ft).sqrt();
            assert!(ft_norm <= mu * fn1.abs() * (1.0 + 1e-12) + 1e-15, "Coulomb: {ft_norm} > {mu} {fn1}");
            let slip: [f64; 3] = std::array::from_fn(|i| rel[i] - rel_n * normal[i]);
            let slip_norm = dot3(&slip, &slip).sqrt();
            if mu == 50.0 {
                assert!(slip_norm < 1e-12, "sticks: {slip_norm}");
            } else {
                // sliding: the force on side 1 is along the slip of side 2 over side 1, at the threshold
                assert!(slip_norm > 1e-6);
                assert!((ft_norm - mu * fn1.abs()).abs() < 1e-12);
                assert!(dot3(&ft, &slip) >= -1e-12, "dissipates");
            }
        }
    }
}
