//! An oversampling terminal with ethercrab 0.7 the way its users set it up (ethercrab #368,
//! the EL4732 example that works: SYNC0 = the cycle / n, SYNC1 = SYNC0 x (n - 1), the
//! terminal set to DC SYNC1 over CoE), then cycled as ethercrab's documentation cycles a DC
//! group: `tx_rx_dc` and a wait of its `next_cycle_wait`. ethercrab #369 (open): that wait is
//! worked out from the SYNC0 period, so the loop runs at the SYNC0 rate, n frames per cycle;
//! the terminal takes one block per SYNC1 event and the others are overwritten unplayed. Run
//! against `ecsync serve --preset oversampling --sandbox -- oversampling_master`, the judge
//! shows it (`overwritten`).
//!
//! ```text
//! oversampling_master [IFACE] [--cycles N] [--cycle-us US] [--samples N]
//! ```
//!
//! Defaults: 4000 loop iterations, a 1000 us cycle, 4 samples. The terminal is the SubDevice
//! whose 0x1C32:04 offers DC SYNC1 (bit 3); every other DC SubDevice with CoE runs on SYNC0
//! with its 0x1C32:02 set to SYNC0's period (a drive refuses OP with 0x0035 otherwise, SOEM
//! #961). One summary line on stdout: the iterations, the loop's mean period and ethercrab's
//! wait.

use ethercrab::error::Error;
use ethercrab::std::{ethercat_now, tx_rx_task};
use ethercrab::subdevice_group::DcConfiguration;
use ethercrab::{DcSync, MainDevice, MainDeviceConfig, PduStorage, Timeouts};
use std::process::ExitCode;
use std::time::{Duration, Instant};

const MAX_SUBDEVICES: usize = 16;
const MAX_PDI: usize = 512;
const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
static STORAGE: PduStorage<16, MAX_PDU_DATA> = PduStorage::new();

struct Options {
    iface: String,
    cycles: u64,
    cycle: Duration,
    samples: u32,
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        iface: std::env::var("ECSYNC_IFACE").unwrap_or_default(),
        cycles: 4_000,
        cycle: Duration::from_millis(1),
        samples: 4,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = |name: &str| -> Result<u64, String> {
            let v = args.next().ok_or(format!("{name} needs a value"))?;
            v.parse().map_err(|e| format!("{name} {v}: {e}"))
        };
        match a.as_str() {
            "--cycles" => o.cycles = num("--cycles")?,
            "--cycle-us" => o.cycle = Duration::from_micros(num("--cycle-us")?),
            "--samples" => o.samples = num("--samples")?.clamp(1, 100) as u32,
            "-h" | "--help" => {
                return Err(
                    "usage: oversampling_master [IFACE] [--cycles N] [--cycle-us US] [--samples N]"
                        .into(),
                );
            }
            s if !s.starts_with('-') => o.iface = s.to_string(),
            s => return Err(format!("unknown option {s} (--help)")),
        }
    }
    if o.iface.is_empty() {
        return Err("no interface: give it as an argument or in ECSYNC_IFACE".into());
    }
    Ok(o)
}

