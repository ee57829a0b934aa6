use super::*;

const US: u64 = 1_000_000; // ps

fn unit(ppm: f64, start: u64) -> DcUnit {
    DcUnit::new(DcParams {
        sof_resolution_ns: 10,
        crystal: CrystalParams {
            ppm,
            initial_local_ns: start,
            ..Default::default()
        },
        is_64bit: true,
    })
}

#[test]
fn sof_skips_the_tick_quantisation_exactly() {
    let mut x = 0x0bad_cafe_f00d_1234u64;
    for seed in 0..40u64 {
        for res in [10, 40, 80, 1_000] {
            let u = DcUnit::new(DcParams {
                sof_resolution_ns: res,
                crystal: CrystalParams {
                    initial_local_ns: seed * 7 + 3,
                    seed: seed.wrapping_mul(0x9e37_79b9_7f4a_7c15),
                    ..Default::default()
                },
                is_64bit: true,
            });
            let check = |v: u64| {
                assert_eq!(
                    u.sof(v),
                    u.sof(u.clock.quantise(v)),
                    "{v} res {res} seed {seed}"
                );
            };
            let lo = u.sof_phase + 10;
            (lo..lo + 2_000).for_each(check);
            for _ in 0..2_000 {
                x = x
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                check(x.max(lo));
                check((x >> 20).max(lo));
            }
        }
    }
}

#[test]
fn constant_remainders_match_the_operator() {
    let mut x = 0x0123_4567_89ab_cdefu64;
    let edges = [
        0,
        1,
        9,
        10,
        39,
        40,
        41,
        u64::MAX,
        u64::MAX - 1,
        u64::MAX - 39,
    ];
    for i in 0..100_000u64 {
        x = x
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        for v in [x, x >> (i % 64), edges[(i % 10) as usize]] {
            assert_eq!(rem40(v), v % 40, "{v}");
            assert_eq!(rem10(v), v % 10, "{v}");
        }
    }
}

#[test]
fn reading_system_time_adds_the_offset() {
    let mut u = unit(0.0, 5_000);
    u.write(reg::DC_SYSTEM_TIME_OFFSET, &1_000_000u64.to_le_bytes(), 0);
    let mut block = [0u8; DC_BLOCK_LEN];
    u.refresh(&mut block, 0x0910, 0x0918, 2 * US);
    let v = u64::from_le_bytes(block[0x10..0x18].try_into().unwrap());
    assert_eq!(v, 5_000 + 2_000 + 1_000_000);
}

#[test]
fn sign_magnitude_difference_after_a_write() {
    // The register description of 0x092C: bits 30:0 = |local copy - received|, bit 31 = 1
    // when the local copy is smaller than the received time, 0 when greater or equal; reset
    // value 0x00000000.
    let mut u = unit(0.0, 0);
    let read = |u: &mut DcUnit| {
        let mut block = [0u8; DC_BLOCK_LEN];
        u.refresh(&mut block, 0x092c, 0x0930, 100 * US);
        u32::from_le_bytes(block[0x2c..0x30].try_into().unwrap())
    };
    assert_eq!(read(&mut u), 0x0000_0000, "reset value");
    u.write(reg::DC_TIME_DIFF_FILTER_DEPTH, &[0], 0);
    assert_eq!(read(&mut u), 0x0000_0000, "after a filter depth write");
    // Local system time at t = 100 us is 100_000; write 100_300 with delay 0: the local copy
    // is 300 ns smaller than the received time, so bit 31 is set and the magnitude 300.
    u.write(reg::DC_SYSTEM_TIME, &100_300u64.to_le_bytes(), 100 * US);
    assert_eq!(read(&mut u), 0x8000_0000 | 300);
    assert_eq!(u.time_difference_ns(), -300.0);
    // With a delay of 500 ns the local copy minus the delay (99_500) is 200 ns greater than
    // the received 99_300: bit 31 clear.
    u.write(reg::DC_SYSTEM_TIME_DELAY, &500u32.to_le_bytes(), 100 * US);
    u.write(reg::DC_SYSTEM_TIME, &99_300u64.to_le_bytes(), 100 * US);
    assert_eq!(read(&mut u), 200);
    assert_eq!(u.time_difference_ns(), 200.0);
    // Equal ("greater than or equal"): bit 31 clear, the register reads 0x00000000.
    u.write(reg::DC_SYSTEM_TIME, &99_500u64.to_le_bytes(), 100 * US);
    assert_eq!(read(&mut u), 0x0000_0000);
    // Writing the speed counter start resets the register to 0.
    u.write(reg::DC_SYSTEM_TIME, &99_000u64.to_le_bytes(), 100 * US);
    assert_eq!(read(&mut u), 500);
    u.write(
        reg::DC_SPEED_COUNTER_START,
        &0x1000u16.to_le_bytes(),
        100 * US,
    );
    assert_eq!(read(&mut u), 0x0000_0000);
}

