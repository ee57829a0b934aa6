//! ethercrab 0.7 on its own Linux raw-socket TX/RX task in namespace B, as the tests that run
//! it against `ecsync serve` start it, and the way they take its drives to OP on SYNC0.

use super::*;
use ethercrab::error::Error;
use ethercrab::std::tx_rx_task;
use ethercrab::subdevice_group::{DcConfiguration, HasDc, Op};
use ethercrab::{DcSync, DefaultLock, MainDevice, PduRx, PduTx, SubDeviceGroup};
use std::sync::Arc;
use std::thread::JoinHandle;

/// ethercrab's TX/RX task on side B of a pair, in a thread of its own; stopped and joined on
/// drop.
pub(crate) struct EthercrabIo {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// How ethercrab's task ended before it was stopped, if it did: ethercrab ends it for good
    /// on any send error and on any reply it no longer waits for (one that came after its PDU
    /// timeout, as on a host loaded by other work), and every PDU after that times out.
    died: Arc<std::sync::Mutex<Option<String>>>,
}

impl EthercrabIo {
    /// Starts the task on `tx` and `rx` (a split `PduStorage`) in `pair`'s namespace B, and
    /// returns once its socket is open: the first PDU's timeout runs from its send.
    pub(crate) fn start(pair: &NetPair, tx: PduTx<'static>, rx: PduRx<'static>) -> EthercrabIo {
        let stop = Arc::new(AtomicBool::new(false));
        let (ns_b, if_b) = (pair.ns_b.clone(), pair.if_b.clone());
        let stop_io = stop.clone();
        let died = Arc::new(std::sync::Mutex::new(None));
        let died_io = died.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns_b).expect("enter namespace B");
            let task = tx_rx_task(&if_b, tx, rx).expect("ethercrab's raw socket");
            let _ = ready_tx.send(());
            let stopped = async {
                while !stop_io.load(Ordering::Relaxed) {
                    async_io::Timer::after(Duration::from_millis(10)).await;
                }
            };
            async_io::block_on(futures_lite::future::or(
                async {
                    if let Err(e) = task.await {
                        *died_io.lock().unwrap_or_else(|p| p.into_inner()) = Some(format!("{e:?}"));
                    }
                },
                stopped,
            ));
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("ethercrab's TX/RX task started");
        EthercrabIo {
            stop,
            thread: Some(thread),
            died,
        }
    }

    /// ethercrab's error if its TX/RX task has ended on one.
    pub(crate) fn died(&self) -> Option<String> {
        self.died.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

impl Drop for EthercrabIo {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A group fresh from ethercrab's scan taken to OP on SYNC0: every drive set to SYNC0, the
/// process data mapped, 2000 rounds of ethercrab's system time sync (its static drift
/// compensation), SYNC0 every `cycle`, half a cycle after the grid point, from 100 ms on, then
/// SAFE-OP and OP requested.
pub(crate) async fn into_op_on_sync0<const N: usize, const PDI: usize>(
    mut group: SubDeviceGroup<N, PDI>,
    maindevice: &MainDevice<'_>,
    cycle: Duration,
) -> Result<SubDeviceGroup<N, PDI, DefaultLock, Op, HasDc>, Error> {
    for mut sd in group.iter_mut(maindevice) {
        sd.set_dc_sync(DcSync::Sync0);
    }
    let group = group.into_pre_op_pdi(maindevice).await?;
    for _ in 0..2_000 {
        group.tx_rx_sync_system_time(maindevice).await?;
    }
    let sync0 = DcConfiguration {
        start_delay: Duration::from_millis(100),
        sync0_period: cycle,
        sync0_shift: cycle / 2,
    };
    group
        .configure_dc_sync(maindevice, sync0)
        .await?
        .into_safe_op(maindevice)
        .await?
        .request_into_op(maindevice)
        .await
}
