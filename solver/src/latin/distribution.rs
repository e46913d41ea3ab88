//! Which rank holds what: substructures in contiguous blocks balanced by dof count (substructures
//! are numbered body by body, lexicographically in space, so blocks keep neighbours together),
//! each interface owned by the rank of its first side (the pieces of a wall interface that share
//! nodes, by the first piece's). Interface fields cross ranks only between an interface's owner
//! and the ranks of its sides.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;

use crate::comm::{Communicator, exchange};
use crate::model::Model;

use glissade_core::field::InterfaceField;

/// The rank of each of `weights.len()` substructures (at least `size`) in contiguous blocks
/// balanced by weight: each to the rank of its weight's midpoint, stepping by at most one rank
/// and leaving at least one substructure to every remaining rank.
pub fn contiguous_blocks(weights: &[f64], size: usize) -> Vec<usize> {
    let n = weights.len();
    let total: f64 = weights.iter().sum();
    let mut rank: Vec<usize> = Vec::with_capacity(n);
    let mut before = 0.0;
    for (s, w) in weights.iter().enumerate() {
        let ideal = (((before + 0.5 * w) / total) * size as f64) as usize;
        let previous = rank.last().copied().unwrap_or(0);
        let lo = previous.max((size + s).saturating_sub(n));
        let hi = if s == 0 { 0 } else { (previous + 1).min(size - 1) };
        rank.push(ideal.clamp(lo, hi.max(lo)));
        before += w;
    }
    rank
}

#[derive(Debug, Clone)]
pub struct Distribution {
    pub rank: usize,
    pub size: usize,
    /// rank of each substructure
    pub substructure_rank: Vec<usize>,
    /// rank owning each interface (runs its local stage)
    pub interface_rank: Vec<usize>,
    /// ranks sharing at least one interface with this one
    pub neighbours: BTreeSet<usize>,
}

impl Distribution {
    /// Balanced contiguous blocks; `size` must not exceed the number of substructures.
    pub fn new<const D: usize>(model: &Model<D>, rank: usize, size: usize) -> Result<Self, String> {
        let n = model.substructures.len();
        if size > n {
            return Err(format!("{size} ranks for {n} substructures: use at most {n} ranks"));
        }
        let dofs: Vec<f64> = model.substructures.iter().map(|s| s.n_dofs() as f64).collect();
        let substructure_rank = contiguous_blocks(&dofs, size);
        let mut interface_rank: Vec<usize> =
            model.interfaces.iter().map(|itf| substructure_rank[itf.sides[0].substructure]).collect();
        // the pieces of a wall interface that share a node are owned together (the local stage
        // applies the law to the node's copies at once): by the owner of the first of them
        let mut first: Vec<usize> = (0..model.interfaces.len()).collect();
        let root = |first: &[usize], mut i: usize| {
            while first[i] != i {
                i = first[i];
            }
            i
        };
        for group in &model.shared_wall_nodes {
            for &(i, _) in group {
                let (a, b) = (root(&first, group[0].0), root(&first, i));
                first[a.max(b)] = a.min(b);
            }
        }
        for i in 0..interface_rank.len() {
            interface_rank[i] = interface_rank[root(&first, i)];
        }
        let mut neighbours = BTreeSet::new();
        for (itf, &owner) in model.interfaces.iter().zip(&interface_rank) {
            let mut ranks: Vec<usize> = itf.sides.iter().map(|s| substructure_rank[s.substructure]).collect();
            ranks.push(owner);
            if ranks.contains(&rank) {
                neighbours.extend(ranks.into_iter().filter(|&r| r != rank));
            }
        }
        Ok(Self { rank, size, substructure_rank, interface_rank, neighbours })
    }

    pub fn owns_substructure(&self, s: usize) -> bool {
        self.substructure_rank[s] == self.rank
    }

    pub fn owns_interface(&self, i: usize) -> bool {
        self.interface_rank[i] == self.rank
    }

    /// Whether this rank keeps fields of interface `i` (it owns it or holds one of its sides).
    pub fn holds_interface<const D: usize>(&self, model: &Model<D>, i: usize) -> bool {
        self.owns_interface(i) || model.interfaces[i].sides.iter().any(|s| self.owns_substructure(s.substructure))
    }

