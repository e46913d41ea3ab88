//! Where a distributed solve's time goes, rank by rank: a [`Communicator`] that times every
//! operation it forwards, and the gathered [`Profile`] that splits each rank's wall time into
//! compute, waiting at collectives, their transfer, and point-to-point exchanges.
//!
//! Every rank calls the same collectives in the same order (the solver is SPMD), so the k-th
//! collective is one synchronisation of all ranks. The rank that arrives last waits for nobody:
//! its time in the call is the transfer itself, and every other rank's excess over it is waiting.
//! The compute between two collectives tells imbalance (the same rank always last) from jitter
//! (the slowest rank changes from one synchronisation to the next).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use crate::comm::Communicator;

/// One collective as a rank saw it.
#[derive(Debug, Clone, Copy)]
struct Collective {
    /// values reduced (f64s) or bytes broadcast
    len: usize,
    broadcast: bool,
    /// compute since the previous communication ended
    compute_before: f64,
    /// time inside the call
    seconds: f64,
}

#[derive(Debug, Default)]
struct Log {
    collectives: Vec<Collective>,
    /// when the last communication call returned
    last_end: Option<Instant>,
    messages_sent: u64,
    bytes_sent: u64,
    messages_received: u64,
    bytes_received: u64,
    exchange_seconds: f64,
}

/// A communicator that times what it forwards to `inner`.
pub struct Profiled<'a> {
    inner: &'a dyn Communicator,
    start: Instant,
    log: RefCell<Log>,
}

impl<'a> Profiled<'a> {
    /// Starts the clock: the profile's wall time runs from here to [`Self::finish`].
    pub fn new(inner: &'a dyn Communicator) -> Self {
        Self { inner, start: Instant::now(), log: RefCell::new(Log::default()) }
    }

    fn compute_since_last(&self, log: &Log, now: Instant) -> f64 {
        (now - log.last_end.unwrap_or(self.start)).as_secs_f64()
    }

    fn collective(&self, len: impl FnOnce() -> usize, broadcast: bool, call: impl FnOnce()) {
        let begin = Instant::now();
        call();
        let end = Instant::now();
        let mut log = self.log.borrow_mut();
        let compute_before = self.compute_since_last(&log, begin);
        log.collectives.push(Collective {
            len: len(),
            broadcast,
            compute_before,
            seconds: (end - begin).as_secs_f64(),
        });
        log.last_end = Some(end);
    }

    fn point_to_point(&self, call: impl FnOnce()) {
        let begin = Instant::now();
        call();
        let end = Instant::now();
        let mut log = self.log.borrow_mut();
        log.exchange_seconds += (end - begin).as_secs_f64();
        log.last_end = Some(end);
    }

    /// Stops the clock and gathers every rank's log on rank 0 (a collective call: every rank
    /// makes it). Rank 0 gets the profile, the others `None`.
    pub fn finish(self) -> Option<Profile> {
        let wall = self.start.elapsed().as_secs_f64();
        let log = self.log.into_inner();
        let mine = RankLog::pack(&log, wall);
        let (rank, size) = (self.inner.rank(), self.inner.size());
        if rank != 0 {
            self.inner.send(0, &mine);
            return None;
        }
        let mut logs = vec![RankLog::unpack(&mine)];
        for r in 1..size {
            logs.push(RankLog::unpack(&self.inner.receive(r)));
        }
        Some(Profile::from_logs(&logs))
    }
}

impl Communicator for Profiled<'_> {
    fn rank(&self) -> usize {
        self.inner.rank()
    }
    fn size(&self) -> usize {
        self.inner.size()
    }
    fn sum_in_place(&self, values: &mut [f64]) {
        let len = values.len();
        self.collective(|| len, false, || self.inner.sum_in_place(values));
    }
    fn send(&self, to: usize, values: &[f64]) {
        self.point_to_point(|| self.inner.send(to, values));
        let mut log = self.log.borrow_mut();
        log.messages_sent += 1;
        log.bytes_sent += 8 * values.len() as u64;
    }
    fn receive(&self, from: usize) -> Vec<f64> {
        let mut out = Vec::new();
        self.point_to_point(|| out = self.inner.receive(from));
        let mut log = self.log.borrow_mut();
        log.messages_received += 1;
        log.bytes_received += 8 * out.len() as u64;
        out
    }
    fn broadcast_bytes(&self, bytes: &mut Vec<u8>) {
        let cell = RefCell::new(bytes);
        self.collective(|| cell.borrow().len(), true, || self.inner.broadcast_bytes(&mut cell.borrow_mut()));
    }
}

/// One rank's log as it travels to rank 0 (f64s: the communicator's one message type).
struct RankLog {
    wall: f64,
    exchange_seconds: f64,
    counts: [u64; 4],
    collectives: Vec<Collective>,
}

impl RankLog {
    const HEADER: usize = 6;

