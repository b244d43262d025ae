//! What a client's verified frames predict from: the bricks its last verified frame needed.
//!
//! While a client drags, its frames follow one another a few degrees apart, so the bricks
//! the last frame needed (after verification and repair) are a close guess of the next
//! frame's: [`Predictor::Previous`]. The guess only steers the work; verification and one
//! round of repair keep the image right whatever it is. A client's first frame, or its
//! first after its weights, threshold or family change (the old set then says little),
//! predicts with the proxy.
//!
//! The scene keeps a single previous set, shared by every client. So every verified frame
//! runs under one lock here: swap the client's own set in, render, take the set the frame
//! left back out. No client's frame ever predicts from another client's set.

use std::collections::HashMap;
use std::sync::{Mutex, PoisonError};

use pofvr::cull::Predictor;
use pofvr::Scene;

/// What a kept set was measured for: a set means something to a later frame only with the
/// same family, weights and threshold.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SetKey {
    /// The family version of the scene the frame rendered on.
    pub family_version: u64,
    /// The weights.
    pub weights: Vec<f32>,
    /// The cull threshold.
    pub threshold: f32,
}

#[derive(Debug)]
struct Kept {
    key: SetKey,
    needed: Vec<bool>,
    /// When it was last stored, to forget the stalest client first.
    stamp: u64,
}

#[derive(Debug, Default)]
struct Table {
    kept: HashMap<String, Kept>,
    clock: u64,
}

/// Each client's last verified set, and the lock verified frames render under.
#[derive(Debug)]
pub(crate) struct DragMemory {
    table: Mutex<Table>,
    max_clients: usize,
}

impl DragMemory {
    /// Remembers the sets of at most `max_clients` clients.
    pub(crate) fn new(max_clients: usize) -> Self {
        DragMemory {
            table: Mutex::new(Table::default()),
            max_clients: max_clients.max(1),
        }
    }

    /// Renders one verified frame of `client` with `render`, which is given the predictor
    /// to use: [`Predictor::Previous`] when the client's last verified frame had the same
    /// `key`, [`Predictor::Proxy`] otherwise. The set the frame needed is kept for the
    /// client's next frame; a failed frame forgets the client's set.
    pub(crate) fn render<R, E>(
        &self,
        scene: &Scene,
        client: &str,
        key: SetKey,
        render: impl FnOnce(Predictor) -> Result<R, E>,
    ) -> Result<R, E> {
        // Held for the whole frame: the scene's one set must not change under it. A
        // poisoned table is still consistent (every update is one insert or remove).
        let mut table = self.table.lock().unwrap_or_else(PoisonError::into_inner);
        let mine = table
            .kept
            .get(client)
            .filter(|k| k.key == key && k.needed.len() == scene.grid().len())
            .map(|k| k.needed.clone());
        let predictor = if mine.is_some() {
            Predictor::Previous
        } else {
            Predictor::Proxy
        };
        scene.set_previous_needed(mine);
        let result = render(predictor);
        match (&result, scene.previous_needed()) {
            (Ok(_), Some(needed)) => {
                if !table.kept.contains_key(client) && table.kept.len() >= self.max_clients {
                    if let Some(stalest) = table
                        .kept
                        .iter()
                        .min_by_key(|(_, k)| k.stamp)
                        .map(|(c, _)| c.clone())
                    {
                        table.kept.remove(&stalest);
                    }
                }
                table.clock += 1;
                let stamp = table.clock;
                table
                    .kept
                    .insert(client.to_string(), Kept { key, needed, stamp });
            }
            _ => {
                table.kept.remove(client);
            }
        }
        // Leave nothing of this client's in the scene for a frame outside this lock.
        scene.set_previous_needed(None);
        result
    }

    /// Clients with a kept set.
    #[cfg(test)]
    pub(crate) fn clients(&self) -> usize {
        self.table
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .kept
            .len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pofvr::render::{families, Camera, Projection};
    use pofvr::volume::phantom::Phantom;
    use pofvr::{Cull, FrameRequest, Predict};

    fn scene() -> Scene {
        let vol = Phantom::SheppLogan.generate(32);
        Scene::builder(vol, families::for_phantom(Phantom::SheppLogan))
            .brick_size(8)
            .build()
            .unwrap()
    }

    fn key(w: f32) -> SetKey {
        SetKey {
            family_version: 0,
            weights: vec![w, 1.0],
            threshold: 0.95,
        }
    }

    fn frame(s: &Scene, p: Predictor) -> Result<pofvr::Frame, pofvr::Error> {
        let cam = Camera::orbit(s.volume(), 30.0, 20.0, 32, 32, Projection::Orthographic);
        let w = [3.0, 1.0];
        let predict = Predict::from_predictor(p, None).unwrap();
        s.render(
            &FrameRequest::new(&cam)
                .weights(&w)
                .cull(Cull::Verified(predict)),
        )
    }

    #[test]
    fn previous_follows_the_client_and_the_key_and_the_table_is_bounded() {
        let s = scene();
        let m = DragMemory::new(2);
        let used = |client: &str, k: SetKey| {
            let mut got = None;
            m.render(&s, client, k, |p| {
                got = Some(p);
                frame(&s, p)
            })
            .unwrap();
            got.unwrap()
        };
        assert_eq!(used("a", key(3.0)), Predictor::Proxy);
        assert_eq!(used("a", key(3.0)), Predictor::Previous);
        assert_eq!(used("b", key(3.0)), Predictor::Proxy, "b saw a's set");
        assert_eq!(
            used("a", key(2.0)),
            Predictor::Proxy,
            "new weights, old set"
        );
        assert!(s.previous_needed().is_none(), "a set was left in the scene");
        assert_eq!(used("c", key(3.0)), Predictor::Proxy);
        assert_eq!(m.clients(), 2);
        // b was the stalest: forgotten.
        assert_eq!(used("b", key(3.0)), Predictor::Proxy);
    }

    #[test]
    fn a_failed_frame_forgets_the_clients_set() {
        let s = scene();
        let m = DragMemory::new(4);
        m.render(&s, "a", key(3.0), |p| frame(&s, p)).unwrap();
        let e: Result<(), &str> = m.render(&s, "a", key(3.0), |_| Err("lost a rank"));
        assert!(e.is_err());
        let mut got = None;
        m.render(&s, "a", key(3.0), |p| {
            got = Some(p);
            frame(&s, p)
        })
        .unwrap();
        assert_eq!(got, Some(Predictor::Proxy));
    }
}
