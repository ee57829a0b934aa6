//! [`Judge::frame`] allocates nothing in steady state (it runs in serve's real-time loop): a
//! counting global allocator watches 20 000 frames with process data on the letter's segment,
//! after 3 000 that settle the statistics' ranges (sends jittered over 200 us, a frame lost
//! now and then, AL status read in every frame, the host's lateness reported).

use ecsync_lab::judge::{Judge, JudgeOptions, Lost};
use ecsync_sim::clock::CrystalParams;
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};
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

fn frame(dgs: &[(Command, u8, DatagramAddress, &[u8])]) -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
    for (c, i, a, d) in dgs {
        b.push(*c, *i, *a, d).unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

#[test]
fn judging_a_frame_allocates_nothing() {
    let mut specs = ecsync_sim::preset::paper_2024();
    // Ideal crystals: the figures' ranges settle (the statistics' buckets are allocated once
    // per new power-of-two range, so a segment whose clocks drift apart unsynchronised, its
    // spread growing for ever, allocates a chunk at each doubling: 16 in this test with
    // crystals 3 ppm apart).
    for s in &mut specs {
        s.crystal = CrystalParams::default();
    }
    let mut seg = ecsync_sim::Segment::new(&specs).unwrap();
    let mut judge = Judge::new(&seg, JudgeOptions::default());
    let b = |ado| DatagramAddress::Position { adp: 0, ado };
    let mut f = frame(&[
        (
            Command::Bwr,
            1,
            b(reg::DC_START_TIME),
            &10_000_000u64.to_le_bytes(),
        ),
        (
            Command::Bwr,
            2,
            b(reg::DC_SYNC0_CYCLE),
            &1_000_000u32.to_le_bytes(),
        ),
        (Command::Bwr, 3, b(reg::DC_ACTIVATION), &[0x03]),
    ]);
    seg.process(&mut f, 1_000_000_000);
    judge.frame(&seg, &f, 1_000_000_000, Lost::No);
    let template = frame(&[
        (
            Command::Lrw,
            0,
            DatagramAddress::Logical(0x1000),
            &[0u8; 32],
        ),
        (
            Command::Fprd,
            0,
            DatagramAddress::configured(0, reg::AL_STATUS),
            &[0u8; 6],
        ),
    ]);
    let mut work = template.clone();
    let mut run = |judge: &mut Judge, seg: &mut ecsync_sim::Segment, from: u64, to: u64| {
        for n in from..to {
            work.copy_from_slice(&template);
            work[ecsync_wire::ETH_HEADER_LEN + 2 + 1] = n as u8;
            // 200 to 400 us before each pulse, a hash of the cycle; every 500th lost.
            let jitter = ecsync_sim::rng::splitmix64(n) % 200_000;
            let t = ((10_000_000 + n * 1_000_000 - 200_000 - jitter) * 1000) as u64;
            seg.advance_to(t);
            let lost = if n % 500 == 0 { Lost::Out } else { Lost::No };
            if lost == Lost::No {
                seg.process(&mut work, t);
            }
            judge.frame(seg, &work, t, lost);
            judge.reply_late(n % 20_000);
        }
    };
    run(&mut judge, &mut seg, 1, 3_000);
    let before = ALLOCS.load(Ordering::Relaxed);
    run(&mut judge, &mut seg, 3_000, 23_000);
    let after = ALLOCS.load(Ordering::Relaxed);
    let out = judge.summary(&seg);
    assert_eq!(out.pd_frames, 22_999 - 45);
    assert!(out.missed >= 40);
    assert_eq!(after - before, 0, "allocations in 20 000 frames");
}
