//! Hostile traversal logs: valid logs written by `LogWriter`, then truncated and corrupted
//! at random positions (with and without the chunk CRCs repaired, so that the record
//! decoder sees the corruption and not only the CRC check). Opening, reading ray by ray
//! and summarizing must return an error or data, never panic, never loop without reading,
//! and never allocate from a corrupted count more than the file justifies.

use crate::log::{summarize, LogEncoder, LogHeader, LogRays, LogReader, LoggedRay, NodeSet};
use crate::log::{LogWriter, HEADER_BYTES};
use crate::testutil::{random_rays, soup};
use crate::{
    Accel, Bvh2Accel, KernelOptions, Mbvh4Accel, Mbvh8Accel, Query, RayStats, TraversalStack,
};
use crate::{TraceError, Traverse};
use geom::Aabb;
use proptest::prelude::*;
use std::path::Path;

/// A valid log of 40 rays (closest and any-hit) through a tree of `width` 2, 4 or 8, in
/// three chunks; and the counters the tracer measured.
fn valid_log(width: u32, path: &Path) -> RayStats {
    let tris = soup(64, 1.5, 21);
    let t = bvh::SweepSahBuilder::default()
        .build(&bvh::triangle_aabbs(&tris))
        .unwrap();
    let b = tris.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb()));
    let rays = random_rays(40, b.center(), b.extent().max_element() * 0.6, 5);
    let o = KernelOptions::default();
    let accel = match width {
        2 => Accel::Bvh2(Bvh2Accel::new(t, &tris, o).unwrap()),
        4 => Accel::Mbvh4(Mbvh4Accel::new(bvh::collapse(&t).unwrap(), &tris, o).unwrap()),
        _ => Accel::Mbvh8(Mbvh8Accel::from_bvh2(&t, &tris, o).unwrap()),
    };
    let mut stack = TraversalStack::new();
    let mut enc = LogEncoder::new(width);
    let mut stats = RayStats::default();
    let mut chunks = Vec::new();
    for (i, r) in rays.iter().enumerate() {
        enc.set_ray(i as u32, (i % 3) as u8);
        let q = if i % 4 == 0 {
            Query::Any
        } else {
            Query::Closest
        };
        accel.trace_observed(r, q, &mut stack, &mut stats, &mut enc);
        if i % 15 == 14 {
            chunks.push(enc.take());
        }
    }
    chunks.push(enc.take());
    let header = LogHeader {
        width,
        node_bytes: 64 * width / 2,
        node_count: accel.node_count() as u64,
        leaf_entries: tris.len() as u64,
        image_width: 40,
        image_height: 1,
        rays: LogRays::Diffuse,
        bounces: 2,
        distance_stack: true,
        seed: 3,
    };
    let mut w = LogWriter::create(path, &header).unwrap();
    for (bytes, n) in &chunks {
        w.write_chunk(bytes, *n).unwrap();
    }
    w.finish().unwrap();
    stats
}

/// Recomputes the CRC of every chunk whose header and payload lie inside `f`.
fn repair_crcs(f: &mut [u8]) {
    let mut pos = HEADER_BYTES;
    while pos + 16 <= f.len() && &f[pos..pos + 4] == b"CHNK" {
        let len = u32::from_le_bytes(f[pos + 4..pos + 8].try_into().unwrap()) as usize;
        let end = pos + 16 + len;
        if end > f.len() {
            return;
        }
        let crc = crc32fast::hash(&f[pos + 16..end]);
        f[pos + 12..pos + 16].copy_from_slice(&crc.to_le_bytes());
        pos = end;
    }
}

