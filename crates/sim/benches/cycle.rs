//! Criterion benches of the simulator's hot path: one 1 ms cycle of the paper-2024 segment in
//! OP, with the letter's frame (FRMW + 204 B LRW + BRD 0x092C), and its parts.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ecsync_sim::bench::CycleBench;
use std::hint::black_box;

fn cycle(c: &mut Criterion) {
    let mut b = CycleBench::paper_2024();
    let slaves = b.slaves() as u64;
    let mut work = vec![0u8; 1514];
    let mut g = c.benchmark_group("segment");
    g.throughput(Throughput::Elements(slaves));
    g.bench_function("cycle_frmw_lrw204_brd_6_slaves", |bn| {
        bn.iter(|| black_box(b.run(1, &mut work)))
    });
    // The same segment with only parts of the frame, to see where the time goes.
    for (name, keep) in [
        ("frmw_only", 0usize),
        ("lrw_only", 1),
        ("brd_only", 2),
        ("nop_only", 3),
    ] {
        let mut part = b.clone();
        part.keep_single_datagram(keep);
        g.bench_function(name, |bn| bn.iter(|| black_box(part.run(1, &mut work))));
    }
    g.finish();
}

criterion_group!(benches, cycle);
criterion_main!(benches);
