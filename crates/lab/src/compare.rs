//! A comparison: every method in every run, in parallel across cores, collected in a fixed
//! order so that the result does not depend on scheduling.

use crate::run::{
    BringupProgress, BringupWatch, BroughtUp, Run, RunError, RunResult, bring_up_watched,
};
use crate::scenario::Scenario;
use ecsync_sim::host::{HostNoise, SharedNoise};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// All runs of all methods.
#[derive(Debug)]
pub struct Comparison {
    /// The scenario.
    pub scenario: Scenario,
    /// `results[m][r]`: method m (in scenario order), run r.
    pub results: Vec<Vec<RunResult>>,
    /// Wall time of each method's runs added up, s (CPU time on the threads).
    pub method_wall_s: Vec<f64>,
    /// Wall time of the whole comparison, s.
    pub wall_s: f64,
    /// Threads used.
    pub threads: usize,
    /// Stopped before every cycle ran (the results hold the cycles done).
    pub interrupted: bool,
}

/// How a comparison runs beyond its scenario.
#[derive(Debug, Default)]
pub struct Options<'a> {
    /// Set to stop: every run ends after its current slice and keeps what it measured.
    pub stop: Option<&'a AtomicBool>,
    /// Write each run's per-cycle samples there (`<method>-run<r>.csv`).
    pub samples_dir: Option<PathBuf>,
    /// Where the runs' bring-ups say how far they got.
    pub bringup: Option<&'a BringupProgress>,
}

/// Cycles a worker runs of one run before it takes the next from the queue: long enough that
/// switching costs nothing (tens of milliseconds), short enough that the cores finish together.
const SLICE_CYCLES: u64 = 65_536;

/// Cycles between two looks at the stop flag. The noise blocks the methods of a run share
/// are drawn per step, so every method steps alike (the slice is a multiple of it).
const STOP_CHECK_CYCLES: u64 = 4_096;

/// Runs `f(i)` for every `i < n` on `threads` threads; results in index order.
fn parallel_map<T: Send>(n: usize, threads: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<T>>> = Mutex::new((0..n).map(|_| None).collect());
    std::thread::scope(|sc| {
        for _ in 0..threads.clamp(1, n.max(1)) {
            sc.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= n {
                        break;
                    }
                    let v = f(i);
                    if let Ok(mut s) = slots.lock() {
                        s[i] = Some(v);
                    }
                }
            });
        }
    });
    slots
        .into_inner()
        .unwrap_or_default()
        .into_iter()
        .map(|v| v.expect("every index ran"))
        .collect()
}

/// Runs the comparison on `threads` threads; `progress` is incremented by simulated cycles.
///
/// Each run's network is brought up once and every method continues from a copy of it. The
/// methods' cyclic phases are then shared out in slices of 65 536 cycles from one queue, so
/// that all cores stay busy until the end (with whole runs per thread, the last run of an odd
/// count would run alone). Neither the slicing nor the threads change any result.
pub fn compare(
    scenario: &Scenario,
    threads: usize,
    progress: &AtomicU64,
) -> Result<Comparison, RunError> {
    compare_with(scenario, threads, progress, &Options::default())
}