#[test]
fn a_32_bit_write_compares_across_the_wrap() {
    // Local system time just after a 2^32 wrap, written value just before it.
    let mut u = unit(0.0, (1u64 << 32) + 40);
    u.write(reg::DC_TIME_DIFF_FILTER_DEPTH, &[0], 0);
    u.write(reg::DC_SYSTEM_TIME, &(u32::MAX - 59).to_le_bytes(), 0);
    assert_eq!(u.time_difference_ns(), 100.0);
}

#[test]
fn the_branch_free_time_difference_is_the_registers() {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let edges = [
        0,
        1,
        -1,
        0x7fff_ffff,
        -0x7fff_ffff,
        0x8000_0000,
        -0x8000_0000,
    ];
    let edges = edges.into_iter().chain([i64::MAX, i64::MIN, i64::MIN + 1]);
    let random = (0..100_000).map(|k| {
        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        // Small and large magnitudes alike.
        (x as i64) >> (k % 64)
    });
    for d in edges.chain(random) {
        assert_eq!(
            encode_time_difference_branch_free(d),
            dc_time::encode_time_difference(d),
            "{d}"
        );
    }
}

#[test]
fn the_loop_pulls_a_drifting_clock_onto_the_reference() {
    // A reference with a perfect clock; this unit runs 80 ppm fast. System time writes every
    // 20 us (static drift compensation), then every 1 ms.
    let mut u = unit(80.0, 0);
    u.write(reg::DC_SPEED_COUNTER_START, &0x1000u16.to_le_bytes(), 0);
    u.write(reg::DC_TIME_DIFF_FILTER_DEPTH, &0x0c00u16.to_le_bytes(), 0);
    let mut t = 0;
    for _ in 0..15_000 {
        t += 20 * US;
        let reference = t / 1000;
        u.write(reg::DC_SYSTEM_TIME, &reference.to_le_bytes(), t);
    }
    let mut worst = 0.0f64;
    for _ in 0..2_000 {
        t += 1_000 * US;
        let reference = t / 1000;
        u.write(reg::DC_SYSTEM_TIME, &reference.to_le_bytes(), t);
        worst = worst.max(u.time_difference_ns().abs());
    }
    assert!(worst < 100.0, "worst |dt| after lock {worst} ns");
    let c = u.clock().drift_correction();
    assert!((c + 80e-6).abs() < 2e-6, "drift correction {c}");
}

#[test]
fn sync0_pulses_on_the_start_time_grid() {
    let mut u = unit(0.0, 0);
    u.write(reg::DC_SYNC0_CYCLE, &1_000_000u32.to_le_bytes(), 0);
    u.write(reg::DC_START_TIME, &5_250_000u64.to_le_bytes(), 0);
    u.write(reg::DC_ACTIVATION, &[0x03], 0);
    assert_eq!(u.next_sync0_after(0), Some(5_250_000));
    assert_eq!(u.next_sync0_after(5_250_000), Some(6_250_000));
    assert_eq!(u.next_sync0_after(7_000_000), Some(7_250_000));
}

