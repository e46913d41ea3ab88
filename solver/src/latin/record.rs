//! What the iterations record for the user: the QoIs' histories (from the interface fields and
//! the body QoIs each linear stage records), the fields' histories, the post-processing sweep.

use super::*;

impl<'m, const D: usize> LatinSolver<'m, D> {
    /// Moves every substructure's field history to rank 0.
    pub(super) fn gather_field_history(&self, h: &mut FieldHistory) {
        let (comm, dist, m) = (self.comm, &self.dist, self.model);
        for r in 1..dist.size {
            let subs: Vec<usize> = (0..m.substructures.len()).filter(|&s| dist.substructure_rank[s] == r).collect();
            if dist.rank == r {
                let mut buf = Vec::new();
                for &s in &subs {
                    for step in h.displacement[s].iter().chain(&h.velocity[s]) {
                        buf.extend_from_slice(step);
                    }
                }
                comm.send(0, &buf);
            } else if dist.rank == 0 {
                let buf = comm.receive(r);
                let mut at = 0;
                for &s in &subs {
                    let n = m.substructures[s].n_dofs();
                    let mut take = || {
                        let v = buf[at..at + n].to_vec();
                        at += n;
                        v
                    };
                    h.displacement[s] = (0..=m.steps).map(|_| take()).collect();
                    h.velocity[s] = (0..=m.steps).map(|_| take()).collect();
                }
            }
        }
    }

    /// Final sweep of every substructure on the converged fields: QoI series and, if asked,
    /// every node's history.
    pub(super) fn post_process(
        &mut self,
        fields: &[InterfaceField],
        u0: &[Option<Vec<f64>>],
        statics: Option<&StageSolution>,
        options: &SolveOptions,
    ) -> (Vec<QoiSeries>, Option<FieldHistory>) {
        let m = self.model;
        let mut history = options.record_fields.then(FieldHistory::default);
        // The sweep writes `s` fields: run it on a copy so the returned solution stays the
        // converged iterate.
        let mut scratch = fields.to_vec();
        let mut body = BodyQois::new(m);
        let n_sub = m.substructures.len();
        if let Some(h) = history.as_mut() {
            h.displacement = vec![Vec::with_capacity(m.steps + 1); n_sub];
            h.velocity = vec![Vec::with_capacity(m.steps + 1); n_sub];
        }
        let mut record = |s: usize, step: usize, u: &[f64], v: &[f64]| {
            body.record(s, step, u, v);
            if let Some(h) = history.as_mut() {
                h.displacement[s].push(u.to_vec());
                h.velocity[s].push(v.to_vec());
            }
        };
        self.linear_stage(Stage::Dynamic, &mut scratch, u0, Some(&mut record), 0..m.steps, None);
        let series = self.qoi_series(fields, statics, &body);
        if let Some(h) = history.as_mut() {
            self.gather_field_history(h);
        }
        (series, history)
    }

    /// Every QoI's history from the local-stage fields (slips, forces) and the substructure
    /// values a linear stage recorded (displacements, velocities), reduced over ranks: one
    /// contribution per value, so every rank gets the same series.
    pub(super) fn qoi_series(
        &self,
        fields: &[InterfaceField],
        statics: Option<&StageSolution>,
        body: &BodyQois,
    ) -> Vec<QoiSeries> {
        let m = self.model;
        let mut out = QoiValues::default();
        self.qoi_values(fields, statics, body, &(0..m.steps), &mut out);
        // (as decimals: 2e-5, not 1.9999999999999998e-5)
        let times: Vec<f64> = (0..=m.steps).map(|n| glissade_core::text::decimal(n as f64 * m.dt)).collect();
        m.qois
            .iter()
            .zip(out.values)
            .map(|(qoi, values)| QoiSeries { name: qoi.name.clone(), times: times.clone(), values })
            .collect()
    }

