//! What a frictional contact did while it slid, as the solver reports it with every solve and
//! the service keeps with every point: evidence a user reads beside the answer, and the one
//! case where the solver knows its answer cannot converge under refinement (an elastic body
//! sliding on a rigid wall above friction 1, docs/verification.md 4d). The solver computes it
//! (glissade-solver's `contact_activity`).

use serde::{Deserialize, Serialize};

/// Most interfaces a report carries (a scene holds far fewer): bounds what a client may send.
pub const MAX_CONTACT_REPORTS: usize = 1024;

/// Above this friction coefficient, an elastic half-space sliding on a rigid plane admits
/// surface waves that grow at a rate proportional to their wavenumber, whatever Poisson's ratio
/// (0 < nu < 1/2): the continuum problem is ill-posed, and every refinement of the mesh resolves
/// faster-growing waves (docs/verification.md 4d, where the determinant's root is derived; the
/// tests below find it).
pub const ILL_POSED_FRICTION: f64 = 1.0;

/// The Prakash-Clifton regularisation of Coulomb's law (docs/method.md 3, "Local stage"): the
/// friction bound is f times a normal force N* that follows the contact's N with a lag,
/// dN*/dt = -(|V| + `velocity`) / `length` (N* - N), V the slip rate, drawn at most
/// [`LAG_CAP`] x N. A sudden change of the normal force then changes the friction over a slip of
/// `length`, not at once: the friction no longer feeds a fast oscillation of the normal force
/// back at once, which damps a sliding contact's chatter below f = 1 (docs/verification.md 4e).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrakashClifton {
    /// m, > 0
    pub length: f64,
    /// m/s, > 0
    pub velocity: f64,
}

/// An interface's law with its numbers at a design point (docs/method.md 1): what the checks
/// of a submission accept and what the solver's local stage applies, node by node. Made by
/// [`crate::check::interface_law`], the one place its rules live.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InterfaceLaw {
    Perfect,
    Contact,
    Friction {
        /// >= 0
        coefficient: f64,
        /// the friction follows the normal force with a lag (`None`: Coulomb's, at once)
        regularisation: Option<PrakashClifton>,
    },
    /// glued, side 2 displaced by `-shortening` (m) along the normal in the static stage (a bolt
    /// shortened by its prestress), the jump then held: perfect in the dynamics
    Prestress {
        shortening: f64,
    },
}

impl InterfaceLaw {
    /// The law of the dynamic stage (velocities): a prestress's jump is held.
    pub fn in_dynamics(self) -> Self {
        match self {
            InterfaceLaw::Prestress { .. } => InterfaceLaw::Perfect,
            law => law,
        }
    }
}

/// The lagged normal force draws the friction bound at most this many times the contact's own:
/// the friction must vanish with the normal force. Uncapped, a node whose normal force collapses
/// (a corner that high friction unloads) keeps a pull of f N* that no step can hold: closed, it
/// holds f N* and that pull lifts it; open, it holds nothing and closes (docs/verification.md
/// 4e: the iterations cycle). At 2 the cap never binds on the chattering blocks the law is for
/// (their slips unchanged to 6 digits); at 1 the law is Coulomb's on every fall of the
/// normal force and the chatter comes back; at 5 and 20 the corners' iterations cycle again.
pub const LAG_CAP: f64 = 2.0;

impl PrakashClifton {
    /// The normal force the friction bound is drawn with: `followed` (N*), at most
    /// [`LAG_CAP`] x the contact's `normal`.
    pub fn bound_normal(followed: f64, normal: f64) -> f64 {
        followed.min(LAG_CAP * normal)
    }

    /// One step of the law at a node: moves the node's N* (`followed`; `None` before its first
    /// step, when it starts at the contact's `normal`, a state at rest) on by `dt` and returns
    /// the normal force the friction bound is drawn with ([`Self::bound_normal`]).
    pub fn step(&self, followed: &mut Option<f64>, normal: f64, slip_rate: f64, dt: f64) -> f64 {
        let now = followed.map_or(normal, |before| self.follow(before, normal, slip_rate, dt));
        *followed = Some(now);
        Self::bound_normal(now, normal)
    }