/// SYNC1 by the datasheet's rule, computed by hand: the SYNC1 cycle time `d` after a SYNC0
/// pulse, measured anew from the first SYNC0 after each SYNC1.
#[test]
fn sync1_follows_sync0_by_its_cycle_time() {
    let setup = |d: u32, activation: u8| {
        let mut u = unit(0.0, 0);
        u.write(reg::DC_SYNC0_CYCLE, &250_000u32.to_le_bytes(), 0);
        u.write(reg::DC_SYNC1_CYCLE, &d.to_le_bytes(), 0);
        u.write(reg::DC_START_TIME, &5_000_000u64.to_le_bytes(), 0);
        u.write(reg::DC_ACTIVATION, &[activation], 0);
        u
    };
    // Oversampling by 4 (ethercrab #368: d = 250 us x 3): SYNC0 at 5.0, 5.25, 5.5, 5.75 ms...;
    // SYNC1 at 5.75 (5.0 + 0.75), then from the SYNC0 after it (6.0): 6.75, 7.75: every 1 ms.
    let u = setup(750_000, 0x07);
    assert_eq!(u.sync1(), Some((5_750_000, 1_000_000)));
    assert_eq!(u.next_sync1_after(0), Some(5_750_000));
    assert_eq!(u.next_sync1_after(5_750_000), Some(6_750_000));
    assert_eq!(u.next_sync1_after(7_000_000), Some(7_750_000));
    // A delay under the SYNC0 cycle: every SYNC0 pulse, 100 us later.
    let u = setup(100_000, 0x07);
    assert_eq!(u.next_sync1_after(5_100_000), Some(5_350_000));
    // No delay: SYNC1 with every SYNC0; 300 us: the pulse after the one 300 us on (every 2).
    assert_eq!(setup(0, 0x07).sync1(), Some((5_000_000, 250_000)));
    assert_eq!(setup(300_000, 0x07).sync1(), Some((5_300_000, 500_000)));
    // SYNC1 not activated (bit 2 clear): none, and 0x098E says which run.
    let mut u = setup(750_000, 0x03);
    assert_eq!(u.sync1(), None);
    let mut block = [0u8; DC_BLOCK_LEN];
    u.refresh(&mut block, 0x098e, 0x098f, 0);
    assert_eq!(
        block[usize::from(reg::DC_ACTIVATION_STATUS - DC_BLOCK_START)],
        0x01
    );
    let mut u = setup(750_000, 0x07);
    u.refresh(&mut block, 0x098e, 0x098f, 0);
    assert_eq!(
        block[usize::from(reg::DC_ACTIVATION_STATUS - DC_BLOCK_START)],
        0x03
    );
    // 0x0998, the next SYNC1 pulse, as a read at 6.2 ms of system time finds it.
    u.refresh(&mut block, 0x0998, 0x09a0, 6_200 * US);
    let at = usize::from(reg::DC_NEXT_SYNC1 - DC_BLOCK_START);
    let next = u64::from_le_bytes(block[at..at + 8].try_into().unwrap());
    assert_eq!(next, 6_750_000);
}

#[test]
fn sync0_start_in_the_past_waits_for_the_32_bit_wrap() {
    let mut u = unit(0.0, 10_000_000);
    u.write(reg::DC_SYNC0_CYCLE, &1_000_000u32.to_le_bytes(), 0);
    u.write(reg::DC_START_TIME, &1_000u64.to_le_bytes(), 0);
    u.write(reg::DC_ACTIVATION, &[0x03], 0);
    assert_eq!(u.sync0().unwrap().0, 1_000 + (1 << 32));
}

/// 0x0932 and 0x092C as the registers read at `t_ps`.
fn loop_registers(u: &mut DcUnit, t_ps: u64) -> (i16, i32) {
    let mut block = [0u8; DC_BLOCK_LEN];
    u.refresh(&mut block, 0x092c, 0x0936, t_ps);
    let diff = i16::from_le_bytes([block[0x32], block[0x33]]);
    let dt = u32::from_le_bytes(block[0x2c..0x30].try_into().unwrap());
    (diff, dc_time::decode_time_difference(dt))
}

/// A unit as masters set it up (replay-dc.pcapng: 0x0934 = 0x00, 0x0935 = 0x0C, then 0x0930 =
/// 0x1000).
fn reset_unit(ppm: f64) -> DcUnit {
    let mut u = unit(ppm, 0);
    u.write(reg::DC_TIME_DIFF_FILTER_DEPTH, &[0x00, 0x0c], 0);
    u.write(reg::DC_SPEED_COUNTER_START, &0x1000u16.to_le_bytes(), 0);
    u
}

