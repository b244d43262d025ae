//! Who renders next: one latest-request slot per client and a global bound on renders.
//!
//! Every request takes a ticket carrying its client's new generation number. Before it
//! renders it must hold its client's render lock (so one frame per client at a time) and
//! a global render permit (so renders never outnumber the cores); after each wait it checks
//! that no newer request from the same client has arrived since, and gives up if one has.
//! A client dragging a slider therefore never builds a queue: whatever was asked while a
//! frame rendered collapses into the newest request.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tokio::sync::{OwnedMutexGuard, OwnedSemaphorePermit, Semaphore};

/// One client's slot.
#[derive(Debug, Default)]
struct ClientSlot {
    /// Generation of the newest request seen from this client.
    latest: AtomicU64,
    /// Held while one of its frames is waiting for a permit or rendering.
    render: Arc<tokio::sync::Mutex<()>>,
}

/// A request's place in its client's order.
#[derive(Debug)]
pub(crate) struct Ticket {
    slot: Arc<ClientSlot>,
    generation: u64,
}

impl Ticket {
    /// This request's generation (1 for a client's first request).
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }

    /// True when a newer request from the same client has arrived.
    pub(crate) fn is_stale(&self) -> bool {
        self.slot.latest.load(Ordering::Acquire) != self.generation
    }
}

/// What a ticket holds while it renders: its client's lock and one global permit. Dropping
/// it lets the client's next request and other clients go on.
#[derive(Debug)]
pub(crate) struct RenderGrant {
    _client: OwnedMutexGuard<()>,
    _permit: OwnedSemaphorePermit,
}

/// Why a request will not be rendered.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Refusal {
    /// A newer request from the same client superseded it.
    Superseded,
    /// The client table is full of clients with requests in flight.
    TooManyClients,
}

/// The per-client slots and the global render bound.
#[derive(Debug)]
pub(crate) struct Scheduler {
    clients: Mutex<HashMap<String, Arc<ClientSlot>>>,
    max_clients: usize,
    permits: Arc<Semaphore>,
    render_slots: usize,
    requests: AtomicU64,
    renders: AtomicU64,
    superseded: AtomicU64,
}

/// Counters of a scheduler.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SchedulerStats {
    /// Frame requests that got a ticket since start.
    pub requests: u64,
    /// Frames rendered since start.
    pub renders: u64,
    /// Requests dropped because a newer one from the same client came first.
    pub superseded: u64,
    /// Clients with a slot.
    pub clients: usize,
    /// Frames that may render at once.
    pub render_slots: usize,
    /// Frames rendering now.
    pub rendering: usize,
}

impl Scheduler {
    /// A scheduler letting `render_slots` frames render at once and tracking at most
    /// `max_clients` clients.
    pub(crate) fn new(render_slots: usize, max_clients: usize) -> Self {
        let render_slots = render_slots.max(1);
        Scheduler {
            clients: Mutex::new(HashMap::new()),
            max_clients: max_clients.max(1),
            permits: Arc::new(Semaphore::new(render_slots)),
            render_slots,
            requests: AtomicU64::new(0),
            renders: AtomicU64::new(0),
            superseded: AtomicU64::new(0),
        }
    }

    /// Registers a new request from `client`, superseding its older ones.
    pub(crate) fn ticket(&self, client: &str) -> Result<Ticket, Refusal> {
        // A poisoned map is still consistent: every update is a single insert or retain.
        let mut clients = self.clients.lock().unwrap_or_else(PoisonError::into_inner);
        if !clients.contains_key(client) && clients.len() >= self.max_clients {
            // Only the map holds an idle slot; forgetting it loses nothing but its count.
            clients.retain(|_, slot| Arc::strong_count(slot) > 1);
            if clients.len() >= self.max_clients {
                return Err(Refusal::TooManyClients);
            }
        }
        let slot = Arc::clone(clients.entry(client.to_string()).or_default());
        let generation = slot.latest.fetch_add(1, Ordering::AcqRel) + 1;
        self.requests.fetch_add(1, Ordering::Relaxed);
        Ok(Ticket { slot, generation })
    }