    /// [`Self::qoi_series`]'s values, into `out`'s buffers, and the interface fields' own scales,
    /// in one reduction.
    /// `steps`: the window iterated (the fields outside it do not change while it is, so their
    /// sums are taken once a window: [`QoiValues::new_window`]).
    pub(super) fn qoi_values(
        &self,
        fields: &[InterfaceField],
        statics: Option<&StageSolution>,
        body: &BodyQois,
        steps: &Range<usize>,
        out: &mut QoiValues,
    ) -> UnitScales {
        let m = self.model;
        let len = m.steps + 1;
        let whole = steps.start == 0 && steps.end >= m.steps;
        let QoiValues { blocks, values: series, outside, before, slips_before, computed } = out;
        // The values a window's iterations may change are its own, `steps.start + 1 ..=
        // steps.end`: after its first call only those are computed (over every step, the QoIs
        // took most of a solve in windows of one step); over the whole interval, all.
        let sized = series.len() == m.qois.len() && series.iter().all(|v| v.len() > steps.end.min(m.steps));
        let values = match (whole, outside.is_some() && sized) {
            (true, _) => 0..len,
            (false, false) => 0..steps.end.min(m.steps) + 1,
            (false, true) => steps.start + 1..steps.end.min(m.steps) + 1,
        };
        let first = values.start == 0;
        let width = values.len();
        blocks.clear();
        self.qoi_blocks(fields, statics, body, (steps.start, &values), slips_before, blocks);
        // Area-weighted sums of squares over every side, step and node of the local-stage
        // velocities, forces and static displacements, and the area they cover.
        // One block of five per interface, from its owner, added up in interface order after
        // the reduction (as eta's parts: the result does not depend on the ranks).
        // In a window, a side's sums over the steps outside it are taken at its first iteration
        // and kept (0 over the whole interval, where the sums are those of every step in order).
        let fresh = outside.is_none();
        let kept = outside.get_or_insert_with(Vec::new);
        let mut side_at = 0;
        for (i, itf) in m.interfaces.iter().enumerate() {
            let mut sums = [0.0; 5];
            if self.dist.owns_interface(i) {
                let n = itf.n_nodes();
                // (a slice that begins at a step: the node of value x is (x / D) % n)
                let weighted =
                    |v: &[f64]| -> f64 { v.iter().enumerate().map(|(x, y)| itf.area[(x / D) % n] * y * y).sum() };
                let inside = if whole { 0..usize::MAX } else { steps.start * n * D..steps.end * n * D };
                for (k, side) in fields[i].hat.iter().enumerate() {
                    let ((vel, vel_out), (force, force_out)) =
                        (split_window(&side.velocity, &inside), split_window(&side.force, &inside));
                    if fresh {
                        // the sums before the window continue those the last window began with,
                        // over the values converged since (the same additions in the same order)
                        let to = vel_out[0].len();
                        if before.len() <= side_at {
                            before.push((0, [-0.0; 2]));
                        }
                        let (from, sums) = &mut before[side_at];
                        if *from > to {
                            (*from, *sums) = (0, [-0.0; 2]);
                        }
                        for (sum, v) in sums.iter_mut().zip([&side.velocity, &side.force]) {
                            *sum = v[*from..to]
                                .iter()
                                .enumerate()
                                .fold(*sum, |a, (x, y)| a + itf.area[((*from + x) / D) % n] * y * y);
                        }
                        *from = to;
                        let out = |sum: f64, after: &[f64]| [sum, weighted(after)].into_iter().sum::<f64>();
                        kept.push([out(sums[0], vel_out[1]), out(sums[1], force_out[1])]);
                    }
                    let [vel_outside, force_outside] = kept[side_at];
                    side_at += 1;
                    sums[0] += vel_outside + weighted(vel);
                    sums[1] += force_outside + weighted(force);
                    sums[2] += statics.map_or(0.0, |st| weighted(&st.interfaces[i].hat[k].velocity));
                    sums[3] += itf.area.iter().sum::<f64>();
                    sums[4] += 1.0;
                }
            }
            blocks.extend(sums);
        }
        self.comm.sum_in_place(blocks);
        let (blocks, per_interface) = blocks.split_at(blocks.len() - 5 * m.interfaces.len());
        let sums = per_interface.chunks(5).fold([0.0; 5], |mut acc, c| {
            for (a, x) in acc.iter_mut().zip(c) {
                *a += x;
            }
            acc
        });
        let scales = UnitScales::from_sums(&sums, m.steps, m.dt);
        series.resize_with(m.qois.len(), Vec::new);
        let mut at = 0;
        for (qoi, series) in m.qois.iter().zip(series.iter_mut()) {
            let parts = match qoi.target {
                QoiTarget::Force { ref interfaces, .. } => interfaces.len(),
                _ => 1,
            };
            if first {
                series.clear();
                series.resize(values.end, 0.0);
            }
            let mine = &mut series[values.clone()];
            mine.fill(0.0);
            for part in blocks[at..at + parts * width].chunks(width) {
                for (v, p) in mine.iter_mut().zip(part) {
                    *v += p;
                }
            }
            at += parts * width;
        }
        *computed = values;
        scales
    }