    /// Sends each remote side's `s` fields to the interface owner (after the linear stage).
    pub fn send_sides_to_owners<const D: usize>(
        &self,
        comm: &dyn Communicator,
        model: &Model<D>,
        fields: &mut [InterfaceField],
        steps: Range<usize>,
    ) {
        self.transfer(comm, model, fields, steps, true);
    }

    /// Sends the owners' local-stage fields back to each remote side (after the local stage).
    pub fn send_hats_to_sides<const D: usize>(
        &self,
        comm: &dyn Communicator,
        model: &Model<D>,
        fields: &mut [InterfaceField],
        steps: Range<usize>,
    ) {
        self.transfer(comm, model, fields, steps, false);
    }

    fn transfer<const D: usize>(
        &self,
        comm: &dyn Communicator,
        model: &Model<D>,
        fields: &mut [InterfaceField],
        steps: Range<usize>,
        to_owner: bool,
    ) {
        if self.size == 1 {
            return;
        }
        // (interface, side, from, to) in a fixed order both ends agree on
        let moves: Vec<(usize, usize, usize, usize)> = model
            .interfaces
            .iter()
            .enumerate()
            .flat_map(|(i, itf)| {
                let owner = self.interface_rank[i];
                itf.sides.iter().enumerate().filter_map(move |(k, s)| {
                    let side_rank = self.substructure_rank[s.substructure];
                    (side_rank != owner).then_some(if to_owner {
                        (i, k, side_rank, owner)
                    } else {
                        (i, k, owner, side_rank)
                    })
                })
            })
            .collect();
        // the values of the steps moved (a time window's, or all), by interface
        let window = |i: usize| {
            let per_step = model.interfaces[i].n_nodes() * D;
            steps.start * per_step..steps.end * per_step
        };
        let mut outgoing: BTreeMap<usize, Vec<f64>> = self.neighbours.iter().map(|&q| (q, Vec::new())).collect();
        for &(i, k, from, to) in &moves {
            if from == self.rank {
                let f = if to_owner { &fields[i].s[k] } else { &fields[i].hat[k] };
                let r = window(i);
                let buf = outgoing.get_mut(&to).expect("the receiver is a neighbour");
                buf.extend_from_slice(&f.force[r.clone()]);
                buf.extend_from_slice(&f.velocity[r]);
            }
        }
        let incoming = exchange(comm, outgoing);
        let mut cursor: BTreeMap<usize, usize> = BTreeMap::new();
        for &(i, k, from, to) in &moves {
            if to == self.rank {
                let buf = &incoming[&from];
                let at = cursor.entry(from).or_insert(0);
                let f = if to_owner { &mut fields[i].s[k] } else { &mut fields[i].hat[k] };
                let r = window(i);
                let len = r.len();
                f.force[r.clone()].copy_from_slice(&buf[*at..*at + len]);
                f.velocity[r].copy_from_slice(&buf[*at + len..*at + 2 * len]);
                *at += 2 * len;
            }
        }
    }

    /// Gathers every interface's fields on rank 0 from their owners (for output and storage).
    pub fn gather_interfaces(&self, comm: &dyn Communicator, fields: &mut [InterfaceField]) {
        if self.size == 1 {
            return;
        }
        let pack = |f: &InterfaceField, buf: &mut Vec<f64>| {
            for side in f.s.iter().chain(&f.hat) {
                buf.extend_from_slice(&side.force);
                buf.extend_from_slice(&side.velocity);
            }
        };
        for r in 1..self.size {
            let owned: Vec<usize> = (0..fields.len()).filter(|&i| self.interface_rank[i] == r).collect();
            if self.rank == r {
                let mut buf = Vec::new();
                for &i in &owned {
                    pack(&fields[i], &mut buf);
                }
                comm.send(0, &buf);
            } else if self.rank == 0 {
                let buf = comm.receive(r);
                let mut at = 0;
                for &i in &owned {
                    let f = &mut fields[i];
                    for side in f.s.iter_mut().chain(f.hat.iter_mut()) {
                        let len = side.force.len();
                        side.force.copy_from_slice(&buf[at..at + len]);
                        side.velocity.copy_from_slice(&buf[at + len..at + 2 * len]);
                        at += 2 * len;
                    }
                }
            }
        }
    }
}