    /// Waits until `ticket` may render: its client's lock, then a global permit, checking
    /// after each wait that it has not been superseded.
    pub(crate) async fn admit(&self, ticket: &Ticket) -> Result<RenderGrant, Refusal> {
        let client = Arc::clone(&ticket.slot.render).lock_owned().await;
        if ticket.is_stale() {
            return Err(self.refuse());
        }
        let Ok(permit) = Arc::clone(&self.permits).acquire_owned().await else {
            // The semaphore is never closed; treat the impossible case as superseded.
            return Err(self.refuse());
        };
        if ticket.is_stale() {
            return Err(self.refuse());
        }
        Ok(RenderGrant {
            _client: client,
            _permit: permit,
        })
    }

    /// Takes every render permit: no frame starts until the returned permit is dropped.
    pub(crate) async fn hold_all(&self) -> Option<OwnedSemaphorePermit> {
        let n = u32::try_from(self.render_slots).ok()?;
        Arc::clone(&self.permits).acquire_many_owned(n).await.ok()
    }

    fn refuse(&self) -> Refusal {
        self.superseded.fetch_add(1, Ordering::Relaxed);
        Refusal::Superseded
    }

    /// Counts a frame that is about to render.
    pub(crate) fn count_render(&self) {
        self.renders.fetch_add(1, Ordering::Relaxed);
    }

    /// Current counters.
    pub(crate) fn stats(&self) -> SchedulerStats {
        let clients = self
            .clients
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len();
        SchedulerStats {
            requests: self.requests.load(Ordering::Relaxed),
            renders: self.renders.load(Ordering::Relaxed),
            superseded: self.superseded.load(Ordering::Relaxed),
            clients,
            render_slots: self.render_slots,
            rendering: self.render_slots - self.permits.available_permits(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_newer_ticket_supersedes_an_older_one_waiting_for_the_client_lock() {
        let s = Scheduler::new(4, 8);
        let first = s.ticket("a").unwrap();
        let grant = s.admit(&first).await.unwrap();
        let second = s.ticket("a").unwrap();
        let third = s.ticket("a").unwrap();
        assert!(second.is_stale() && !third.is_stale());
        drop(grant);
        assert_eq!(s.admit(&second).await.unwrap_err(), Refusal::Superseded);
        assert!(s.admit(&third).await.is_ok());
        assert_eq!(s.stats().superseded, 1);
    }

    #[tokio::test]
    async fn a_client_renders_one_frame_at_a_time_even_with_free_permits() {
        let s = Arc::new(Scheduler::new(4, 8));
        let first = s.ticket("a").unwrap();
        let grant = s.admit(&first).await.unwrap();
        let second = s.ticket("a").unwrap();
        let s2 = Arc::clone(&s);
        let waiter = tokio::spawn(async move { s2.admit(&second).await.map(|_| ()) });
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        assert!(
            !waiter.is_finished(),
            "a's second frame started while its first rendered"
        );
        drop(grant);
        assert_eq!(waiter.await.unwrap(), Ok(()));
    }

    #[tokio::test]
    async fn clients_do_not_supersede_each_other() {
        let s = Scheduler::new(4, 8);
        let a = s.ticket("a").unwrap();
        let b = s.ticket("b").unwrap();
        let ga = s.admit(&a).await.unwrap();
        let gb = s.admit(&b).await.unwrap();
        assert_eq!(s.stats().rendering, 2);
        drop((ga, gb));
        assert_eq!(s.stats().rendering, 0);
    }

    #[tokio::test]
    async fn the_client_table_is_bounded_and_idle_clients_are_forgotten() {
        let s = Scheduler::new(1, 2);
        let a = s.ticket("a").unwrap();
        let _b = s.ticket("b").unwrap();
        assert_eq!(s.ticket("c").unwrap_err(), Refusal::TooManyClients);
        drop(a);
        assert!(s.ticket("c").is_ok());
        assert_eq!(s.stats().clients, 2);
    }

    #[tokio::test]
    async fn renders_never_outnumber_the_permits() {
        let s = Arc::new(Scheduler::new(1, 8));
        let a = s.ticket("a").unwrap();
        let b = s.ticket("b").unwrap();
        let ga = s.admit(&a).await.unwrap();
        let s2 = Arc::clone(&s);
        let waiter = tokio::spawn(async move { s2.admit(&b).await.map(|_| ()) });
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        assert!(
            !waiter.is_finished(),
            "b rendered while a held the only permit"
        );
        drop(ga);
        assert_eq!(waiter.await.unwrap(), Ok(()));
    }
}