/// One damage to a log file; positions are taken modulo the file length.
#[derive(Clone, Debug)]
enum Damage {
    /// Cut the file to a length.
    Truncate(usize),
    /// Set one byte.
    Byte(usize, u8),
    /// Set four bytes to a little-endian value (counts, lengths, tags).
    Word(usize, u32),
    /// Remove a run of bytes.
    Remove(usize, usize),
    /// Insert bytes.
    Insert(usize, Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    let at = any::<usize>();
    let word = prop_oneof![
        Just(0u32),
        Just(u32::MAX),
        Just(1u32 << 30),
        Just((1u32 << 30) + 1),
        0u32..300,
        any::<u32>(),
    ];
    prop_oneof![
        at.prop_map(Damage::Truncate),
        (at, any::<u8>()).prop_map(|(p, b)| Damage::Byte(p, b)),
        (
            at,
            prop_oneof![Just(0xFFu8), Just(0x80), Just(0x0A), 0u8..12]
        )
            .prop_map(|(p, b)| Damage::Byte(p, b)),
        (at, word).prop_map(|(p, w)| Damage::Word(p, w)),
        (at, 1usize..9).prop_map(|(p, n)| Damage::Remove(p, n)),
        (at, proptest::collection::vec(any::<u8>(), 1..9)).prop_map(|(p, b)| Damage::Insert(p, b)),
    ]
}

impl Damage {
    fn apply(&self, f: &mut Vec<u8>) {
        let n = f.len().max(1);
        match self {
            Damage::Truncate(p) => f.truncate(p % n),
            Damage::Byte(p, b) => {
                if let Some(x) = f.get_mut(p % n) {
                    *x = *b;
                }
            }
            Damage::Word(p, w) => {
                let p = p % n;
                for (k, b) in w.to_le_bytes().into_iter().enumerate() {
                    if let Some(x) = f.get_mut(p + k) {
                        *x = b;
                    }
                }
            }
            Damage::Remove(p, k) => {
                let p = p % n;
                let end = (p + k).min(f.len());
                f.drain(p.min(end)..end);
            }
            Damage::Insert(p, b) => {
                let p = (p % n).min(f.len());
                f.splice(p..p, b.iter().copied());
            }
        }
    }
}

/// Reads `path` every way there is; each must end in data or an error.
fn read_all_ways(path: &Path) -> Result<u64, TraceError> {
    let file_len = std::fs::metadata(path).unwrap().len();
    let summary = summarize(path);
    let mut r = LogReader::open(path)?;
    let mut ray = LoggedRay::default();
    let mut rays = 0u64;
    let read = loop {
        match r.next_ray(&mut ray) {
            Ok(true) => {
                rays += 1;
                // Every ray takes bytes of the file: no endless reading.
                assert!(rays <= file_len, "{rays} rays from {file_len} bytes");
                // Events are records of the file too.
                assert!(ray.events.len() as u64 <= file_len);
            }
            Ok(false) => break Ok(rays),
            Err(e) => break Err(e),
        }
    };
    // After the end or an error, further calls still return (no panic).
    for _ in 0..3 {
        let _ = r.next_ray(&mut ray);
    }
    match (&summary, &read) {
        (Ok(s), Ok(n)) => {
            // The reader and the summary read the same rays.
            assert_eq!(s.total.rays, *n);
            let by_bounce: u64 = s.per_bounce.iter().map(|b| b.rays).sum();
            assert_eq!(by_bounce, *n);
            assert!(s.distinct_nodes <= s.header.unwrap().node_count);
        }
        (Ok(_), Err(e)) => panic!("summarize accepted what the reader refused: {e}"),
        _ => {}
    }
    summary.map(|s| s.total.rays)
}

#[test]
fn valid_logs_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    for width in [2, 4, 8] {
        let path = dir.path().join(format!("w{width}.bin"));
        let stats = valid_log(width, &path);
        assert_eq!(read_all_ways(&path).unwrap(), 40);
        let s = summarize(&path).unwrap();
        assert_eq!(s.total, stats, "width {width}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random damage: an error or data, never a panic.
    #[test]
    fn damaged_logs_never_panic(
        width in prop_oneof![Just(2u32), Just(4), Just(8)],
        damages in proptest::collection::vec(damage(), 1..4),
        repair in any::<bool>(),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.bin");
        valid_log(width, &path);
        let mut f = std::fs::read(&path).unwrap();
        for d in &damages {
            d.apply(&mut f);
        }
        if repair {
            repair_crcs(&mut f);
        }
        std::fs::write(&path, &f).unwrap();
        let _ = read_all_ways(&path);
    }

    /// Damage confined to chunk payloads, CRCs repaired: the record decoder itself meets
    /// every kind of corrupt record.
    #[test]
    fn corrupt_records_never_panic(
        width in prop_oneof![Just(2u32), Just(4), Just(8)],
        bytes in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..6),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.bin");
        valid_log(width, &path);
        let mut f = std::fs::read(&path).unwrap();
        // Payload bytes only: after the header and each chunk's 16-byte head, before
        // the 24-byte trailer.
        let payload: Vec<usize> = {
            let mut v = Vec::new();
            let mut pos = HEADER_BYTES;
            while &f[pos..pos + 4] == b"CHNK" {
                let len = u32::from_le_bytes(f[pos + 4..pos + 8].try_into().unwrap()) as usize;
                v.extend(pos + 16..pos + 16 + len);
                pos += 16 + len;
            }
            v
        };
        for (p, b) in &bytes {
            f[payload[p % payload.len()]] = *b;
        }
        repair_crcs(&mut f);
        std::fs::write(&path, &f).unwrap();
        let _ = read_all_ways(&path);
    }
}

#[test]
fn a_corrupted_node_count_allocates_nothing_large() {
    // A header claiming 2^64 - 1 nodes over a file of a few hundred bytes: the distinct
    // node count is kept in a set of the nodes met, not in a 512 MiB bitmap.
    let set = NodeSet::new(u64::MAX, 300);
    assert!(matches!(set, NodeSet::Sparse(..)));
    let set = NodeSet::new(1 << 20, 300);
    assert!(matches!(set, NodeSet::Bits(ref w, _) if w.len() == (1 << 14)));
    // And the log still summarizes, counting the nodes it names.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("log.bin");
    valid_log(2, &path);
    let good = summarize(&path).unwrap();
    let mut f = std::fs::read(&path).unwrap();
    f[20..28].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(&path, &f).unwrap();
    let s = summarize(&path).unwrap();
    assert_eq!(s.distinct_nodes, good.distinct_nodes);
    assert_eq!(s.total, good.total);
}

#[test]
fn an_index_delta_beyond_i64_is_an_error() {
    // A node delta of zigzag(i64::MAX) from a base above 0 overflowed i64 before.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("log.bin");
    let header = LogHeader {
        width: 2,
        node_bytes: 64,
        node_count: 10,
        leaf_entries: 1,
        image_width: 1,
        image_height: 1,
        rays: LogRays::Primary,
        bounces: 0,
        distance_stack: false,
        seed: 0,
    };
    let mut p = vec![0x01, 0x00, 0x00, 0x00]; // RAY, pixel 0, bounce 0, closest
    p.extend_from_slice(&[0u8; 32]);
    p.extend_from_slice(&[0x09, 0x0A]); // NODE_FULL to node 5 (zigzag 10)
    p.push(0x09); // NODE_FULL, delta zigzag(u64::MAX - 1) = i64::MAX
    p.extend_from_slice(&[0xFE, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01]);
    p.extend_from_slice(&[0x08, 0x00]); // END, no hit
    let mut w = LogWriter::create(&path, &header).unwrap();
    w.write_chunk(&p, 1).unwrap();
    w.finish().unwrap();
    let e = summarize(&path).unwrap_err();
    assert!(e.to_string().contains("delta"), "{e}");
}
