use std::time::{Duration, Instant};

use super::*;

const LONG: Duration = Duration::from_secs(20);

#[test]
fn ping_pong_keeps_order_per_sender_and_tag() {
    let out = LocalCommunicator::run(2, |comm| {
        let peer = Rank(1 - comm.rank().0);
        if comm.rank() == Rank(0) {
            for i in 0..100u8 {
                comm.send(peer, 7, vec![i]).unwrap();
            }
            let mut got = Vec::new();
            for _ in 0..100 {
                let (from, bytes) = comm.recv(Some(peer), 8, LONG).unwrap();
                assert_eq!(from, peer);
                got.push(bytes[0]);
            }
            got
        } else {
            for _ in 0..100 {
                let (_, mut bytes) = comm.recv(None, 7, LONG).unwrap();
                bytes[0] = bytes[0].wrapping_mul(2);
                comm.send(peer, 8, bytes).unwrap();
            }
            Vec::new()
        }
    });
    let expected: Vec<u8> = (0..100u8).map(|i| i.wrapping_mul(2)).collect();
    assert_eq!(out[0], expected);
}

#[test]
fn recv_selects_by_tag_and_sender() {
    let out = LocalCommunicator::run(3, |comm| match comm.rank().0 {
        0 => {
            // Rank 2's tag-6 message is taken although its tag-5 message is older.
            let first = comm.recv(Some(Rank(2)), 6, LONG).unwrap();
            let mut any = vec![
                comm.recv(None, 5, LONG).unwrap(),
                comm.recv(None, 5, LONG).unwrap(),
            ];
            any.sort();
            let last = comm.recv(Some(Rank(1)), 6, LONG).unwrap();
            let none_left = comm.recv(None, 5, Duration::from_millis(20)).is_err();
            Some((first, any, last, none_left))
        }
        r => {
            let r = u8::try_from(r).unwrap();
            comm.send(Rank(0), 5, vec![r]).unwrap();
            comm.send(Rank(0), 6, vec![10 * r]).unwrap();
            None
        }
    });
    let (first, any, last, none_left) = out[0].clone().unwrap();
    assert_eq!(first, (Rank(2), vec![20]));
    assert_eq!(any, vec![(Rank(1), vec![1]), (Rank(2), vec![2])]);
    assert_eq!(last, (Rank(1), vec![10]));
    assert!(none_left);
}

#[test]
fn all_gather_and_gather_at_odd_rank_counts() {
    for n in [1, 2, 3, 7] {
        let out = LocalCommunicator::run(n, |comm| {
            let me = comm.rank().0;
            let mine = vec![u8::try_from(me).unwrap(); me as usize + 1];
            let all = comm.all_gather(mine.clone(), LONG).unwrap();
            // Twice in a row: the second must not mix with the first.
            let again = comm.all_gather(vec![42], LONG).unwrap();
            assert_eq!(again, vec![vec![42]; comm.size()]);
            let root = Rank(u32::try_from(comm.size()).unwrap() - 1);
            let gathered = comm.gather(root, mine, LONG).unwrap();
            assert_eq!(gathered.is_some(), comm.rank() == root);
            comm.barrier(LONG).unwrap();
            (all, gathered)
        });
        let expected: Vec<Vec<u8>> = (0..n)
            .map(|r| vec![u8::try_from(r).unwrap(); r + 1])
            .collect();
        for (r, (all, gathered)) in out.into_iter().enumerate() {
            assert_eq!(all, expected, "all_gather at {n} ranks, rank {r}");
            if r == n - 1 {
                assert_eq!(gathered.as_ref(), Some(&expected), "gather at {n} ranks");
            }
        }
    }
}

#[test]
fn recv_timeout_returns_an_error_naming_rank_and_tag() {
    let timeout = Duration::from_millis(100);
    let out = LocalCommunicator::run(2, |comm| {
        let start = Instant::now();
        let err = comm
            .recv(Some(Rank(1 - comm.rank().0)), 99, timeout)
            .unwrap_err();
        (err, start.elapsed())
    });
    for (r, (err, elapsed)) in out.into_iter().enumerate() {
        assert!(
            elapsed >= timeout && elapsed < timeout + Duration::from_secs(5),
            "{elapsed:?}"
        );
        let rank = Rank(u32::try_from(r).unwrap());
        assert_eq!(
            err,
            CommError::Timeout {
                rank,
                from: Some(Rank(1 - rank.0)),
                tag: 99,
                waited: timeout
            }
        );
        let msg = err.to_string();
        assert!(
            msg.contains(&format!("rank {r}:")) && msg.contains("0x63"),
            "{msg}"
        );
    }
}