    fn pack(log: &Log, wall: f64) -> Vec<f64> {
        let mut v = vec![
            wall,
            log.exchange_seconds,
            log.messages_sent as f64,
            log.bytes_sent as f64,
            log.messages_received as f64,
            log.bytes_received as f64,
        ];
        for c in &log.collectives {
            let len = if c.broadcast { -(c.len as f64) - 1.0 } else { c.len as f64 };
            v.extend([len, c.compute_before, c.seconds]);
        }
        v
    }

    fn unpack(v: &[f64]) -> Self {
        let collectives = v[Self::HEADER.min(v.len())..]
            .chunks_exact(3)
            .map(|c| {
                let broadcast = c[0] < 0.0;
                let len = if broadcast { (-c[0] - 1.0) as usize } else { c[0] as usize };
                Collective { len, broadcast, compute_before: c[1], seconds: c[2] }
            })
            .collect();
        let at = |k: usize| v.get(k).copied().unwrap_or(0.0);
        Self {
            wall: at(0),
            exchange_seconds: at(1),
            counts: [at(2) as u64, at(3) as u64, at(4) as u64, at(5) as u64],
            collectives,
        }
    }
}

/// One rank's wall time, split (seconds): `compute + wait + transfer + exchange = wall`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RankProfile {
    pub rank: usize,
    pub wall: f64,
    /// outside any communication: the rank's own work
    pub compute: f64,
    /// at collectives, for the last rank to arrive
    pub wait: f64,
    /// at collectives, once every rank has arrived (the last arriver's time in the call)
    pub transfer: f64,
    /// in point-to-point sends and receives (transfer and waiting for the partner together)
    pub exchange: f64,
    pub collectives: usize,
    /// collectives at which this rank arrived last (all others waited for it)
    pub last_to_arrive: usize,
    pub messages_sent: u64,
    pub bytes_sent: u64,
    pub messages_received: u64,
    pub bytes_received: u64,
}

/// The collectives of one kind and size (the macro right-hand side reduced once a time step,
/// the error indicator's parts once an iteration, ...).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CollectiveGroup {
    /// "sum" or "broadcast"
    pub kind: &'static str,
    /// f64s summed or bytes broadcast
    pub len: usize,
    pub calls: usize,
    /// summed over the calls
    pub transfer: f64,
    /// waiting summed over the calls and the ranks
    pub wait: f64,
    /// the compute before the calls that the slowest rank of each call did beyond the ranks'
    /// mean: the wait that unequal work causes
    pub slowest_excess: f64,
}

/// Every rank's split, and what the synchronisations cost.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Profile {
    pub ranks: Vec<RankProfile>,
    pub collectives: Vec<CollectiveGroup>,
    /// the largest rank's compute over the ranks' mean (1 = balanced)
    pub imbalance: f64,
    /// sum over synchronisations of the slowest rank's compute before it, minus the largest
    /// rank's total of the same: time lost because the slowest rank changes from one
    /// synchronisation to the next (0 when it is always the same rank)
    pub jitter: f64,
}

