//! The coordinator's connections: at most a fixed number open at once (more are closed as they
//! arrive, before the process runs out of file descriptors), at most a share of them from one
//! client address (one host holding every slot with slow or pinging connections would lock
//! everyone else out), and each closed once it has sent nothing for the idle time. HTTP/2
//! clients answer the keepalive pings the server sends every quarter of that time, so long polls
//! and event streams of a live client stay open; a socket opened and left silent, or an HTTP/1.1
//! keep-alive connection no one uses, is closed.
//!
//! Where the coordinator asks for tokens, a connection is **on probation** until one of its
//! requests presents a valid token ([`ConnInfo::trust`]): it is closed at the end of the
//! probation whatever it sends (a PING a second, a body a byte at a time), and when every slot is
//! taken a new connection displaces the oldest one still on probation instead of being refused.
//! So strangers, however many and however slow, hold slots for a bounded time and never the slot
//! a client with a token needs.

use std::collections::{HashMap, VecDeque};
use std::io;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError, Weak};
use std::task::{Context, Poll, Waker, ready};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_stream::Stream;
use tonic::transport::server::{Connected, TcpConnectInfo};

/// How connections are limited.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_connections: usize,
    pub max_per_client: usize,
    /// A connection that has sent nothing for this long is closed.
    pub idle: Duration,
    /// How long a connection may stay without presenting a token; None where the coordinator
    /// asks for none (every connection is trusted).
    pub probation: Option<Duration>,
}

/// The accepted connections, limited and watched.
pub struct Incoming {
    listener: TcpListener,
    permits: Arc<Semaphore>,
    per_client: PerClient,
    limits: Limits,
    /// The connections on probation, oldest first (entries whose connection closed or was
    /// trusted are skipped and pruned).
    on_probation: VecDeque<Weak<Trust>>,
    /// After an accept error (out of file descriptors): a pause, not a spin.
    pause: Option<Pin<Box<Sleep>>>,
}

impl Incoming {
    pub fn new(listener: TcpListener, limits: Limits) -> Self {
        Self {
            listener,
            permits: Arc::new(Semaphore::new(limits.max_connections)),
            per_client: PerClient { open: Arc::new(Mutex::new(HashMap::new())), max: limits.max_per_client },
            limits,
            on_probation: VecDeque::new(),
            pause: None,
        }
    }

    /// The slot of the oldest connection still on probation, from `ip` or from anyone; that
    /// connection is closed.
    fn displace(&mut self, ip: Option<IpAddr>) -> Option<Held> {
        let at = self
            .on_probation
            .iter()
            .position(|t| t.upgrade().is_some_and(|t| !t.granted() && ip.is_none_or(|ip| t.ip == ip) && t.holds()))?;
        let trust = self.on_probation.remove(at)?.upgrade()?;
        trust.evict()
    }

    /// The slots of a new connection from `ip`: its address's and one of all, free ones or, when
    /// taken, those of the oldest connection still on probation, from that address first.
    fn slots(&mut self, ip: IpAddr) -> Option<Held> {
        let Some(client) = self.per_client.take(ip) else {
            // a host at its share displaces only its own strangers
            return self.displace(Some(ip));
        };
        let permit = match self.permits.clone().try_acquire_owned() {
            Ok(permit) => permit,
            // (the displaced connection's address slot goes back as it closes)
            Err(_) => self.displace(None)?.permit,
        };
        Some(Held { permit, _client: client })
    }
}

/// The slots a connection holds: one of all, one of its address's share.
struct Held {
    permit: OwnedSemaphorePermit,
    /// given back as it drops
    _client: ClientSlot,
}

/// Whether a connection has presented a valid token; and, while it has not, its slot, which a
/// newer connection may take (closing it).
pub struct Trust {
    ip: IpAddr,
    trusted: AtomicBool,
    evicted: AtomicBool,
    /// the slots, kept here so that an eviction can hand them over
    held: Mutex<Option<Held>>,
    /// the connection's task, woken to close it when evicted
    waker: Mutex<Option<Waker>>,
}

