//! A master developer's CI test with ethercrab, as it runs against
//! `ecsync serve --sandbox -- ci_master`: the scan, the identity of every SubDevice read by SDO
//! (0x1018:01) against its SII, SYNC0 on every DC SubDevice, ethercrab's DC configuration
//! (its static drift compensation in the scan, `configure_dc_sync`), SAFE-OP and OP, then a
//! number of cycles of process data with `tx_rx_dc`, the working counter checked in every one.
//! The cycle follows the DC time as ethercrab's own examples do (`next_cycle_wait`: the
//! reference's time of the last frame decides when the next one goes).
//!
//! ```text
//! ci_master [IFACE] [--cycles N] [--cycle-us US] [--slaves N] [--jitter-every N --jitter-us U]
//! ```
//!
//! Defaults: 5000 cycles of 4000 us (SYNC0 every cycle, the frames half a cycle after it: room
//! for a loaded CI host at normal priority), 6 SubDevices (0: any). The interface: IFACE, else
//! `ECSYNC_IFACE`. `--jitter-every N --jitter-us U` sleeps U us
//! before the exchange of every N-th cycle: frames pushed past SYNC0 on purpose, for a judge of
//! the master's timing to catch. Exit 0 on success, 1 with the reason on stderr otherwise; one
//! summary line on stdout.
//!
//! Build: `cargo build --release -p ecsync-ethercrab --example ci_master` (the binary is
//! `target/release/examples/ci_master`).

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

/// The command line.
struct Options {
    iface: String,
    cycles: u64,
    cycle: Duration,
    slaves: usize,
    jitter_every: u64,
    jitter: Duration,
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        iface: std::env::var("ECSYNC_IFACE").unwrap_or_default(),
        cycles: 5_000,
        cycle: Duration::from_millis(4),
        slaves: 6,
        jitter_every: 0,
        jitter: Duration::ZERO,
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
            "--slaves" => o.slaves = num("--slaves")? as usize,
            "--jitter-every" => o.jitter_every = num("--jitter-every")?,
            "--jitter-us" => o.jitter = Duration::from_micros(num("--jitter-us")?),
            "-h" | "--help" => return Err(
                "usage: ci_master [IFACE] [--cycles N] [--cycle-us US] [--slaves N (0: any)] [--jitter-every N --jitter-us U]".into(),
            ),
            s if !s.starts_with('-') => o.iface = s.to_string(),
            s => return Err(format!("unknown option {s} (--help)")),
        }
    }
    if o.iface.is_empty() {
        return Err("no interface: give it as an argument or in ECSYNC_IFACE".into());
    }
    Ok(o)
}

/// What the counted cycles saw.
#[derive(Default)]
struct Tally {
    cycles: u64,
    wkc_errors: u64,
    first_bad: Option<(u64, u16)>,
    lateness: Vec<Duration>,
    /// Frames that reached the reference after the SYNC0 they were for (by its time).
    past_sync0: u64,
}