    /// N* a step `dt` on from `before`, with the contact's normal force `normal` and the slip
    /// rate `slip_rate` held over the step: the law's equation solved exactly, so it is stable
    /// at any step and gives Coulomb's N* = N as `length` goes to zero.
    pub fn follow(&self, before: f64, normal: f64, slip_rate: f64, dt: f64) -> f64 {
        let decay = (-(slip_rate.abs() + self.velocity) * dt / self.length).exp();
        normal + (before - normal) * decay
    }
}

/// What one frictional interface's contact did over the dynamic stage (its pieces between
/// substructures summed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContactActivity {
    pub interface: String,
    pub friction: f64,
    /// against a rigid wall (where `ILL_POSED_FRICTION` is derived), not between two bodies
    pub rigid_wall: bool,
    /// nodes in contact at some step
    pub contact_nodes: usize,
    /// the first time a node in contact slides (s), if one does
    pub first_slip_time: Option<f64>,
    /// landings of nodes that had lifted off, once the interface slides (summed over nodes)
    pub landings_while_sliding: usize,
    /// the interface's largest total normal force over the sliding phase against its mean there
    pub peak_normal_force_ratio: f64,
    /// it slides on a rigid wall with a friction coefficient above `ILL_POSED_FRICTION`
    pub ill_posed: bool,
}

impl ContactActivity {
    /// What it did while it slid, in words: evidence, not a verdict (answers with landings
    /// while sliding converge slowly in dt and h).
    pub fn evidence(&self) -> String {
        format!(
            "contact '{}' slides from t = {:.3e} s; its nodes lifted off and landed {} times while it slid, \
             the normal force peaking at {:.1} x its mean",
            self.interface,
            self.first_slip_time.unwrap_or(0.0),
            self.landings_while_sliding,
            self.peak_normal_force_ratio
        )
    }

    /// The warning a user reads, with its evidence.
    pub fn warning(&self) -> Option<String> {
        self.ill_posed.then(|| {
            format!(
                "interface '{}' slides on a rigid wall at friction {}: above {} the sliding of an elastic body is ill-posed \
                 (surface waves grow at a rate proportional to their wavenumber, docs/verification.md 4d), so this answer \
                 moves as the mesh and the time step are refined and no tolerance bounds that; while it slid its contact \
                 nodes lifted off and landed {} times, the total normal force peaking at {:.1} x its mean",
                self.interface,
                self.friction,
                ILL_POSED_FRICTION,
                self.landings_while_sliding,
                self.peak_normal_force_ratio
            )
        })
    }
}

/// A slide chatters when its contact nodes lifted off and landed while it slid at least this many
/// times each on average. Measured on issue 30's blocks (docs/notebook/2026-11-29.md, "A slide
/// that chatters says so"): 62 to 880 landings on 5 to 45 nodes wherever the answer moved with
/// the time step; 4 on 9 nodes at f = 1 and none on the shipped scenes, whose answers settle.
pub const CHATTER_LANDINGS_PER_NODE: usize = 1;

impl ContactActivity {
    /// Its nodes lifted off and landed while it slid, [`CHATTER_LANDINGS_PER_NODE`] times each or
    /// more: a slide whose answer moves with the time step by more than any iteration tolerance
    /// bounds (docs/verification.md 4d).
    pub fn chatters(&self) -> bool {
        self.contact_nodes > 0 && self.landings_while_sliding >= CHATTER_LANDINGS_PER_NODE * self.contact_nodes
    }

    /// The warning a user reads where the slide chatters (and is not ill-posed, whose warning
    /// says more), with its evidence and what to do.
    pub fn chatter_warning(&self) -> Option<String> {
        (self.chatters() && !self.ill_posed).then(|| {
            format!(
                "interface '{}' chatters while it slides: its {} contact nodes lifted off and landed {} times, the total \
                 normal force peaking at {:.1} x its mean. Such an answer, its normal force above all, moves with the \
                 time step by more than the tolerance bounds and need not settle as dt falls (docs/verification.md 4d: \
                 a block of ours slid 1.6 %, 6.9 % and 9.0 % further at dt / 2, dt / 4 and dt / 10); measure it \
                 (glissade-worker refine --dt 1,2,4, or solve to an accuracy) or damp it with a Prakash-Clifton law \
                 (docs/scenes.md)",
                self.interface, self.contact_nodes, self.landings_while_sliding, self.peak_normal_force_ratio
            )
        })
    }

    /// The warning of either kind: ill-posed, else chattering.
    pub fn any_warning(&self) -> Option<String> {
        self.warning().or_else(|| self.chatter_warning())
    }
}

