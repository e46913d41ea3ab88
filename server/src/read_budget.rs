//! Each client address's budget of web requests (the page, the JSON API, /metrics): a token
//! bucket of `rate` requests a second that holds two seconds' worth, so a person's browser (a
//! page, then a progress poll a second) never meets it. A request over the budget **waits its
//! turn** (the bucket goes into debt, up to [`MAX_WAIT`] of requests), and past that it is refused
//! with 429 after [`REFUSAL_DELAY`]: a client that reads as fast as it is answered is slowed to
//! the rate instead of taking the cores the studies' dispatch needs. Waiting and refusing late
//! cost a timer; a refusal at once did not help (issue 48's bench: readers that ask again at once
//! made 3 x more requests, each a connection and a parse, and the honest study fell from 0.77-0.92
//! of its quiet throughput to 0.46-0.75).
//!
//! Keyed by IPv4 address and by IPv6 /64 (a host is handed a /64, and would otherwise have 2^64
//! budgets). At most [`MAX_CLIENTS`] addresses are followed: when the map is full, addresses whose
//! bucket has refilled (as good as new) are forgotten, and while none has, newcomers share one
//! bucket, so a flood of addresses costs bounded memory and gets one budget between them.
//! gRPC calls (the CLI, Python, pools) are not counted here: they are limited by their
//! connections (conn.rs) and answered from the coordinator's own state.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// Default of `--web-reads-per-second`.
pub const DEFAULT_RATE: f64 = 20.0;

/// How many seconds of requests a full bucket holds.
const BURST_SECONDS: f64 = 2.0;

/// Most addresses followed at once (each about 64 bytes).
pub const MAX_CLIENTS: usize = 4096;

/// The longest a request over the budget waits for its turn; past it, it is refused.
pub const MAX_WAIT: Duration = Duration::from_secs(5);

/// How long a refused request waits before its 429, so that asking again at once is not a way
/// to spin the coordinator.
pub const REFUSAL_DELAY: Duration = Duration::from_secs(1);

/// Whom a bucket belongs to: an address, or every newcomer while the map is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Client {
    V4(u32),
    V6Prefix(u64),
    Overflow,
}

impl Client {
    fn of(ip: IpAddr) -> Self {
        match ip {
            IpAddr::V4(v4) => Client::V4(v4.into()),
            IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
                Some(v4) => Client::V4(v4.into()),
                None => Client::V6Prefix((u128::from(v6) >> 64) as u64),
            },
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    at: Instant,
}

#[derive(Debug)]
pub struct ReadBudget {
    rate: f64,
    burst: f64,
    max_clients: usize,
    buckets: Mutex<HashMap<Client, Bucket>>,
}

/// What a request gets from its address's budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Admission {
    Now,
    /// its turn comes after this long (at most [`MAX_WAIT`])
    After(Duration),
    /// the turns of the next [`MAX_WAIT`] are taken: try again after this long
    Refused {
        retry_after: Duration,
    },
}

impl ReadBudget {
    /// `rate` requests a second per address (finite and positive: the caller checks its flag).
    pub fn new(rate: f64) -> Self {
        Self::with_capacity(rate, MAX_CLIENTS)
    }

    fn with_capacity(rate: f64, max_clients: usize) -> Self {
        let burst = (rate * BURST_SECONDS).max(1.0);
        ReadBudget { rate, burst, max_clients, buckets: Mutex::new(HashMap::new()) }
    }

    /// The requests a second per address.
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// Takes one request from `ip`'s budget at `now`: now, after a wait, or refused.
    pub fn take(&self, ip: IpAddr, now: Instant) -> Admission {
        // a panic under the lock leaves a map of valid buckets
        let mut buckets = self.buckets.lock().unwrap_or_else(PoisonError::into_inner);
        let mut client = Client::of(ip);
        if !buckets.contains_key(&client) && buckets.len() >= self.max_clients {
            let refill = Duration::from_secs_f64(self.burst / self.rate);
            buckets.retain(|c, b| *c == Client::Overflow || now.saturating_duration_since(b.at) < refill);
            if buckets.len() >= self.max_clients {
                client = Client::Overflow;
            }
        }
        let bucket = buckets.entry(client).or_insert(Bucket { tokens: self.burst, at: now });
        let elapsed = now.saturating_duration_since(bucket.at).as_secs_f64();
        bucket.tokens = (bucket.tokens + elapsed * self.rate).min(self.burst);
        bucket.at = bucket.at.max(now);
        // in debt, the bucket's tokens are the turns already promised to waiting requests
        let wait = (1.0 - bucket.tokens).max(0.0) / self.rate;
        if wait > MAX_WAIT.as_secs_f64() {
            return Admission::Refused { retry_after: Duration::from_secs_f64(wait - MAX_WAIT.as_secs_f64()) };
        }
        bucket.tokens -= 1.0;
        if wait == 0.0 { Admission::Now } else { Admission::After(Duration::from_secs_f64(wait)) }
    }