    /// The QoIs' `values` (indices from 0, the initial state), as blocks of `values.len()` (one
    /// block per part for forces) for the reduction over ranks: the interface QoIs from their
    /// owner, zeros elsewhere; the body QoIs from `body`. A slip sums every step before: its
    /// relative displacement at `first_step` (the window's first value) is kept in `slips_before`
    /// at a call from value 0 and taken up at the later ones.
    fn qoi_blocks(
        &self,
        fields: &[InterfaceField],
        statics: Option<&StageSolution>,
        body: &BodyQois,
        (first_step, values): (usize, &Range<usize>),
        slips_before: &mut Vec<Vec<f64>>,
        blocks: &mut Vec<f64>,
    ) {
        let m = self.model;
        let first = values.start == 0;
        if first {
            slips_before.clear();
        }
        let width = values.len();
        // Interface QoIs: computed by each interface's owner, as blocks of the values computed
        // (one block per part for forces), then summed over ranks.
        let mut slip = 0;
        for (q, qoi) in m.qois.iter().enumerate() {
            match qoi.target {
                QoiTarget::Slip { interface, node, component } => {
                    if self.dist.owns_interface(interface) {
                        // (the relative displacement at the window's first value, kept from its
                        // first call: a slip sums every step before)
                        let before = slips_before
                            .get(slip)
                            .filter(|b| b.len() == D)
                            .map_or([0.0; D], |b| std::array::from_fn(|c| b[c]));
                        let rel =
                            relative_displacement_over(m, &fields[interface], interface, node, values.clone(), before);
                        if first {
                            slips_before.push(rel.get(first_step).map_or(vec![0.0; D], |r| r.to_vec()));
                        }
                        slip_history::<D>(m, interface, node, component, &rel, blocks);
                    } else {
                        if first {
                            slips_before.push(Vec::new());
                        }
                        blocks.extend(std::iter::repeat_n(0.0, width));
                    }
                    slip += 1;
                }
                QoiTarget::Force { ref interfaces, component } => {
                    for i in interfaces.clone() {
                        if !self.dist.owns_interface(i) {
                            blocks.extend(std::iter::repeat_n(0.0, width));
                            continue;
                        }
                        let itf = &m.interfaces[i];
                        let n = itf.n_nodes();
                        let resultant = |force: &[f64], step: usize| -> f64 {
                            (0..n).map(|j| itf.area[j] * force[(step * n + j) * D + component]).sum::<f64>()
                        };
                        // value 0 is the prestress's, value j the end of step j - 1
                        blocks.extend(values.clone().map(|value| match value {
                            0 => statics.map_or(0.0, |st| resultant(&st.interfaces[i].hat[0].force, 0)),
                            _ => resultant(&fields[i].hat[0].force, value - 1),
                        }));
                    }
                }
                _ => blocks.extend_from_slice(&body.values[q][values.clone()]),
            }
        }
    }
}

/// The values of `v` in `inside` (clamped to it), and those before and after.
fn split_window<'v>(v: &'v [f64], inside: &Range<usize>) -> (&'v [f64], [&'v [f64]; 2]) {
    let (from, to) = (inside.start.min(v.len()), inside.end.min(v.len()));
    (&v[from..to], [&v[..from], &v[to..]])
}

/// The QoIs' histories, `[qoi][step]`, and the blocks of values they are reduced from.
#[derive(Default)]
pub(super) struct QoiValues {
    pub(super) blocks: Vec<f64>,
    pub(super) values: Vec<Vec<f64>>,
    /// per interface side this rank owns, its fields' sums (velocity, force) over the steps
    /// outside the window iterated (summed again at every iteration, they took 41 % of a
    /// windowed solve's time at 2000 steps)
    outside: Option<Vec<[f64; 2]>>,
    /// per interface side this rank owns, the value its sums before the last window began at
    /// reach, and those sums (velocity, force): a window's first call continues them
    before: Vec<(usize, [f64; 2])>,
    /// per slip QoI of an interface this rank owns, the relative displacement at the window's
    /// first value (taken at its first call)
    slips_before: Vec<Vec<f64>>,
    /// the values the last call computed (those before were computed earlier in the window)
    pub(super) computed: Range<usize>,
}

impl QoiValues {
    /// A window begins (or is iterated again): the fields outside it may have changed.
    pub(super) fn new_window(&mut self) {
        self.outside = None;
    }
}

/// The displacement and velocity QoIs of this rank's substructures, recorded step by step
/// during a dynamic linear stage (zeros for the QoIs of other ranks' substructures).
#[derive(Clone)]
pub(super) struct BodyQois {
    /// (QoI, substructure, dof, displacement rather than velocity)
    pub(super) wanted: Vec<(usize, usize, usize, bool)>,
    pub(super) values: Vec<Vec<f64>>,
}

impl BodyQois {
    pub(super) fn new<const D: usize>(m: &Model<D>) -> Self {
        let wanted = m
            .qois
            .iter()
            .enumerate()
            .filter_map(|(q, qoi)| match qoi.target {
                QoiTarget::Displacement { substructure, dof } => Some((q, substructure, dof, true)),
                QoiTarget::Velocity { substructure, dof } => Some((q, substructure, dof, false)),
                _ => None,
            })
            .collect();
        Self { wanted, values: vec![vec![0.0; m.steps + 1]; m.qois.len()] }
    }

