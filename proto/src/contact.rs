//! A contact report (`glissade_core::contact::ContactActivity`) on the wire: out as the solver
//! made it, in checked, as from a client that is not ours.

use glissade_core::contact::{ContactActivity, ContactReportError};

use crate::v1;

impl From<&ContactActivity> for v1::ContactActivity {
    fn from(a: &ContactActivity) -> Self {
        Self {
            interface: a.interface.clone(),
            friction: a.friction,
            rigid_wall: a.rigid_wall,
            contact_nodes: u32::try_from(a.contact_nodes).unwrap_or(u32::MAX),
            first_slip_time: a.first_slip_time,
            landings_while_sliding: u32::try_from(a.landings_while_sliding).unwrap_or(u32::MAX),
            peak_normal_force_ratio: a.peak_normal_force_ratio,
            ill_posed: a.ill_posed,
            chatters: a.chatters(),
        }
    }
}

impl TryFrom<v1::ContactActivity> for ContactActivity {
    /// what is wrong with it, for the client
    type Error = ContactReportError;

    fn try_from(m: v1::ContactActivity) -> Result<Self, ContactReportError> {
        let a = ContactActivity {
            interface: m.interface,
            friction: m.friction,
            rigid_wall: m.rigid_wall,
            contact_nodes: m.contact_nodes as usize,
            first_slip_time: m.first_slip_time,
            landings_while_sliding: m.landings_while_sliding as usize,
            peak_normal_force_ratio: m.peak_normal_force_ratio,
            ill_posed: m.ill_posed,
        };
        a.check()?;
        Ok(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report() -> ContactActivity {
        ContactActivity {
            interface: "floor".into(),
            friction: 1.5,
            rigid_wall: true,
            contact_nodes: 5,
            first_slip_time: Some(4.2e-5),
            landings_while_sliding: 24,
            peak_normal_force_ratio: 14.9,
            ill_posed: true,
        }
    }

    #[test]
    fn a_report_goes_out_and_comes_back_the_same() {
        let a = report();
        assert_eq!(ContactActivity::try_from(v1::ContactActivity::from(&a)), Ok(a));
    }

    /// What a client that is not ours may send: refused, saying what is wrong.
    #[test]
    fn a_report_the_solver_could_not_have_made_is_refused() {
        let out = v1::ContactActivity::from(&report());
        type Spoil = fn(&mut v1::ContactActivity);
        let cases: [(&str, Spoil); 5] = [
            ("name", |m| m.interface = "x".repeat(300)),
            ("name", |m| m.interface = "a\nb".into()),
            ("finite", |m| m.peak_normal_force_ratio = f64::NAN),
            ("finite", |m| m.first_slip_time = Some(-1.0)),
            ("ill_posed", |m| m.friction = 0.5),
        ];
        for (word, spoil) in cases {
            let mut m = out.clone();
            spoil(&mut m);
            let e = ContactActivity::try_from(m).expect_err(word).to_string();
            assert!(e.contains(word), "{e}");
        }
    }
}
