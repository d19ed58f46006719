//! Read latency of a memory system under a controlled load, to take apart the loaded read
//! latency of MergeTree's final merge (`docs/mergetree-vs-thesis.md`, "Fast system: what
//! the gap is made of").
//!
//! `cargo run --release -p sim --example dram_latency -- SYSTEM READS_IN_FLIGHT READ_BYTES
//! WRITE_BYTES_PER_CYCLE [WRITE_BYTES [STREAMS]]`: keeps `READS_IN_FLIGHT` reads of
//! `READ_BYTES` outstanding, taking turns over `STREAMS` (default 1) sequential streams
//! 256 KiB long and 256 KiB apart (partial-sort runs of M = 8192 elements, as the final
//! merge's refills of its active runs are; stream `s` starts `s * 37 * 512` bytes into its
//! run and wraps around it), and offers sequential writes of `WRITE_BYTES` (default 512, the emitter's chunk)
//! from 1 GiB at a mean `WRITE_BYTES_PER_CYCLE` (unit cycles of 1 ns), issued as soon as
//! the port takes them. Prints the mean read latency (acceptance to last burst) in unit
//! cycles, the read and write bandwidth achieved, and the row-hit rate, over 20,000 reads.

use sim::dram::{self, AccessKind, MemRequest};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        return Err("usage: dram_latency SYSTEM READS_IN_FLIGHT READ_BYTES \
                    WRITE_BYTES_PER_CYCLE [WRITE_BYTES]"
            .into());
    }
    let system = &args[0];
    let in_flight: usize = args[1].parse()?;
    let read_bytes: u32 = args[2].parse()?;
    let write_rate: f64 = args[3].parse()?;
    let write_bytes: u32 = args.get(4).map_or(Ok(512), |s| s.parse())?;
    let streams: u64 = args.get(5).map_or(Ok(1), |s| s.parse())?;
    let mut port = dram::open(system, 1_000_000)?;
    let total_reads = 20_000u64;
    let (mut sent_reads, mut done_reads, mut lat_sum) = (0u64, 0u64, 0u64);
    let mut next_write = 1u64 << 30;
    let (mut credit, mut tag, mut outstanding_reads) = (0.0f64, 0u64, 0usize);
    let mut pending_write: Option<MemRequest> = None;
    while done_reads < total_reads {
        while outstanding_reads < in_flight && sent_reads < total_reads {
            let r = MemRequest {
                tag,
                addr: (sent_reads % streams) << 18
                    | ((sent_reads % streams * 37 * 512
                        + sent_reads / streams * read_bytes as u64)
                        & ((1 << 18) - 1)),
                bytes: read_bytes,
                kind: AccessKind::Read,
            };
            if port.send(r).is_err() {
                break;
            }
            tag += 1;
            sent_reads += 1;
            outstanding_reads += 1;
        }
        credit += write_rate;
        if pending_write.is_none() && credit >= write_bytes as f64 {
            credit -= write_bytes as f64;
            pending_write = Some(MemRequest {
                tag: u64::MAX,
                addr: next_write,
                bytes: write_bytes,
                kind: AccessKind::Write,
            });
            next_write += write_bytes as u64;
        }
        if let Some(w) = pending_write {
            if port.send(w).is_ok() {
                pending_write = None;
            }
        }
        port.tick();
        while let Some(r) = port.pop_response() {
            if r.kind == AccessKind::Read {
                done_reads += 1;
                outstanding_reads -= 1;
                lat_sum += r.completed_cycle - r.accepted_cycle;
            }
        }
    }
    let s = port.stats();
    let cycles = port.cycle() as f64;
    println!(
        "{system} reads_in_flight={in_flight} read_bytes={read_bytes} write_rate={write_rate} \
         write_bytes={write_bytes} streams={streams}: read latency {:.1} cycles, read {:.2} B/cycle, write {:.2} \
         B/cycle, row hits {:.1}%",
        lat_sum as f64 / done_reads as f64,
        s.bytes_read as f64 / cycles,
        s.bytes_written as f64 / cycles,
        100.0 * s.row_hits as f64 / (s.row_hits + s.row_misses).max(1) as f64
    );
    Ok(())
}