#[test]
fn collective_timeout_when_a_rank_never_joins() {
    let out = LocalCommunicator::run(3, |comm| {
        if comm.rank() == Rank(2) {
            return None;
        }
        let start = Instant::now();
        let err = comm.barrier(Duration::from_millis(500)).unwrap_err();
        assert!(start.elapsed() < Duration::from_secs(5));
        Some(err)
    });
    for err in out.into_iter().flatten() {
        assert!(
            matches!(
                err,
                CommError::Timeout {
                    from: Some(Rank(2)),
                    ..
                }
            ),
            "{err}"
        );
    }
}

#[test]
fn an_aborting_rank_wakes_its_blocked_peers() {
    let out = LocalCommunicator::run(4, |comm| {
        let start = Instant::now();
        let result = if comm.rank() == Rank(3) {
            std::thread::sleep(Duration::from_millis(50));
            comm.abort("disk on fire");
            comm.recv(None, 1, LONG)
        } else {
            comm.recv(None, 1, LONG)
        };
        (result, start.elapsed())
    });
    for (r, (result, elapsed)) in out.into_iter().enumerate() {
        assert!(
            elapsed < Duration::from_secs(5),
            "rank {r} waited {elapsed:?}"
        );
        match result {
            Err(CommError::Aborted {
                rank,
                by: Rank(3),
                reason,
            }) => {
                assert_eq!(rank.index(), r);
                assert_eq!(reason, "disk on fire");
            }
            other => panic!("rank {r}: {other:?}"),
        }
    }
}

#[test]
fn sends_after_an_abort_fail() {
    let out = LocalCommunicator::run(2, |comm| {
        if comm.rank() == Rank(0) {
            comm.abort("stop");
        } else {
            // Woken by the abort, or seeing it at once.
            comm.recv(None, 1, LONG).unwrap_err();
        }
        comm.send(Rank(1 - comm.rank().0), 1, vec![1]).unwrap_err()
    });
    assert!(
        out.iter()
            .all(|e| matches!(e, CommError::Aborted { by: Rank(0), .. })),
        "{out:?}"
    );
}

#[test]
fn a_panicking_rank_aborts_the_group() {
    let peers_saw = std::sync::Mutex::new(Vec::new());
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        LocalCommunicator::run(3, |comm| {
            assert!(comm.rank() != Rank(1), "rank 1 fails on purpose");
            let err = comm.recv(None, 5, LONG).unwrap_err();
            peers_saw.lock().unwrap().push(err);
        })
    }));
    assert!(result.is_err(), "the rank's panic is re-raised");
    let saw = peers_saw.into_inner().unwrap();
    assert_eq!(saw.len(), 2);
    assert!(
        saw.iter()
            .all(|e| matches!(e, CommError::Aborted { by: Rank(1), .. })),
        "{saw:?}"
    );
}

#[test]
fn bad_ranks_are_errors_and_bytes_are_counted() {
    let out = LocalCommunicator::run(2, |comm| {
        let e1 = comm.send(Rank(2), 0, vec![1]).unwrap_err();
        let e2 = comm.recv(Some(Rank(5)), 0, LONG).unwrap_err();
        let e3 = comm.gather(Rank(9), Vec::new(), LONG).unwrap_err();
        comm.send(
            Rank(1 - comm.rank().0),
            3,
            vec![0; 10 + comm.rank().index()],
        )
        .unwrap();
        comm.recv(None, 3, LONG).unwrap();
        (e1, e2, e3, comm.bytes_sent())
    });
    assert_eq!(
        out[0].0,
        CommError::NoSuchRank {
            rank: Rank(0),
            got: Rank(2),
            size: 2
        }
    );
    assert_eq!(
        out[1].1,
        CommError::NoSuchRank {
            rank: Rank(1),
            got: Rank(5),
            size: 2
        }
    );
    assert!(matches!(
        out[0].2,
        CommError::NoSuchRank { got: Rank(9), .. }
    ));
    assert_eq!((out[0].3, out[1].3), (10, 11));
    assert!(LocalCommunicator::group(0).is_empty());
    assert!(LocalCommunicator::run(0, |_| ()).is_empty());
}

#[test]
fn communicators_are_usable_as_trait_objects() {
    let sizes = LocalCommunicator::run(2, |comm| {
        let dynamic: &dyn Communicator = comm;
        dynamic.size() + dynamic.rank().index()
    });
    assert_eq!(sizes, vec![2, 3]);
}
