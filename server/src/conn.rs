//! The coordinator's connections: at most a fixed number open at once (more are closed as they
//! arrive, before the process runs out of file descriptors), at most a share of them from one
//! client address (one host holding every slot with slow or pinging connections would lock
//! everyone else out), and each closed once it has sent nothing for the idle time. HTTP/2 clients answer the keepalive pings the server sends every
//! quarter of that time, so long polls and event streams of a live client stay open; a socket
//! opened and left silent, or an HTTP/1.1 keep-alive connection no one uses, is closed.

use std::collections::HashMap;
use std::io;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, ready};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_stream::Stream;
use tonic::transport::server::{Connected, TcpConnectInfo};

/// The accepted connections, limited and watched.
pub struct Incoming {
    listener: TcpListener,
    permits: Arc<Semaphore>,
    per_client: PerClient,
    idle: Duration,
    /// After an accept error (out of file descriptors): a pause, not a spin.
    pause: Option<Pin<Box<Sleep>>>,
}

impl Incoming {
    pub fn new(listener: TcpListener, max_connections: usize, max_per_client: usize, idle: Duration) -> Self {
        Self {
            listener,
            permits: Arc::new(Semaphore::new(max_connections)),
            per_client: PerClient { open: Arc::new(Mutex::new(HashMap::new())), max: max_per_client },
            idle,
            pause: None,
        }
    }
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
                Ok((stream, peer)) => match self.permits.clone().try_acquire_owned() {
                    Ok(permit) => {
                        let Some(slot) = self.per_client.take(peer.ip()) else {
                            // dropped, as past the global limit
                            tracing::warn!(%peer, max = self.per_client.max, "this client holds its share of the connections: closing a new one");
                            continue;
                        };
                        // No Nagle: a lease is several small messages, and delayed ACKs would add 40 ms to each.
                        if let Err(e) = stream.set_nodelay(true) {
                            tracing::debug!(error = %e, "TCP_NODELAY");
                        }
                        let idle = self.idle;
                        return Poll::Ready(Some(Ok(Guarded::new(stream, permit, slot, idle))));
                    }
                    // dropped: closed at once, the client sees a reset instead of a hang
                    Err(_) => tracing::warn!(%peer, "connection limit reached: closing a new connection"),
                },
                Err(e) => {
                    tracing::warn!(error = %e, "accepting a connection");
                    self.pause = Some(Box::pin(tokio::time::sleep(Duration::from_millis(50))));
                }
            }
        }
    }
}

/// A connection that holds one of the limited permits and fails once idle.
pub struct Guarded {
    stream: TcpStream,
    _permit: OwnedSemaphorePermit,
    _slot: ClientSlot,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
}

impl Guarded {
    fn new(stream: TcpStream, permit: OwnedSemaphorePermit, slot: ClientSlot, idle: Duration) -> Self {
        Self { stream, _permit: permit, _slot: slot, idle, deadline: Box::pin(tokio::time::sleep(idle)) }
    }

    /// Pending I/O: an error once the connection has been silent past its deadline (the
    /// deadline's timer wakes the task then).
    fn pending_or_idle<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(io::Error::new(io::ErrorKind::TimedOut, "connection idle"))),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl AsyncRead for Guarded {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(r) => {
                if buf.filled().len() > before {
                    let next = Instant::now() + self.idle;
                    self.deadline.as_mut().reset(next);
                }
                Poll::Ready(r)
            }
            Poll::Pending => self.pending_or_idle(cx),
        }
    }
}

impl AsyncWrite for Guarded {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        match Pin::new(&mut self.stream).poll_write(cx, buf) {
            Poll::Ready(r) => Poll::Ready(r),
            // a client that stops reading is as idle as one that stops writing
            Poll::Pending => self.pending_or_idle(cx),
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match Pin::new(&mut self.stream).poll_flush(cx) {
            Poll::Ready(r) => Poll::Ready(r),
            Poll::Pending => self.pending_or_idle(cx),
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
            Poll::Pending => self.pending_or_idle(cx),
        }
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl Connected for Guarded {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.stream.connect_info()
    }
}
