//! The harness itself: the allocation cap catches an oversized allocation, and headers that
//! claim far more voxels than their data holds fail before allocating for them.

use pofvr_fuzz::alloc::{self, Capped};
use pofvr_fuzz::target::{by_name, Scratch, TARGETS};

#[global_allocator]
static ALLOC: Capped = Capped;

// One test function: the cap is process-wide, and tests run on parallel threads.
#[test]
fn the_cap_catches_big_allocations_and_huge_headers_stay_under_it() {
    alloc::arm(1 << 20);
    let v: Vec<u8> = Vec::with_capacity(8 << 20);
    assert_eq!(alloc::disarm(), Some(8 << 20));
    drop(v);

    let s = Scratch::new();
    let huge: [(&str, &[u8]); 5] = [
        ("nrrd", b"NRRD0004\ntype: float\ndimension: 3\nsizes: 10000 10000 10000\nencoding: gzip\n\n\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03"),
        ("nrrd", b"NRRD0004\ntype: float\ndimension: 3\nsizes: 10000 10000 10000\nencoding: raw\n\n"),
        ("nhdr", b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 100000 100000 100\nencoding: gzip\ndata file: d.raw.gz\n"),
        ("mha", b"NDims = 3\nDimSize = 10000 10000 10000\nElementType = MET_FLOAT\nCompressedData = True\nElementDataFile = LOCAL\nx\x9c"),
        ("mhd", b"NDims = 3\nDimSize = 10000 10000 10000\nElementType = MET_UCHAR\nElementDataFile = d.raw\n"),
    ];
    for (name, bytes) in huge {
        let t = by_name(name).unwrap();
        alloc::arm(t.allocation_limit(bytes.len()));
        let accepted = t.run(&s, bytes);
        let over = alloc::disarm();
        let text = String::from_utf8_lossy(bytes);
        assert!(!accepted, "{name}: {text:?}");
        assert_eq!(over, None, "{name}: {text:?}");
    }
    // Every seed passes its target.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus");
    for t in TARGETS {
        for e in std::fs::read_dir(t.corpus(&root)).unwrap() {
            let data = std::fs::read(e.unwrap().path()).unwrap();
            alloc::arm(t.allocation_limit(data.len()));
            t.run(&s, &data);
            assert_eq!(alloc::disarm(), None, "{}", t.name);
        }
    }
}
