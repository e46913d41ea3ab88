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
        let QoiValues { blocks, values: series, outside } = out;
        blocks.clear();
        // Interface QoIs: computed by each interface's owner, as blocks of steps + 1 values
        // (one block per part for forces), then summed over ranks.
        for (q, qoi) in m.qois.iter().enumerate() {
            match qoi.target {
                QoiTarget::Slip { interface, node, component } => {
                    if self.dist.owns_interface(interface) {
                        slip_history(m, &fields[interface], interface, node, component, blocks);
                    } else {
                        blocks.extend(std::iter::repeat_n(0.0, len));
                    }
                }
                QoiTarget::Force { ref interfaces, component } => {
                    for i in interfaces.clone() {
                        if !self.dist.owns_interface(i) {
                            blocks.extend(std::iter::repeat_n(0.0, len));
                            continue;
                        }
                        let itf = &m.interfaces[i];
                        let n = itf.n_nodes();
                        let resultant = |force: &[f64], step: usize| -> f64 {
                            (0..n).map(|j| itf.area[j] * force[(step * n + j) * D + component]).sum::<f64>()
                        };
                        blocks.push(statics.map_or(0.0, |st| resultant(&st.interfaces[i].hat[0].force, 0)));
                        blocks.extend((0..m.steps).map(|step| resultant(&fields[i].hat[0].force, step)));
                    }
                }
                _ => blocks.extend_from_slice(&body.values[q]),
            }
        }
        // Area-weighted sums of squares over every side, step and node of the local-stage
        // velocities, forces and static displacements, and the area they cover.
        // One block of five per interface, from its owner, added up in interface order after
        // the reduction (as eta's parts: the result does not depend on the ranks).
        // In a window, a side's sums over the steps outside it are taken at its first iteration
        // and kept (0 over the whole interval, where the sums are those of every step in order).
        let whole = steps.start == 0 && steps.end >= m.steps;
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
                        let out = |parts: [&[f64]; 2]| parts.iter().map(|p| weighted(p)).sum::<f64>();
                        kept.push([out(vel_out), out(force_out)]);
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
        for (qoi, values) in m.qois.iter().zip(series.iter_mut()) {
            let parts = match qoi.target {
                QoiTarget::Force { ref interfaces, .. } => interfaces.len(),
                _ => 1,
            };
            values.clear();
            values.resize(len, 0.0);
            for part in blocks[at..at + parts * len].chunks(len) {
                for (v, p) in values.iter_mut().zip(part) {
                    *v += p;
                }
            }
            at += parts * len;
        }
        scales
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

/// Slip at an interface node: the tangential part of its sides' relative displacement
/// ([`relative_displacement`]); its norm, or its `component` along an axis, with its sign;
/// appended to `out` (steps + 1 values).
pub(super) fn slip_history<const D: usize>(
    m: &Model<D>,
    f: &InterfaceField,
    interface: usize,
    node: usize,
    component: Option<usize>,
    out: &mut Vec<f64>,
) {
    let nrm = m.interfaces[interface].normal[node];
    for rel in relative_displacement(m, f, interface, node) {
        let rn: f64 = (0..D).map(|c| rel[c] * nrm[c]).sum();
        let slip: [f64; D] = std::array::from_fn(|c| rel[c] - rn * nrm[c]);
        out.push(match component {
            Some(c) => slip[c],
            None => slip.iter().map(|x| x * x).sum::<f64>().sqrt(),
        });
    }
}
