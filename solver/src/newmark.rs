//! Newmark's family in velocity form (docs/method.md 3). With gamma and beta, each step solves
//! `[M / (gamma dt) + (beta dt / gamma) K] v_{n+1} = f_{n+1} + M (v_n / (gamma dt) + (1 - gamma) / gamma a_n) -
//! K (u_n + dt (1 - beta / gamma) v_n + dt^2 (1/2 - beta / gamma) a_n)`.
//! gamma = 1/2, beta = 1/4 is the trapezoidal rule (average acceleration: second order, no
//! numerical dissipation); gamma > 1/2 with beta = (gamma + 1/2)^2 / 4 damps the highest
//! frequencies (first order), which holds a chattering contact's answer over a range of steps
//! (docs/verification.md, "A time scheme for chatter"). Shared by the LATIN linear stage and the
//! monolithic reference, so both integrate alike.

use crate::sparse::CsrMatrix;

/// A member of Newmark's family: `gamma` in [1/2, 1], `beta` from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Newmark {
    pub beta: f64,
    pub gamma: f64,
}

impl Default for Newmark {
    fn default() -> Self {
        Self::TRAPEZOIDAL
    }
}

impl Newmark {
    /// Average acceleration: second order, energy-conserving on a linear body.
    pub const TRAPEZOIDAL: Self = Self { beta: 0.25, gamma: 0.5 };

    /// gamma with beta = (gamma + 1/2)^2 / 4, the member that damps the highest frequencies
    /// most for its gamma (unconditionally stable); 1/2 gives the trapezoidal rule.
    pub fn with_gamma(gamma: f64) -> Self {
        Self { beta: 0.25 * (gamma + 0.5) * (gamma + 0.5), gamma }
    }

    /// The velocity coefficient of the step's displacement, beta dt / gamma: within a step a
    /// body opposes this times its stiffness to a velocity (dt/2 for the trapezoidal rule).
    pub fn new_velocity_weight(self, dt: f64) -> f64 {
        self.beta * dt / self.gamma
    }

    /// The previous velocity's share of the step's displacement, dt (1 - beta / gamma).
    pub fn old_velocity_weight(self, dt: f64) -> f64 {
        dt * (1.0 - self.beta / self.gamma)
    }

    /// The displacement a step of length dt adds from its two velocities, leaving out the
    /// acceleration's term (what the slip and the contact gap integrate): dt/2 (v_old + v_new)
    /// for the trapezoidal rule, bit for bit.
    pub fn displacement_increment(self, dt: f64, v_old: f64, v_new: f64) -> f64 {
        let s = self.step(dt);
        s.old * (v_old + v_new) + s.extra_new * v_new
    }

    /// Coefficients of one step of length dt; for the trapezoidal rule every one of them is what
    /// its literal formulas give, bit for bit (the products by 0 and 1 vanish exactly).
    fn step(self, dt: f64) -> Step {
        let (b, g) = (self.beta, self.gamma);
        let old = self.old_velocity_weight(dt);
        Step {
            mass: 1.0 / (g * dt),
            carried: (1.0 - g) / g,
            old,
            extra_new: self.new_velocity_weight(dt) - old,
            acceleration: dt * dt * ((0.5 - b) - b * (1.0 - g) / g),
        }
    }
}

/// u_{n+1} = u_n + old (v_n + v_{n+1}) + extra_new v_{n+1} + acceleration a_n,
/// a_{n+1} = mass (v_{n+1} - v_n) - carried a_n.
struct Step {
    mass: f64,
    carried: f64,
    old: f64,
    extra_new: f64,
    acceleration: f64,
}

/// State (u, v, a) of a discretised body and a scratch vector.
#[derive(Debug, Clone)]
pub struct NewmarkState {
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub a: Vec<f64>,
    tmp: Vec<f64>,
}

impl NewmarkState {
    pub fn new(n: usize) -> Self {
        Self { u: vec![0.0; n], v: vec![0.0; n], a: vec![0.0; n], tmp: vec![0.0; n] }
    }

    /// rhs += M (v_n / (gamma dt) + (1 - gamma) / gamma a_n) - K (u_n + dt (1 - beta / gamma) v_n + c a_n)
    pub fn add_history(&mut self, scheme: Newmark, mass: &CsrMatrix, stiffness: &CsrMatrix, dt: f64, rhs: &mut [f64]) {
        let s = scheme.step(dt);
        for i in 0..self.tmp.len() {
            self.tmp[i] = s.mass * self.v[i] + s.carried * self.a[i];
        }
        mass.mul_add(1.0, &self.tmp, rhs);
        for i in 0..self.tmp.len() {
            self.tmp[i] = self.u[i] + s.old * self.v[i] + s.acceleration * self.a[i];
        }
        stiffness.mul_add(-1.0, &self.tmp, rhs);
    }

