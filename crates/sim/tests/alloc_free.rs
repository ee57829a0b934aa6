//! The simulator's hot path allocates nothing: a counting global allocator watches 20 000
//! cycles of the paper-2024 segment in OP (FRMW + 204 B LRW + BRD 0x092C per frame: every
//! datagram passes every ESC's processing unit, the DC loop runs, the FMMUs map process data).

use ecsync_sim::bench::CycleBench;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarding to the system allocator with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
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
    let before = ALLOCS.load(Ordering::Relaxed);
    // 20 s of simulated time: crosses the crystals' wander grid (10 s) too.
    let wkc = b.run(20_000, &mut work);
    let after = ALLOCS.load(Ordering::Relaxed);
    assert_eq!(wkc, b.expected_lrw_wkc, "the cycle did its work");
    assert_eq!(after - before, 0, "allocations in 20 000 cycles");
}
