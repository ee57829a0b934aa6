//! Every method's update allocates nothing (a counting global allocator), run directly and
//! through the registry's [`Method`] (the per-cycle path of the lab and the real master).

use ecsync_dc::sync::{CycleInput, MasterSync};
use ecsync_dc::time::{MasterInstant, SystemTime};
use ecsync_dc::{
    BusShift, Dcm, DcmMode, DcmParams, MedianFit, MedianSync, Method, MethodContext, MethodKind,
    MethodParams, PiM2s, SetValueRef, Snap, SoemPi,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // Per thread: the test harness's own threads allocate while a test runs (its output
    // capture, its timers), which a process-wide count took for the method's.
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // `try_with`: a thread being torn down has no counter left, and is not the test's.
        let _ = ALLOCS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: forwarding to the system allocator with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn run<S: MasterSync>(mut s: S) -> u64 {
    let before = ALLOCS.with(Cell::get);
    for i in 0..50_000u64 {
        let t = 1_000_000_000 + i * 1_000_000;
        let input = CycleInput {
            cycle: i,
            period_ns: 1_000_000,
            nominal_start: MasterInstant::from_ns(t),
            scheduled_start: MasterInstant::from_ns(t),
            send: MasterInstant::from_ns(t + 20_000 + (i * 7919) % 3_000),
            receive: MasterInstant::from_ns(t + 60_000),
            ref_time: if i % 1000 == 999 {
                None
            } else {
                Some(SystemTime::from_ns(t + 35_000 + i % 13))
            },
        };
        std::hint::black_box(s.update(&input));
    }
    ALLOCS.with(Cell::get) - before
}

#[test]
fn updates_allocate_nothing() {
    assert_eq!(run(MedianSync::default()), 0, "median");
    assert_eq!(run(PiM2s::default()), 0, "pi-m2s");
    assert_eq!(run(BusShift::default()), 0, "bus-shift");
    assert_eq!(run(Snap::default()), 0, "snap");
    assert_eq!(run(SoemPi::new(50_000)), 0, "soem-pi");
    assert_eq!(run(MedianFit::new(11, 0.01, 10_000, 0)), 0, "median-fit");
    let p = DcmParams::default_for(0, 1_000_000);
    assert_eq!(run(Dcm::new(DcmMode::BusShift, p)), 0, "dcm-bus-shift");
    let p = DcmParams {
        set_value_ref: SetValueRef::CycleStart,
        ..p
    };
    assert_eq!(
        run(Dcm::new(DcmMode::MasterShift, p)),
        0,
        "dcm-master-shift"
    );
}

#[test]
fn updates_through_the_registry_allocate_nothing() {
    let ctx = MethodContext {
        cycle_ns: 1_000_000,
        target_phase_ns: 0,
    };
    let params = MethodParams::default();
    for kind in MethodKind::ALL {
        let m: Method = params.build(kind, &ctx);
        assert_eq!(run(m), 0, "{kind}");
    }
}

/// The counter sees an allocation on the test's thread (else the tests above could not fail).
#[test]
fn the_counter_sees_this_threads_allocations() {
    let before = ALLOCS.with(Cell::get);
    let v = std::hint::black_box(vec![1u8; 16]);
    assert!(ALLOCS.with(Cell::get) > before);
    drop(v);
}