    /// How many addresses are followed (for tests).
    #[cfg(test)]
    fn followed(&self) -> usize {
        self.buckets.lock().unwrap_or_else(PoisonError::into_inner).len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(text: &str) -> IpAddr {
        text.parse().unwrap()
    }

    fn after(a: Admission) -> f64 {
        match a {
            Admission::Now => 0.0,
            Admission::After(d) => d.as_secs_f64(),
            Admission::Refused { .. } => panic!("refused"),
        }
    }

    #[test]
    fn an_address_gets_its_burst_then_waits_its_turn_then_is_refused_and_others_are_not_touched() {
        let budget = ReadBudget::new(10.0);
        let t0 = Instant::now();
        let a = ip("10.0.0.1");
        // two seconds' worth at once
        for _ in 0..20 {
            assert_eq!(budget.take(a, t0), Admission::Now);
        }
        // then each waits a tenth of a second more than the one before, up to five seconds
        for k in 1..=50 {
            assert!((after(budget.take(a, t0)) - 0.1 * f64::from(k)).abs() < 1e-9, "{k}");
        }
        let Admission::Refused { retry_after } = budget.take(a, t0) else { panic!("not refused") };
        assert!((retry_after.as_secs_f64() - 0.1).abs() < 1e-9, "{retry_after:?}");
        // another address has its own budget
        assert_eq!(budget.take(ip("10.0.0.2"), t0), Admission::Now);
        // the debt is paid at the rate: a second later, ten turns are free again
        let later = t0 + Duration::from_secs(1);
        for _ in 0..10 {
            assert!(after(budget.take(a, later)) > 4.0);
        }
        assert!(matches!(budget.take(a, later), Admission::Refused { .. }));
        // a long pause refills to the burst, not beyond
        let much_later = t0 + Duration::from_secs(3600);
        for _ in 0..20 {
            assert_eq!(budget.take(a, much_later), Admission::Now);
        }
        assert!((after(budget.take(a, much_later)) - 0.1).abs() < 1e-9);
    }

    #[test]
    fn an_ipv6_host_has_one_budget_for_its_64_and_a_mapped_ipv4_is_the_ipv4() {
        let budget = ReadBudget::new(1.0);
        let t0 = Instant::now();
        let now = |text: &str| budget.take(ip(text), t0) == Admission::Now;
        assert!(now("2001:db8:1:2::1") && now("2001:db8:1:2:ffff::9"));
        assert!(!now("2001:db8:1:2:abcd::7"), "the same /64");
        assert!(now("2001:db8:1:3::1") && now("192.0.2.7") && now("::ffff:192.0.2.7"));
        assert!(!now("192.0.2.7"), "the mapped address is the IPv4 one");
    }

    #[test]
    fn a_flood_of_addresses_is_followed_in_bounded_memory_and_shares_one_budget() {
        let budget = ReadBudget::with_capacity(1.0, 8);
        let t0 = Instant::now();
        for k in 0..8u8 {
            assert_eq!(budget.take(IpAddr::from([10, 0, 0, k]), t0), Admission::Now);
        }
        // the map is full of addresses still drawing down: the newcomers share the overflow's two
        assert_eq!(budget.take(ip("10.0.1.1"), t0), Admission::Now);
        assert_eq!(budget.take(ip("10.0.1.2"), t0), Admission::Now);
        assert!(matches!(budget.take(ip("10.0.1.3"), t0), Admission::After(_)));
        assert_eq!(budget.followed(), 9, "eight addresses and the overflow");
        // once their buckets have refilled the addresses are forgotten, and a newcomer has its own
        let later = t0 + Duration::from_secs(10);
        assert_eq!(budget.take(ip("10.0.2.1"), later), Admission::Now);
        assert_eq!(budget.take(ip("10.0.2.1"), later), Admission::Now);
        assert!(budget.followed() <= 2, "{}", budget.followed());
    }
}