impl Profile {
    fn from_logs(logs: &[RankLog]) -> Self {
        let p = logs.len();
        // the synchronisations every rank saw (SPMD: the same count; the shortest, were it not)
        let n = logs.iter().map(|l| l.collectives.len()).min().unwrap_or(0);
        let mut ranks: Vec<RankProfile> = logs
            .iter()
            .enumerate()
            .map(|(rank, l)| RankProfile {
                rank,
                wall: l.wall,
                compute: 0.0,
                wait: 0.0,
                transfer: 0.0,
                exchange: l.exchange_seconds,
                collectives: l.collectives.len(),
                last_to_arrive: 0,
                messages_sent: l.counts[0],
                bytes_sent: l.counts[1],
                messages_received: l.counts[2],
                bytes_received: l.counts[3],
            })
            .collect();
        let mut groups: BTreeMap<(bool, usize), CollectiveGroup> = BTreeMap::new();
        let mut before = vec![0.0; p];
        let mut slowest_sum = 0.0;
        for k in 0..n {
            let calls: Vec<&Collective> = logs.iter().map(|l| &l.collectives[k]).collect();
            let (last, transfer) = calls
                .iter()
                .enumerate()
                .map(|(r, c)| (r, c.seconds))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or((0, 0.0));
            ranks[last].last_to_arrive += 1;
            let slowest = calls.iter().map(|c| c.compute_before).fold(0.0, f64::max);
            let mean = calls.iter().map(|c| c.compute_before).sum::<f64>() / p as f64;
            slowest_sum += slowest;
            let g = groups.entry((calls[0].broadcast, calls[0].len)).or_insert_with(|| CollectiveGroup {
                kind: if calls[0].broadcast { "broadcast" } else { "sum" },
                len: calls[0].len,
                calls: 0,
                transfer: 0.0,
                wait: 0.0,
                slowest_excess: 0.0,
            });
            g.calls += 1;
            g.transfer += transfer;
            g.slowest_excess += slowest - mean;
            for (r, c) in calls.iter().enumerate() {
                ranks[r].transfer += transfer;
                ranks[r].wait += c.seconds - transfer;
                g.wait += c.seconds - transfer;
                before[r] += c.compute_before;
            }
        }
        for (r, l) in logs.iter().enumerate() {
            // collectives a rank made beyond the common count (none in an SPMD solve) count whole
            let extra: f64 = l.collectives[n..].iter().map(|c| c.seconds).sum();
            ranks[r].transfer += extra;
            let rp = &mut ranks[r];
            rp.compute = rp.wall - rp.wait - rp.transfer - rp.exchange;
        }
        let computes: Vec<f64> = ranks.iter().map(|r| r.compute).collect();
        let mean = computes.iter().sum::<f64>() / p.max(1) as f64;
        let imbalance = if mean > 0.0 { computes.iter().fold(0.0, |a: f64, &b| a.max(b)) / mean } else { 1.0 };
        let jitter = (slowest_sum - before.iter().fold(0.0, |a: f64, &b| a.max(b))).max(0.0);
        Self { ranks, collectives: groups.into_values().collect(), imbalance, jitter }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log(collectives: &[(usize, f64, f64)], wall: f64, exchange: f64) -> RankLog {
        RankLog {
            wall,
            exchange_seconds: exchange,
            counts: [0; 4],
            collectives: collectives
                .iter()
                .map(|&(len, compute_before, seconds)| Collective { len, broadcast: false, compute_before, seconds })
                .collect(),
        }
    }

    #[test]
    fn the_last_rank_to_arrive_defines_the_transfer_and_the_others_wait() {
        // two syncs: rank 1 computes 3 s then 1 s, rank 0 1 s then 3 s; each call's transfer 0.1 s
        let a = log(&[(4, 1.0, 2.1), (4, 3.0, 0.1)], 6.2, 0.0);
        let b = log(&[(4, 3.0, 0.1), (4, 1.0, 2.1)], 6.2, 0.0);
        let p = Profile::from_logs(&[a, b]);
        for r in &p.ranks {
            assert!((r.transfer - 0.2).abs() < 1e-12);
            assert!((r.wait - 2.0).abs() < 1e-12, "{r:?}");
            assert!((r.compute - 4.0).abs() < 1e-12);
            assert!((r.compute + r.wait + r.transfer + r.exchange - r.wall).abs() < 1e-12);
            assert_eq!(r.last_to_arrive, 1);
        }
        // balanced in total (4 s each) but the slowest rank changes: 6 s of slowest against 4
        assert!((p.imbalance - 1.0).abs() < 1e-12);
        assert!((p.jitter - 2.0).abs() < 1e-12, "{}", p.jitter);
        assert_eq!(p.collectives.len(), 1);
        assert_eq!(p.collectives[0].calls, 2);
        assert!((p.collectives[0].wait - 4.0).abs() < 1e-12);
        assert!((p.collectives[0].slowest_excess - 2.0).abs() < 1e-12);
    }

    #[test]
    fn a_rank_always_last_is_imbalance_not_jitter() {
        let a = log(&[(2, 1.0, 1.0), (2, 1.0, 1.0)], 4.0, 0.0);
        let b = log(&[(2, 2.0, 0.0), (2, 2.0, 0.0)], 4.0, 0.0);
        let p = Profile::from_logs(&[a, b]);
        assert_eq!(p.ranks[1].last_to_arrive, 2);
        assert!(p.jitter.abs() < 1e-12);
        assert!((p.imbalance - 4.0 / 3.0).abs() < 1e-12, "{}", p.imbalance);
    }

    #[test]
    fn a_log_survives_its_trip_to_rank_zero() {
        let mut l = Log { messages_sent: 3, bytes_sent: 24, exchange_seconds: 0.5, ..Default::default() };
        l.collectives.push(Collective { len: 7, broadcast: true, compute_before: 0.25, seconds: 0.125 });
        l.collectives.push(Collective { len: 0, broadcast: false, compute_before: 1.0, seconds: 2.0 });
        let back = RankLog::unpack(&RankLog::pack(&l, 9.0));
        assert_eq!(back.wall, 9.0);
        assert_eq!(back.counts, [3, 24, 0, 0]);
        assert_eq!(back.collectives.len(), 2);
        assert!(back.collectives[0].broadcast && back.collectives[0].len == 7);
        assert!(!back.collectives[1].broadcast && back.collectives[1].len == 0);
    }

    #[test]
    fn serial_profile_is_all_compute() {
        let serial = crate::comm::Serial;
        let p = Profiled::new(&serial);
        let mut v = vec![1.0; 3];
        p.sum_in_place(&mut v);
        let busy = Instant::now();
        while busy.elapsed().as_secs_f64() < 0.01 {}
        let profile = p.finish().expect("rank 0 has the profile");
        let r = &profile.ranks[0];
        assert_eq!(r.collectives, 1);
        assert_eq!(r.wait, 0.0);
        assert!(r.compute >= 0.01 && (r.compute + r.transfer - r.wall).abs() < 1e-9, "{r:?}");
    }
}
