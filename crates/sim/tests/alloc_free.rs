//! The simulator's hot path allocates nothing: a counting global allocator watches 20 000
//! cycles of the paper-2024 segment in OP (FRMW + 204 B LRW + BRD 0x092C per frame: every
//! datagram passes every ESC's processing unit, the DC loop runs, the FMMUs map process data).

use ecsync_sim::bench::CycleBench;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    /// This thread's allocations: `cargo test` runs the tests of a file on threads of one
    /// process, and one test's allocations must not count in another's.
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

/// Counts one allocation of the calling thread (none while the thread is being torn down).
fn count() {
    let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
}

/// The calling thread's allocations so far.
fn allocs_so_far() -> u64 {
    ALLOCS.with(Cell::get)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarding to the system allocator with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_cycle_processing_allocates_nothing() {
    let mut b = CycleBench::paper_2024();
    let mut work = vec![0u8; 1514];
    b.run(100, &mut work);
    let before = allocs_so_far();
    // 20 s of simulated time: crosses the crystals' wander grid (10 s) too.
    let wkc = b.run(20_000, &mut work);
    let after = allocs_so_far();
    assert_eq!(wkc, b.expected_lrw_wkc, "the cycle did its work");
    assert_eq!(after - before, 0, "allocations in 20 000 cycles");
}

/// serve plays the drives' watchdogs between every two frames: a call that expires nothing
/// allocates nothing, and one that does allocates no more than the ESCs' own expiries do when
/// called one by one (it used to collect the positions in a Vec that its caller dropped); the
/// count it returns is the slaves its expiry took out of OP, as their AL state tells, and a
/// second call finds none left to expire.
#[test]
fn expiring_watchdogs_between_frames_allocates_nothing_of_its_own() {
    let mut b = CycleBench::paper_2024();
    let mut work = vec![0u8; 1514];
    b.run(100, &mut work);
    let in_op = |s: &ecsync_sim::Segment| {
        (0..s.len())
            .filter(|&p| s.esc(p).al_state() == ecsync_wire::AlState::Op)
            .count()
    };
    let op_before = in_op(&b.segment);
    let mut one_by_one = b.segment.clone();
    // Nothing written for far longer than any watchdog's 100 ms.
    let later_ps = b.start_ps + 2_000_000_000_000;
    let allocs = |f: &mut dyn FnMut() -> usize| {
        let before = allocs_so_far();
        let n = f();
        (n, allocs_so_far() - before)
    };
    let (first, first_allocs) = allocs(&mut || b.segment.expire_watchdogs(b.start_ps));
    assert_eq!((first, first_allocs), (0, 0), "outputs written this cycle");
    let (expired, by_segment) = allocs(&mut || b.segment.expire_watchdogs(later_ps));
    let (by_hand, by_escs) = allocs(&mut || {
        (0..one_by_one.len())
            .filter(|&p| one_by_one.esc_mut(p).expire_watchdog(later_ps))
            .count()
    });
    assert_eq!(by_segment, by_escs, "allocations beyond the ESCs' own");
    assert!(expired > 0, "no watchdog expired");
    assert_eq!(expired, by_hand);
    assert_eq!(expired, op_before - in_op(&b.segment), "left OP");
    let (again, again_allocs) = allocs(&mut || b.segment.expire_watchdogs(later_ps));
    assert_eq!((again, again_allocs), (0, 0), "an expired watchdog is off");
}