impl ContactActivity {
    /// Whether it is a report the solver could have made: numbers finite and not negative, the
    /// name a short single line.
    pub fn check(&self) -> Result<(), ContactReportError> {
        let name = &self.interface;
        if name.is_empty() || name.len() > 256 || name.chars().any(char::is_control) {
            return Err(ContactReportError::Name);
        }
        let numbers = [self.friction, self.peak_normal_force_ratio, self.first_slip_time.unwrap_or(0.0)];
        if numbers.iter().any(|x| !x.is_finite() || *x < 0.0) {
            return Err(ContactReportError::Numbers { interface: name.clone() });
        }
        if self.ill_posed && !(self.rigid_wall && self.friction > ILL_POSED_FRICTION) {
            return Err(ContactReportError::IllPosed { interface: name.clone() });
        }
        Ok(())
    }
}

/// A contact report the solver could not have made ([`ContactActivity::check`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ContactReportError {
    #[error("contact: an interface name must be 1 to 256 characters, on one line")]
    Name,
    #[error("contact on '{interface}': friction, times and ratios must be finite and not negative")]
    Numbers { interface: String },
    #[error("contact on '{interface}': ill_posed only on a rigid wall above friction {above}", above = ILL_POSED_FRICTION)]
    IllPosed { interface: String },
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A slide chatters from one landing per contact node while it slides; an ill-posed one is
    /// warned of as such, once; a contact that never touched does not chatter.
    #[test]
    fn a_slide_chatters_from_one_landing_a_node() {
        let report = |nodes: usize, landings: usize, ill_posed: bool| ContactActivity {
            interface: "floor".into(),
            friction: if ill_posed { 1.5 } else { 0.4 },
            rigid_wall: true,
            contact_nodes: nodes,
            first_slip_time: Some(3e-4),
            landings_while_sliding: landings,
            peak_normal_force_ratio: 6.5,
            ill_posed,
        };
        assert!(!report(9, 8, false).chatters() && report(9, 9, false).chatters());
        assert!(!report(0, 0, false).chatters());
        let w = report(9, 229, false).chatter_warning().expect("229 landings on 9 nodes chatter");
        assert!(w.contains("'floor' chatters") && w.contains("9 contact nodes lifted off and landed 229 times"), "{w}");
        assert!(w.contains("refine --dt 1,2,4") && w.contains("6.5 x its mean"), "{w}");
        assert_eq!(report(9, 229, false).any_warning(), Some(w));
        assert_eq!(report(9, 4, false).any_warning(), None);
        let ill = report(9, 229, true);
        assert_eq!(ill.chatter_warning(), None);
        assert!(ill.any_warning().is_some_and(|w| w.contains("ill-posed")));
    }

    /// The law's step is its equation's exact solution: constant inputs relax N* exponentially
    /// at the rate (|V| + V*) / L, two half steps make one step, and a vanishing length is
    /// Coulomb's law (N* = N at once).
    #[test]
    fn the_followed_normal_force_relaxes_at_the_laws_rate() {
        let law = PrakashClifton { length: 2e-5, velocity: 0.5 };
        let (before, normal, slip_rate, dt) = (3.0, 1.0, -1.5, 1e-5);
        let exact = normal + (before - normal) * (-(1.5 + 0.5) * dt / 2e-5f64).exp();
        assert!((law.follow(before, normal, slip_rate, dt) - exact).abs() < 1e-14);
        let half = law.follow(law.follow(before, normal, slip_rate, dt / 2.0), normal, slip_rate, dt / 2.0);
        assert!((half - exact).abs() < 1e-14, "{half} against {exact}");
        let coulomb = PrakashClifton { length: 1e-300, velocity: 0.5 };
        assert_eq!(coulomb.follow(before, normal, 0.0, dt), normal);
        assert_eq!(law.follow(before, normal, 0.0, 0.0), before, "no time, no change");
        // the bound is drawn with N*, at most LAG_CAP x N
        assert_eq!(PrakashClifton::bound_normal(3.0, 1.0), LAG_CAP);
        assert_eq!(PrakashClifton::bound_normal(1.5, 1.0), 1.5);
        assert_eq!(PrakashClifton::bound_normal(1.5, 0.0), 0.0, "no contact force, no friction");
    }
}
