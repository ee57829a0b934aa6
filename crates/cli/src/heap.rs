//! The simulator's heap on transparent huge pages (Linux with glibc).
//!
//! A large network's cycle touches a few cache lines of every ESC: its state in the segment,
//! its process RAM, each in pages of their own. At a thousand drives that is more 4 KiB pages
//! than the TLB holds, and every visit walks the page tables (in a virtual machine, two
//! levels of them). With the heap on 2 MiB pages the same cycle takes a few hundred: `ecsync
//! bench --slaves 6,256,1000,1500`, side by side, went from 64.8-69.2 to 59.5-59.8 ns per
//! slave-cycle at 1 000 drives and from 99.5-103.4 to 72.7-75.3 at 1 500 (the README's
//! "Speed"). What glibc's `glibc.malloc.hugetlb=1` tunable does, asked for from within: the
//! tunable is read only at start-up, from the environment.
//!
//! Nothing the simulator computes depends on it; only where its memory lies.

/// The heap grows in steps of this (virtual: only what is touched is backed).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const HEAP_STEP: usize = 512 << 20;

/// Grows the heap by [`HEAP_STEP`] now and asks for huge pages under it; allocations of up to
/// 64 MiB come from the heap (not each its own mapping of small pages). Best effort: where the
/// kernel has no transparent huge pages, or the heap cannot grow, nothing changes.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn use_huge_pages() {
    const HUGE_PAGE: usize = 2 << 20;
    // SAFETY: mallopt, malloc, free and sbrk(0) are called as glibc documents them; madvise
    // is given a range of the heap that this process owns (from a huge-page boundary within
    // the block just allocated up to the heap's end) and only advises on it.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 64 << 20);
        libc::mallopt(libc::M_TOP_PAD, HEAP_STEP as libc::c_int);
        libc::mallopt(libc::M_TRIM_THRESHOLD, (2 * HEAP_STEP) as libc::c_int);
        // Larger than the heap's free top: the heap grows by it plus the pad, in one step.
        let block = libc::malloc(HUGE_PAGE);
        if block.is_null() {
            return;
        }
        let end = libc::sbrk(0) as usize;
        let start = (block as usize).next_multiple_of(HUGE_PAGE);
        libc::free(block);
        if end > start + HUGE_PAGE {
            libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
        }
    }
}

/// Elsewhere the heap stays as it is.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn use_huge_pages() {}