impl Trust {
    /// The connection presented a valid token: it stays (within the idle time) and keeps its slot.
    pub fn grant(&self) {
        self.trusted.store(true, Ordering::Release);
    }

    pub fn granted(&self) -> bool {
        self.trusted.load(Ordering::Acquire)
    }

    fn holds(&self) -> bool {
        self.held.lock().unwrap_or_else(PoisonError::into_inner).is_some()
    }

    /// Closes the connection, unless trusted, and gives its slots.
    fn evict(&self) -> Option<Held> {
        let mut held = self.held.lock().unwrap_or_else(PoisonError::into_inner);
        if self.granted() {
            return None;
        }
        let taken = held.take()?;
        self.evicted.store(true, Ordering::Release);
        if let Some(w) = self.waker.lock().unwrap_or_else(PoisonError::into_inner).take() {
            w.wake();
        }
        Some(taken)
    }
}

impl std::fmt::Debug for Trust {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Trust").field("ip", &self.ip).field("trusted", &self.granted()).finish_non_exhaustive()
    }
}

/// What a request knows of its connection (tonic puts it in every request's extensions, inside
/// `TlsConnectInfo` under TLS).
#[derive(Debug, Clone)]
pub struct ConnInfo {
    pub tcp: TcpConnectInfo,
    pub trust: Arc<Trust>,
}

/// The connections open from each client address, and how many one may hold.
struct PerClient {
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
    max: usize,
}

impl PerClient {
    /// A slot for `ip`, or None when it holds its share already.
    fn take(&self, ip: IpAddr) -> Option<ClientSlot> {
        let mut open = self.open.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let n = open.entry(ip).or_insert(0);
        if *n >= self.max {
            return None;
        }
        *n += 1;
        Some(ClientSlot { ip, open: self.open.clone() })
    }
}

/// One connection's count against its address, given back when the connection closes.
struct ClientSlot {
    ip: IpAddr,
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        let mut open = self.open.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

impl Stream for Incoming {
    type Item = io::Result<Guarded>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        loop {
            if let Some(pause) = &mut self.pause {
                ready!(pause.as_mut().poll(cx));
                self.pause = None;
            }
            match ready!(self.listener.poll_accept(cx)) {
                Ok((stream, peer)) => {
                    let Some(held) = self.slots(peer.ip()) else {
                        // dropped: closed at once, the client sees a reset instead of a hang
                        tracing::warn!(%peer, max = self.per_client.max, "connection limit, or this client's share of it, reached: closing a new connection");
                        continue;
                    };
                    // No Nagle: a lease is several small messages, and delayed ACKs would add 40 ms to each.
                    if let Err(e) = stream.set_nodelay(true) {
                        tracing::debug!(error = %e, "TCP_NODELAY");
                    }
                    let conn = Guarded::new(stream, peer.ip(), held, self.limits);
                    if self.limits.probation.is_some() {
                        if self.on_probation.len() >= 2 * self.limits.max_connections {
                            self.on_probation.retain(|t| t.upgrade().is_some_and(|t| !t.granted()));
                        }
                        self.on_probation.push_back(Arc::downgrade(&conn.trust));
                    }
                    return Poll::Ready(Some(Ok(conn)));
                }
                Err(e) => {
                    tracing::warn!(error = %e, "accepting a connection");
                    self.pause = Some(Box::pin(tokio::time::sleep(Duration::from_millis(50))));
                }
            }
        }
    }
}

/// A connection that holds one of the limited permits and fails once idle, or at the end of its
/// probation, or when a newer connection takes its slot.
pub struct Guarded {
    stream: TcpStream,
    trust: Arc<Trust>,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
    /// the end of the probation, until the connection is trusted
    probation: Option<Pin<Box<Sleep>>>,
}