    /// Takes `from`'s values (the QoIs recorded before a window) into this one's buffers.
    pub(super) fn copy_from(&mut self, from: &BodyQois) {
        copy_rows(&mut self.values, &from.values);
    }

    pub(super) fn record(&mut self, s: usize, step: usize, u: &[f64], v: &[f64]) {
        for &(q, sub, dof, is_u) in &self.wanted {
            if sub == s {
                self.values[q][step] = if is_u { u[dof] } else { v[dof] };
            }
        }
    }
}

/// Slip at an interface node: the tangential part of its sides' relative displacement `rel`
/// ([`relative_displacement`]); its norm, or its `component` along an axis, with its sign;
/// appended to `out`, a value for each of `rel`.
pub(super) fn slip_history<const D: usize>(
    m: &Model<D>,
    interface: usize,
    node: usize,
    component: Option<usize>,
    rel: &[[f64; D]],
    out: &mut Vec<f64>,
) {
    let nrm = m.interfaces[interface].normal[node];
    for rel in rel {
        let rn: f64 = (0..D).map(|c| rel[c] * nrm[c]).sum();
        let slip: [f64; D] = std::array::from_fn(|c| rel[c] - rn * nrm[c]);
        out.push(match component {
            Some(c) => slip[c],
            None => slip.iter().map(|x| x * x).sum::<f64>().sqrt(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comm::Serial;
    use glissade_core::scene::Scene;

    /// After a window's first call, the QoIs are computed over the window's values only (the
    /// slips from the relative displacement kept at its first value): with fields changed inside
    /// the window, they are those a call over every value gives, to the bit.
    #[test]
    fn a_windows_later_calls_compute_its_values_as_a_whole_call_does() {
        let text = include_str!("../../../scenes/sliding-block-2d.toml").replace("steps = 100", "steps = 40");
        let scene = Scene::parse(&text).expect("scene");
        let values = scene.parameter_values(&Default::default()).expect("defaults");
        let model = Model::<2>::build(&scene, &values).expect("model");
        let solver = LatinSolver::new(&model, &Serial).expect("solver");
        // fields that vary over steps, nodes and sides
        let mut fields: Vec<InterfaceField> =
            model.interfaces.iter().map(|itf| InterfaceField::zeros(itf.sides.len(), 40 * itf.n_nodes() * 2)).collect();
        let wave = |x: usize, k: usize, bump: f64| ((x as f64) * 0.37 + k as f64).sin() * (1.0 + bump);
        let fill = |fields: &mut [InterfaceField], from: usize, bump: f64| {
            for f in fields.iter_mut() {
                let per_step = f.hat[0].velocity.len() / 40;
                for (k, side) in f.hat.iter_mut().enumerate() {
                    for x in from * per_step..side.velocity.len() {
                        side.velocity[x] = wave(x, k, bump);
                        side.force[x] = 1e6 * wave(x + 3, k, bump);
                    }
                }
            }
        };
        fill(&mut fields, 0, 0.0);
        let window = 12..20;
        let body = BodyQois::new(&model);
        let mut kept = QoiValues::default();
        solver.qoi_values(&fields, None, &body, &window, &mut kept);
        assert_eq!(kept.computed, 0..21);
        let before = kept.values.clone();
        // an iteration changes the window's values (and those after it, which are not read)
        fill(&mut fields, window.start, 0.25);
        solver.qoi_values(&fields, None, &body, &window, &mut kept);
        assert_eq!(kept.computed, 13..21);
        let mut whole = QoiValues::default();
        solver.qoi_values(&fields, None, &body, &(0..40), &mut whole);
        assert!(model.qois.iter().any(|q| matches!(q.target, QoiTarget::Slip { .. })));
        for (q, (a, b)) in kept.values.iter().zip(&whole.values).enumerate() {
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a[..21]), bits(&b[..21]), "QoI {}", model.qois[q].name);
            assert!(a[13..21].iter().zip(&before[q][13..21]).all(|(x, y)| x != y), "the window's values moved");
        }
        // The fields' sums before a window continue those its last began with: the next window's
        // scales, and those of a window iterated again before it, are a fresh call's to the bit.
        for next in [20..28, 4..12, 28..40] {
            fill(&mut fields, next.start, 0.5 + next.start as f64);
            kept.new_window();
            let a = solver.qoi_values(&fields, None, &body, &next, &mut kept);
            let b = solver.qoi_values(&fields, None, &body, &next, &mut QoiValues::default());
            assert_eq!(
                [a.length, a.velocity, a.force].map(f64::to_bits),
                [b.length, b.velocity, b.force].map(f64::to_bits)
            );
            assert!(a.velocity > 0.0 && a.force > 0.0);
        }
    }
}