/// [`compare`] with options: an interruption flag, samples.
pub fn compare_with(
    scenario: &Scenario,
    threads: usize,
    progress: &AtomicU64,
    opts: &Options<'_>,
) -> Result<Comparison, RunError> {
    let t0 = Instant::now();
    // A cycle the network's frames do not fit in is refused before minutes of bring-up.
    crate::run::check_cycle_fits(scenario)?;
    let stopped = || opts.stop.is_some_and(|s| s.load(Ordering::Relaxed));
    let methods = scenario.entries();
    let runs = scenario.runs as usize;
    let threads = threads.max(1);
    let watch = BringupWatch {
        stop: opts.stop,
        progress: opts.bringup,
    };
    let ups = parallel_map(runs, threads, |r| {
        bring_up_watched(scenario, r as u32, &watch)
    });
    // Stopped while bringing up: nothing was measured, so nothing is reported (a run that
    // failed on its own says why instead).
    if stopped() && ups.iter().any(|u| matches!(u, Err(RunError::Interrupted))) {
        return Err(RunError::Interrupted);
    }
    let ups: Vec<BroughtUp> = ups.into_iter().collect::<Result<_, _>>()?;
    // Every method of a run meets the same noise: drawn once per run.
    let noises: Vec<Arc<SharedNoise>> = ups
        .iter()
        .map(|u| {
            Arc::new(SharedNoise::new(
                HostNoise::replaying(scenario.host, u.seed(), scenario.host_trace.clone()),
                methods.len() as u32,
            ))
        })
        .collect();

    let jobs: Vec<(usize, usize)> = (0..runs)
        .flat_map(|r| (0..methods.len()).map(move |m| (m, r)))
        .collect();
    let mut queue = VecDeque::with_capacity(jobs.len());
    for j in 0..jobs.len() {
        queue.push_back((j, None::<Run>));
    }
    let queue = Mutex::new(queue);
    type Slot = Option<Result<RunResult, RunError>>;
    let slots: Mutex<Vec<Slot>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    let cpu_s: Mutex<Vec<f64>> = Mutex::new(vec![0.0; jobs.len()]);
    let store = |j: usize, v: Result<RunResult, RunError>| {
        if let Ok(mut s) = slots.lock() {
            s[j] = Some(v);
        }
    };
    let workers = threads.clamp(1, jobs.len().max(1));
    std::thread::scope(|sc| {
        for _ in 0..workers {
            sc.spawn(|| {
                loop {
                    let task = queue.lock().ok().and_then(|mut q| q.pop_front());
                    let Some((j, state)) = task else { break };
                    let (m, r) = jobs[j];
                    let t = Instant::now();
                    let mut run = match state {
                        Some(run) => run,
                        None => {
                            let made =
                                Run::new(scenario, &ups[r], methods[m]).and_then(|mut run| {
                                    if let Some(dir) = &opts.samples_dir {
                                        run.write_samples(dir)?;
                                    }
                                    run.share_noise(Arc::clone(&noises[r]));
                                    Ok(run)
                                });
                            match made {
                                Ok(run) => run,
                                Err(e) => {
                                    store(j, Err(e));
                                    continue;
                                }
                            }
                        }
                    };
                    // The slice in steps, the stop flag looked at between them: Ctrl-C ends
                    // a run within a step (a third of a second on a 1000-drive line).
                    let mut left = SLICE_CYCLES;
                    while left > 0 && !stopped() {
                        let n = run.step(STOP_CHECK_CYCLES.min(left));
                        progress.fetch_add(n, Ordering::Relaxed);
                        if n == 0 {
                            break;
                        }
                        left = left.saturating_sub(n);
                    }
                    if let Ok(mut c) = cpu_s.lock() {
                        c[j] += t.elapsed().as_secs_f64();
                    }
                    if run.remaining() == 0 || stopped() {
                        store(j, run.finish());
                    } else if let Ok(mut q) = queue.lock() {
                        q.push_back((j, Some(run)));
                    }
                }
            });
        }
    });
    let slots = slots.into_inner().unwrap_or_default();
    let cpu_s = cpu_s.into_inner().unwrap_or_default();
    let mut results: Vec<Vec<RunResult>> = (0..methods.len()).map(|_| Vec::new()).collect();
    let mut method_wall_s = vec![0.0; methods.len()];
    for (j, slot) in slots.into_iter().enumerate() {
        let (m, _r) = jobs[j];
        let res = slot.expect("every job ran");
        results[m].push(res?);
        method_wall_s[m] += cpu_s[j];
    }
    let interrupted = results.iter().flatten().any(|r| !r.reached_end);
    Ok(Comparison {
        scenario: scenario.clone(),
        results,
        method_wall_s,
        wall_s: t0.elapsed().as_secs_f64(),
        threads: workers,
        interrupted,
    })
}