impl Guarded {
    fn new(stream: TcpStream, ip: IpAddr, held: Held, limits: Limits) -> Self {
        let trust = Arc::new(Trust {
            ip,
            trusted: AtomicBool::new(limits.probation.is_none()),
            evicted: AtomicBool::new(false),
            held: Mutex::new(Some(held)),
            waker: Mutex::new(None),
        });
        Self {
            stream,
            trust,
            idle: limits.idle,
            deadline: Box::pin(tokio::time::sleep(limits.idle)),
            probation: limits.probation.map(|p| Box::pin(tokio::time::sleep(p))),
        }
    }

    /// Pending I/O: an error once the connection has been silent past its deadline, has ended
    /// its probation untrusted, or was evicted (the timers and the eviction wake the task).
    fn pending_or_closed<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        if let Some(closed) = self.closed(cx) {
            return Poll::Ready(Err(closed));
        }
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(io::Error::new(io::ErrorKind::TimedOut, "connection idle"))),
            Poll::Pending => Poll::Pending,
        }
    }

    /// Why a connection on probation is closed now, if it is.
    fn closed(&mut self, cx: &mut Context<'_>) -> Option<io::Error> {
        let probation = self.probation.as_mut()?;
        if self.trust.granted() {
            self.probation = None;
            return None;
        }
        if self.trust.evicted.load(Ordering::Acquire) {
            return Some(displaced());
        }
        if probation.as_mut().poll(cx).is_ready() {
            return Some(io::Error::new(io::ErrorKind::TimedOut, "no token presented within the probation"));
        }
        let mut waker = self.trust.waker.lock().unwrap_or_else(PoisonError::into_inner);
        if !waker.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
            *waker = Some(cx.waker().clone());
        }
        drop(waker);
        // evicted between the check and the waker's registration
        self.trust.evicted.load(Ordering::Acquire).then(displaced)
    }
}

fn displaced() -> io::Error {
    io::Error::new(io::ErrorKind::ConnectionAborted, "displaced by a newer connection: no token")
}

impl AsyncRead for Guarded {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        // a sender that never pauses (a PING a second, a byte at a time) is closed all the same
        if let Some(closed) = self.closed(cx) {
            return Poll::Ready(Err(closed));
        }
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(r) => {
                if buf.filled().len() > before {
                    let next = Instant::now() + self.idle;
                    self.deadline.as_mut().reset(next);
                }
                Poll::Ready(r)
            }
            Poll::Pending => self.pending_or_closed(cx),
        }
    }
}

impl AsyncWrite for Guarded {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        match Pin::new(&mut self.stream).poll_write(cx, buf) {
            Poll::Ready(r) => Poll::Ready(r),
            // a client that stops reading is as idle as one that stops writing
            Poll::Pending => self.pending_or_closed(cx),
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match Pin::new(&mut self.stream).poll_flush(cx) {
            Poll::Ready(r) => Poll::Ready(r),
            Poll::Pending => self.pending_or_closed(cx),
        }
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        match Pin::new(&mut self.stream).poll_write_vectored(cx, bufs) {
            Poll::Ready(r) => Poll::Ready(r),
            Poll::Pending => self.pending_or_closed(cx),
        }
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl Drop for Guarded {
    /// The slots go back with the connection (the trust may outlive it in a request's extensions).
    fn drop(&mut self) {
        drop(self.trust.held.lock().unwrap_or_else(PoisonError::into_inner).take());
    }
}

impl Connected for Guarded {
    type ConnectInfo = ConnInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        ConnInfo { tcp: self.stream.connect_info(), trust: self.trust.clone() }
    }
}

/// The connection a request came on, plain or under TLS.
pub fn conn_of(extensions: &axum::http::Extensions) -> Option<&ConnInfo> {
    extensions
        .get::<ConnInfo>()
        .or_else(|| extensions.get::<tonic::transport::server::TlsConnectInfo<ConnInfo>>().map(|t| t.get_ref()))
}