    /// Advances to v_{n+1} = `v_new`.
    pub fn advance(&mut self, scheme: Newmark, v_new: &[f64], dt: f64) {
        let s = scheme.step(dt);
        for i in 0..v_new.len() {
            let a_new = s.mass * (v_new[i] - self.v[i]) - s.carried * self.a[i];
            self.u[i] += s.old * (self.v[i] + v_new[i]) + s.extra_new * v_new[i] + s.acceleration * self.a[i];
            self.v[i] = v_new[i];
            self.a[i] = a_new;
        }
    }
}

/// The Newmark step operator M / (gamma dt) + (beta dt / gamma) K.
pub fn step_operator(scheme: Newmark, mass: &CsrMatrix, stiffness: &CsrMatrix, dt: f64) -> CsrMatrix {
    mass.combine(scheme.step(dt).mass, stiffness, scheme.new_velocity_weight(dt))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(value: f64) -> CsrMatrix {
        CsrMatrix::from_triplets(1, vec![(0, 0, value)])
    }

    /// The trapezoidal rule's coefficients give what the literal formulas of average
    /// acceleration give, bit for bit (stored solutions and every figure measured before the
    /// family stay exactly as they were).
    #[test]
    fn the_trapezoidal_member_is_the_average_acceleration_rule_bit_for_bit() {
        let t = Newmark::TRAPEZOIDAL;
        let mut seed = 0x2545F4914F6CDD1Du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..1000 {
            let dt = next().abs() * 1e-5 + 1e-9;
            let (u, v, a, vn) = (next(), next(), next(), next());
            let s = t.step(dt);
            assert_eq!(s.mass, 2.0 / dt);
            assert_eq!(s.mass * v + s.carried * a, 2.0 / dt * v + a);
            assert_eq!(u + s.old * v + s.acceleration * a, u + 0.5 * dt * v);
            assert_eq!(s.mass * (vn - v) - s.carried * a, 2.0 / dt * (vn - v) - a);
            let mut x = u;
            x += s.old * (v + vn) + s.extra_new * vn + s.acceleration * a;
            let mut y = u;
            y += 0.5 * dt * (v + vn);
            assert_eq!(x, y);
            assert_eq!(t.new_velocity_weight(dt), dt / 2.0);
        }
    }

    /// Integrates m x'' + k x = 0 from x = 1 over `periods` periods; returns (x, v) at the end.
    fn oscillator(scheme: Newmark, steps_per_period: usize, periods: usize) -> (f64, f64) {
        let (m, k) = (2.0, 8.0); // omega = 2
        let dt = std::f64::consts::PI / steps_per_period as f64;
        let (mass, stiffness) = (one(m), one(k));
        let op = step_operator(scheme, &mass, &stiffness, dt);
        let mut s = NewmarkState::new(1);
        s.u[0] = 1.0;
        s.a[0] = -k / m; // the equation at t = 0
        for _ in 0..steps_per_period * periods {
            let mut rhs = vec![0.0];
            s.add_history(scheme, &mass, &stiffness, dt, &mut rhs);
            let v = rhs[0] / op.val[0];
            s.advance(scheme, &[v], dt);
        }
        (s.u[0], s.v[0])
    }

    /// The trapezoidal rule keeps the energy of an oscillator exactly and converges at order 2;
    /// gamma = 0.6 loses energy and converges at order 1: the dissipation falls as dt falls.
    #[test]
    fn the_members_keep_their_order_and_their_energy_balance() {
        let energy = |(x, v): (f64, f64)| 0.5 * 2.0 * v * v + 0.5 * 8.0 * x * x;
        let e0 = energy((1.0, 0.0));
        let error = |scheme, n| {
            let (x, v) = oscillator(scheme, n, 4);
            ((x - 1.0).powi(2) + (v / 2.0).powi(2)).sqrt()
        };
        let t = Newmark::TRAPEZOIDAL;
        assert!((energy(oscillator(t, 20, 4)) - e0).abs() < 1e-12 * e0);
        let order = |scheme| (error(scheme, 40) / error(scheme, 80)).log2();
        assert!((order(t) - 2.0).abs() < 0.1, "trapezoidal order {}", order(t));
        let d = Newmark::with_gamma(0.6);
        assert!(energy(oscillator(d, 20, 4)) < 0.9 * e0, "gamma 0.6 dissipates");
        assert!((order(d) - 1.0).abs() < 0.15, "gamma 0.6 order {}", order(d));
        let lost = |n| e0 - energy(oscillator(d, n, 4));
        assert!(lost(80) < 0.6 * lost(40), "the dissipation falls with dt: {} {}", lost(40), lost(80));
    }
}