#[test]
fn the_speed_counter_diff_formula() {
    // Section II, note to 0x0932: deviation = diff / (5 (start + diff + 2)(start - diff + 2)).
    // At 0x1000: diff 188 is 188 / (5 * 4286 * 3910) = 2.2437e-6.
    let d = speed_counter_deviation(0x1000, 188.0);
    assert!((d - 188.0 / (5.0 * 4286.0 * 3910.0)).abs() < 1e-15, "{d}");
    assert!((d - 2.2437e-6).abs() < 1e-10, "{d}");
    // Odd in diff, and read back.
    assert_eq!(speed_counter_deviation(0x1000, -188.0), -d);
    assert!((speed_counter_diff_for(0x1000, d) - 188.0).abs() < 1e-9);
    assert_eq!(speed_counter_diff_for(0x1000, 0.0), 0.0);
    // The range's end, diff = start - 0x7F = 3969: 3969 / (5 * 8067 * 129) = 762.8 ppm.
    let end = speed_counter_deviation(0x1000, 3969.0);
    assert!((end - 3969.0 / (5.0 * 8067.0 * 129.0)).abs() < 1e-15);
    assert!((speed_counter_diff_for(0x1000, end) - 3969.0).abs() < 1e-6);
}

#[test]
fn the_mean_difference_averages_what_it_has_since_the_reset() {
    // 0x0934 = 4: a mean of up to 16 differences. Three writes at the same instant (no phase
    // step in between; local system time 100_000): -300, then the mean of -300 and -100, then
    // of -300, -100 and +100.
    let mut u = unit(0.0, 0);
    u.write(reg::DC_TIME_DIFF_FILTER_DEPTH, &[0x04], 0);
    u.write(reg::DC_SPEED_COUNTER_START, &0x1000u16.to_le_bytes(), 0);
    let t = 100 * US;
    for (written, mean) in [(100_300u64, -300), (100_100, -200), (99_900, -100)] {
        u.write(reg::DC_SYSTEM_TIME, &written.to_le_bytes(), t);
        assert_eq!(loop_registers(&mut u, t).1, mean, "after {written}");
    }
}

#[test]
fn a_constant_drift_is_learned_and_shown_in_0x0932() {
    // A crystal 2.24 ppm fast (the EL2889 against the EK1100 in the captures), a perfect
    // reference, a write every millisecond. The clock period deviation's mean after N writes
    // is the change of the difference over the (N - 1) ms its own steps do not explain: the
    // drift, within the 10 ns quantisation of the two ends over 1 s (0.02 ppm).
    let mut u = reset_unit(2.24);
    let mut t = 0;
    for _ in 0..1_001 {
        t += 1_000 * US;
        u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    }
    let c = u.clock().drift_correction();
    assert!((c + 2.24e-6).abs() < 0.03e-6, "correction {c}");
    // 0x0932: the loop slows a fast crystal, a negative diff; by the formula 2.24e-6 is
    // 2.24e-6 * 5 * (4098^2 - 188^2) = 187.7, and 0.03 ppm is 2.5 of its steps.
    let (diff, dt) = loop_registers(&mut u, t);
    assert!((-191..=-185).contains(&diff), "0x0932 = {diff}");
    let shown = speed_counter_deviation(0x1000, f64::from(diff));
    assert!((shown - c).abs() < 0.01e-6, "{shown} against {c}");
    assert!(dt.abs() <= 20, "0x092C {dt}");
    // 0x0930 written: 0x092C and 0x0932 read 0, and the next write only starts an interval.
    u.write(reg::DC_SPEED_COUNTER_START, &0x1000u16.to_le_bytes(), t);
    assert_eq!(loop_registers(&mut u, t), (0, 0));
    t += 1_000 * US;
    u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    assert_eq!(u.clock().drift_correction(), 0.0);
}

