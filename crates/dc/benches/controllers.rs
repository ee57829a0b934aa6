//! The cost of one update of each master synchronization method (the per-cycle work a master
//! adds to its loop).

use criterion::{Criterion, criterion_group, criterion_main};
use ecsync_dc::sync::{CycleInput, MasterSync};
use ecsync_dc::time::{MasterInstant, SystemTime};
use ecsync_dc::{BusShift, MedianSync, PiM2s, Snap, SoemPi};
use std::hint::black_box;

fn bench_one<S: MasterSync>(c: &mut Criterion, mut s: S) {
    let p = 1_000_000u64;
    let mut i = 0u64;
    let name = s.name();
    c.bench_function(&format!("update/{name}"), |b| {
        b.iter(|| {
            i += 1;
            // A plausible input: the reference a little ahead, some jitter in the send time.
            let t = 1_000_000_000 + i * p;
            let jitter = (i.wrapping_mul(0x9e37_79b9) >> 20) % 5_000;
            let input = CycleInput {
                cycle: i,
                period_ns: p as u32,
                nominal_start: MasterInstant::from_ns(t),
                scheduled_start: MasterInstant::from_ns(t),
                send: MasterInstant::from_ns(t + 20_000 + jitter),
                receive: MasterInstant::from_ns(t + 60_000 + jitter),
                ref_time: Some(SystemTime::from_ns(t + 35_000 + jitter + (i % 7) * 10)),
            };
            black_box(s.update(black_box(&input)))
        })
    });
}

fn controllers(c: &mut Criterion) {
    // Past their initialisation, so the benches time the steady-state update.
    bench_one(c, MedianSync::new(11, 0.01, 1));
    bench_one(c, PiM2s::new(0.125, 0.0005, 1));
    bench_one(c, BusShift::default());
    bench_one(c, Snap::default());
    bench_one(c, SoemPi::new(0));
}

criterion_group!(benches, controllers);
criterion_main!(benches);