/// The loop's iterations and its mean period.
async fn run(o: &Options, maindevice: &MainDevice<'_>) -> Result<(u64, Duration), String> {
    let e = |what: &'static str| move |err: Error| format!("{what}: {err:?}");
    let sync0 = o.cycle / o.samples;
    let sync1 = sync0 * (o.samples - 1);
    let mut group = maindevice
        .init_single_group::<MAX_SUBDEVICES, MAX_PDI>(ethercat_now)
        .await
        .map_err(e("the scan"))?;
    let mut terminals = 0;
    for mut sd in group.iter_mut(maindevice) {
        if !sd.dc_support().any() {
            continue;
        }
        let modes: Result<u16, Error> = sd.sdo_read(0x1c32, 4).await;
        match modes {
            Ok(m) if m & 0x08 != 0 => {
                sd.sdo_write(0x1c32, 1, 3u16)
                    .await
                    .map_err(e("0x1C32:01 = 3"))?;
                sd.set_dc_sync(DcSync::Sync01 {
                    sync1_period: sync1,
                });
                terminals += 1;
            }
            Ok(_) => {
                sd.sdo_write(0x1c32, 1, 2u16)
                    .await
                    .map_err(e("0x1C32:01 = 2"))?;
                let c = sync0.as_nanos() as u32;
                sd.sdo_write(0x1c32, 2, c).await.map_err(e("0x1C32:02"))?;
                sd.set_dc_sync(DcSync::Sync0);
            }
            // No CoE (a coupler): no SYNC.
            Err(_) => {}
        }
    }
    if terminals == 0 {
        return Err("no SubDevice offers DC SYNC1 (0x1C32:04 bit 3)".into());
    }
    let group = group
        .into_pre_op_pdi(maindevice)
        .await
        .map_err(e("PRE-OP with process data"))?;
    for _ in 0..2_000 {
        group
            .tx_rx_sync_system_time(maindevice)
            .await
            .map_err(e("static drift compensation"))?;
    }
    let dc = DcConfiguration {
        start_delay: Duration::from_millis(100),
        sync0_period: sync0,
        sync0_shift: sync0 / 2,
    };
    let group = group
        .configure_dc_sync(maindevice, dc)
        .await
        .map_err(e("configure_dc_sync"))?
        .into_safe_op(maindevice)
        .await
        .map_err(e("SAFE-OP"))?
        .request_into_op(maindevice)
        .await
        .map_err(e("requesting OP"))?;
    let t0 = Instant::now();
    loop {
        let now = Instant::now();
        let r = group
            .tx_rx_dc(maindevice)
            .await
            .map_err(e("a cycle before OP"))?;
        if r.all_op() {
            break;
        }
        if t0.elapsed() > Duration::from_secs(10) {
            return Err(format!("not in OP after 10 s: {:?}", r.group_state()));
        }
        async_io::Timer::at(now + r.extra.next_cycle_wait).await;
    }
    // The application's cycle as ethercrab's documentation writes it: new outputs (a block of
    // samples) every iteration, the wait `next_cycle_wait`.
    let start = Instant::now();
    for k in 0..o.cycles {
        let now = Instant::now();
        for sd in group.iter(maindevice) {
            let mut out = sd.outputs_raw_mut();
            for (i, b) in out.iter_mut().enumerate() {
                *b = (k as u8).wrapping_add(i as u8);
            }
        }
        let r = group
            .tx_rx_dc(maindevice)
            .await
            .map_err(e("a cycle in OP"))?;
        async_io::Timer::at(now + r.extra.next_cycle_wait).await;
    }
    let mean = start.elapsed() / o.cycles.max(1) as u32;
    group
        .into_safe_op(maindevice)
        .await
        .map_err(e("OP -> SAFE-OP"))?;
    Ok((o.cycles, mean))
}

fn main() -> ExitCode {
    let o = match options() {
        Ok(o) => o,
        Err(m) => {
            eprintln!("oversampling_master: {m}");
            return ExitCode::from(2);
        }
    };
    let (tx, rx, pdu_loop) = STORAGE.try_split().expect("split once");
    let task = match tx_rx_task(&o.iface, tx, rx) {
        Ok(t) => t,
        Err(err) => {
            eprintln!(
                "oversampling_master: FAILED: a raw socket on {}: {err}",
                o.iface
            );
            return ExitCode::FAILURE;
        }
    };
    std::thread::spawn(move || async_io::block_on(task));
    let timeouts = Timeouts {
        eeprom: Duration::from_millis(500),
        pdu: Duration::from_millis(500),
        ..Timeouts::default()
    };
    let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());
    match futures_lite::future::block_on(run(&o, &maindevice)) {
        Ok((n, mean)) => {
            println!(
                "oversampling_master: {n} iterations of tx_rx_dc, mean period {} us (cycle {} us, SYNC0 {} us, SYNC1 every {} us)",
                mean.as_micros(),
                o.cycle.as_micros(),
                (o.cycle / o.samples).as_micros(),
                o.cycle.as_micros()
            );
            ExitCode::SUCCESS
        }
        Err(m) => {
            eprintln!("oversampling_master: FAILED: {m}");
            ExitCode::FAILURE
        }
    }
}