async fn run(o: &Options, maindevice: &MainDevice<'_>) -> Result<(Tally, u16), String> {
    let e = |what: &'static str| move |err: Error| format!("{what}: {err:?}");
    let mut group = maindevice
        .init_single_group::<MAX_SUBDEVICES, MAX_PDI>(ethercat_now)
        .await
        .map_err(e("the scan"))?;
    if o.slaves != 0 && group.len() != o.slaves {
        return Err(format!(
            "{} SubDevices found, expected {}",
            group.len(),
            o.slaves
        ));
    }
    for (i, mut sd) in group.iter_mut(maindevice).enumerate() {
        let vendor: u32 = sd.sdo_read(0x1018, 1).await.map_err(e("SDO 0x1018:01"))?;
        if vendor != sd.identity().vendor_id {
            return Err(format!(
                "SubDevice {i}: 0x1018:01 reads {vendor:#x}, its SII {:#x}",
                sd.identity().vendor_id
            ));
        }
        if sd.dc_support().any() {
            sd.set_dc_sync(DcSync::Sync0);
        }
    }
    let group = group
        .into_pre_op_pdi(maindevice)
        .await
        .map_err(e("PRE-OP with process data"))?;
    let expected: u16 = group
        .iter(maindevice)
        .map(|sd| {
            2 * u16::from(!sd.outputs_raw().is_empty()) + u16::from(!sd.inputs_raw().is_empty())
        })
        .sum();
    let dc = DcConfiguration {
        start_delay: Duration::from_millis(100),
        sync0_period: o.cycle,
        sync0_shift: o.cycle / 2,
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
    let mut t = Tally::default();
    // The frames' aim in DC time: each cycle's deadline shifted by the offset between the
    // host's clock and DC time, from the last cycle that woke on time and did not sleep on
    // purpose; a frame is past its SYNC0 when the reference saw it after the first SYNC0 (a
    // grid point in ethercrab's configuration) after its aim.
    let origin = Instant::now();
    let ns = |i: Instant| i.saturating_duration_since(origin).as_nanos() as i128;
    let period = o.cycle.as_nanos() as i128;
    let (mut deadline, mut host_to_dc): (Option<Instant>, Option<i128>) = (None, None);
    while t.cycles < o.cycles {
        let now = Instant::now();
        t.cycles += 1;
        let jittered = o.jitter_every != 0 && t.cycles % o.jitter_every == 0;
        if jittered {
            std::thread::sleep(o.jitter);
        }
        let r = group
            .tx_rx_dc(maindevice)
            .await
            .map_err(e("a cycle in OP"))?;
        let dc = i128::from(r.extra.dc_system_time);
        if let (Some(d), Some(off)) = (deadline, host_to_dc) {
            let sync0 = ((ns(d) + off).div_euclid(period) + 1) * period;
            t.past_sync0 += u64::from(dc > sync0);
        }
        if r.working_counter != expected {
            t.wkc_errors += 1;
            t.first_bad.get_or_insert((t.cycles, r.working_counter));
        } else if let Some(d) = deadline
            && !jittered
            && now.saturating_duration_since(d) < Duration::from_micros(200)
        {
            host_to_dc = Some(dc - ns(d));
        }
        let wake = now + r.extra.next_cycle_wait;
        async_io::Timer::at(wake).await;
        t.lateness
            .push(Instant::now().saturating_duration_since(wake));
        deadline = Some(wake);
    }
    group
        .into_safe_op(maindevice)
        .await
        .map_err(e("OP -> SAFE-OP"))?
        .into_pre_op(maindevice)
        .await
        .map_err(e("SAFE-OP -> PRE-OP"))?
        .into_init(maindevice)
        .await
        .map_err(e("PRE-OP -> INIT"))?;
    Ok((t, expected))
}

fn main() -> ExitCode {
    let o = match options() {
        Ok(o) => o,
        Err(m) => {
            eprintln!("ci_master: {m}");
            return ExitCode::from(2);
        }
    };
    let (tx, rx, pdu_loop) = STORAGE.try_split().expect("split once");
    let task = match tx_rx_task(&o.iface, tx, rx) {
        Ok(t) => t,
        Err(err) => {
            eprintln!("ci_master: FAILED: a raw socket on {}: {err}", o.iface);
            return ExitCode::FAILURE;
        }
    };
    std::thread::spawn(move || async_io::block_on(task));
    let timeouts = Timeouts {
        eeprom: Duration::from_millis(500),
        ..Timeouts::default()
    };
    let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());
    let (mut t, expected) = match futures_lite::future::block_on(run(&o, &maindevice)) {
        Ok(r) => r,
        Err(m) => {
            eprintln!("ci_master: FAILED: {m}");
            return ExitCode::FAILURE;
        }
    };
    t.lateness.sort();
    let q = |p: f64| t.lateness[((t.lateness.len() - 1) as f64 * p) as usize].as_micros();
    let jitter = if o.jitter_every != 0 {
        format!(
            ", a {} us sleep every {}",
            o.jitter.as_micros(),
            o.jitter_every
        )
    } else {
        String::new()
    };
    println!(
        "ci_master: {} cycles of {} us in OP on {}{jitter}, {} working counter errors (expected {expected}), loop lateness p99 {} us, max {} us, {} frames past their SYNC0 by the reference's time",
        t.cycles,
        o.cycle.as_micros(),
        o.iface,
        t.wkc_errors,
        q(0.99),
        q(1.0),
        t.past_sync0
    );
    if let Some((c, wkc)) = t.first_bad {
        eprintln!(
            "ci_master: FAILED: {} cycles with a wrong working counter (the first: cycle {c}, {wkc}, expected {expected})",
            t.wkc_errors
        );
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}