#[test]
fn the_correction_stays_within_the_speed_counter_range() {
    // 1 000 ppm fast is beyond 0x0932's range at 0x1000 (±3969, 762.8 ppm): the loop holds
    // the range's end and the register reads -3969.
    let mut u = reset_unit(1_000.0);
    let mut t = 0;
    for _ in 0..200 {
        t += 1_000 * US;
        u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    }
    let end = speed_counter_deviation(0x1000, 3969.0);
    assert_eq!(u.clock().drift_correction(), -end);
    assert_eq!(loop_registers(&mut u, t).0, -3969);
}

#[test]
fn a_late_write_leaves_the_mean_with_the_next_interval() {
    // After 1 000 intervals of 1 ms (the mean not yet full at depth 12: all of them count),
    // one write whose time is 5 us behind (its frame left late, a master's send jitter): its
    // interval shows the local clock 5 000 ppm fast, and weighing 1 ms of the 1.001 s it moves
    // the mean by -5 ppm; the next interval shows the same 5 us the other way and takes it
    // back, to within the stamps' 10 ns over the 1.002 s (0.01 ppm).
    let mut u = reset_unit(2.24);
    let mut t = 0;
    for _ in 0..1_001 {
        t += 1_000 * US;
        u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    }
    let before = u.clock().drift_correction();
    t += 1_000 * US;
    u.write(reg::DC_SYSTEM_TIME, &(t / 1000 - 5_000).to_le_bytes(), t);
    let spiked = u.clock().drift_correction() - before;
    assert!((spiked + 5e-6).abs() < 0.05e-6, "moved by {spiked}");
    t += 1_000 * US;
    u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    let after = u.clock().drift_correction() - before;
    assert!(after.abs() < 0.01e-6, "left {after}");
    // A frame resent 10 us after the last, 20 ns off: 2 000 ppm over its 10 us, weighing 10 us
    // (-0.02 ppm); the next interval, 990 us, takes the 20 ns back. (A mean over the writes
    // instead of their time would keep about -2 ppm of it: 2 000 ppm / 1 003.)
    let before = u.clock().drift_correction();
    u.write(
        reg::DC_SYSTEM_TIME,
        &((t + 10 * US) / 1000 - 20).to_le_bytes(),
        t + 10 * US,
    );
    t += 1_000 * US;
    u.write(reg::DC_SYSTEM_TIME, &(t / 1000).to_le_bytes(), t);
    let after = u.clock().drift_correction() - before;
    assert!(after.abs() < 0.01e-6, "left {after}");
}

/// MII stamps are taken on the crystal's 25 MHz edges, the counter counts the crystal plus the
/// loop's corrections. Worked by hand: a clock never corrected (a reference) reads 0x0910 on
/// one residue modulo 40 ns at every frame (replay-dc: every FRMW the EK1100 answered is 0
/// modulo 40); a clock corrected by +20 ppm gains 40 ns on its crystal every 2 ms, so its
/// stamps, read every 100 us over 4 ms, fall on all four 10 ns residues.
#[test]
fn mii_stamps_are_on_the_crystals_grid_not_the_corrected_time() {
    let mii = |seed: u64| {
        DcUnit::new(DcParams {
            sof_resolution_ns: 40,
            crystal: CrystalParams {
                initial_local_ns: 1_000_000 + seed,
                seed,
                ..Default::default()
            },
            is_64bit: true,
        })
    };
    let residues = |u: &mut DcUnit| {
        let mut seen = std::collections::BTreeSet::new();
        for k in 1..=40u64 {
            let t = k * 100 * US + k * 7_777; // arbitrary instants within the cells
            u.clock.advance_to(t);
            seen.insert(u.system_time_read_ns(t) % 40);
        }
        seen
    };
    for seed in 0..8 {
        let mut reference = mii(seed);
        assert_eq!(residues(&mut reference).len(), 1, "seed {seed}");
        let mut corrected = mii(seed);
        corrected.clock.set_drift_correction(0, 20e-6);
        let r = residues(&mut corrected);
        assert_eq!(r.len(), 4, "seed {seed}: {r:?}");
        assert!(r.iter().all(|x| x % 10 == r.first().unwrap() % 10));
    }
}
