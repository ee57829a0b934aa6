//! A comparison: every method in every run, in parallel across cores, collected in a fixed
//! order so that the result does not depend on scheduling.

use crate::run::{RunError, RunResult, run_one};
use crate::scenario::Scenario;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
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
}

/// Runs the comparison on `threads` threads; `progress` is incremented by simulated cycles.
pub fn compare(
    scenario: &Scenario,
    threads: usize,
    progress: &AtomicU64,
) -> Result<Comparison, RunError> {
    let t0 = Instant::now();
    let methods = scenario.methods.clone();
    let runs = scenario.runs as usize;
    let jobs: Vec<(usize, usize)> = (0..runs)
        .flat_map(|r| (0..methods.len()).map(move |m| (m, r)))
        .collect();
    let next = AtomicUsize::new(0);
    type Slot = Option<(Result<RunResult, RunError>, f64)>;
    let slots: Mutex<Vec<Slot>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    let threads = threads.clamp(1, jobs.len().max(1));
    std::thread::scope(|sc| {
        for _ in 0..threads {
            sc.spawn(|| {
                loop {
                    let j = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(m, r)) = jobs.get(j) else { break };
                    let t = Instant::now();
                    let res = run_one(scenario, &methods[m], r as u32, progress);
                    let dt = t.elapsed().as_secs_f64();
                    if let Ok(mut s) = slots.lock() {
                        s[j] = Some((res, dt));
                    }
                }
            });
        }
    });
    let slots = slots.into_inner().unwrap_or_default();
    let mut results: Vec<Vec<RunResult>> = (0..methods.len()).map(|_| Vec::new()).collect();
    let mut method_wall_s = vec![0.0; methods.len()];
    for (j, slot) in slots.into_iter().enumerate() {
        let (m, _r) = jobs[j];
        let (res, dt) = slot.expect("every job ran");
        results[m].push(res?);
        method_wall_s[m] += dt;
    }
    Ok(Comparison {
        scenario: scenario.clone(),
        results,
        method_wall_s,
        wall_s: t0.elapsed().as_secs_f64(),
        threads,
    })
}
