//! What `ecsync serve` does while the segment serves: the status line, warnings, faults as
//! they happen, and the control socket's requests (taken between two frames).

use super::control::{self, ControlServer, Request};
use ecsync_lab::judge::{Judge, JudgeOptions, JudgeOut, Lost};
use ecsync_net::serve::{FrameLoss, ServeHooks, Served};
use ecsync_sim::Segment;
use ecsync_sim::fault::{FaultEvent, FaultPlayer};
use serde_json::{Value, json};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Instant;

/// How often the status line is printed where it cannot be rewritten in place, s.
const STATUS_LINE_EVERY_S: f64 = 10.0;

/// `serve`'s hooks.
pub(super) struct CliHooks {
    pub(super) quiet: bool,
    /// The status line is rewritten in place every second (a terminal of serve's own), else
    /// printed whole every [`STATUS_LINE_EVERY_S`].
    pub(super) live: bool,
    pub(super) t0: Instant,
    pub(super) last_print: Instant,
    pub(super) control: Option<ControlServer>,
    /// Whether a status line is on the terminal (a message first ends it).
    pub(super) line_open: bool,
    /// The judge of the master on the other end.
    pub(super) judge: Judge,
    pub(super) judge_options: JudgeOptions,
    /// `--out`: where summary.json and report.html go, and how often, s.
    pub(super) out: Option<(PathBuf, f64)>,
    pub(super) last_write: Instant,
}

/// Writes the judge's summary.json and report.html into `dir` (each atomically).
pub(super) fn write_judge(dir: &std::path::Path, out: &JudgeOut) -> std::io::Result<()> {
    let json = serde_json::to_string_pretty(out).map_err(std::io::Error::other)?;
    ecsync_lab::output::write_atomic(&dir.join("summary.json"), (json + "\n").as_bytes())?;
    let html = ecsync_lab::judge::report_html(out);
    ecsync_lab::output::write_atomic(&dir.join("report.html"), html.as_bytes())
}

impl CliHooks {
    fn say(&mut self, text: &str) {
        if self.line_open {
            eprintln!();
            self.line_open = false;
        }
        eprintln!("{text}");
    }

    fn answer(&mut self, req: &Value, served: &mut Served<'_>) -> Value {
        let cmd = req.get("cmd").and_then(Value::as_str).unwrap_or("");
        match cmd {
            "status" => status(served),
            "judge" => {
                json!({"ok": true, "judge": self.judge.summary(served.segment)})
            }
            "inject" => inject(req, served),
            "clear" => {
                let which = req.get("fault").and_then(Value::as_u64);
                let which = which.map(|n| n as usize);
                if let Some(n) = which
                    && n >= served.faults.schedule().faults.len()
                {
                    return control::error(&format!(
                        "clear: there is no fault {n} (0 to {})",
                        served.faults.schedule().faults.len().saturating_sub(1)
                    ));
                }
                served.faults.clear(served.segment, which, served.now_ps);
                json!({"ok": true})
            }
            "reset" => {
                // Every slave off and on again at once: registers, AL Init, new power-up
                // times, as a segment switched on. The faults' windows stay as they are.
                for p in 0..served.segment.len() {
                    served.segment.power_off(p, served.now_ps);
                }
                for p in 0..served.segment.len() {
                    served.segment.power_on(p, served.now_ps);
                }
                self.say("ecsync serve: reset to power-on (control socket)");
                self.judge = Judge::new(served.segment, self.judge_options.clone());
                json!({"ok": true})
            }
            "epoch" => {
                // The schedule's at_s count from now, whatever its `epoch` says.
                served.faults.set_epoch(served.now_ps);
                json!({"ok": true, "epoch_s": served.now_ps as f64 / 1e12})
            }
            "stop" => {
                super::STOP.store(true, Ordering::Relaxed);
                json!({"ok": true})
            }
            "" => control::error(&format!(
                "a request needs \"cmd\": one of {}",
                control::COMMANDS
            )),
            other => control::error(&format!(
                "unknown cmd {other:?}: one of {}",
                control::COMMANDS
            )),
        }
    }
}

fn status(served: &Served<'_>) -> Value {
    let seg: &Segment = served.segment;
    let slaves: Vec<Value> = (0..seg.len())
        .map(|p| {
            // 0x0300-0x0313 as the master would read them: per port the invalid frame and RX
            // error counters, the forwarded RX errors, the processing unit's and PDI's errors,
            // the lost links.
            let c = seg.esc(p).error_counters();
            json!({
                "position": p + 1,
                "powered": !seg.is_powered_off(p),
                "al_state": seg.esc(p).al_state().to_string(),
                "invalid_frames": [c[0], c[2], c[4], c[6]],
                "rx_errors": [c[1], c[3], c[5], c[7]],
                "forwarded_rx_errors": &c[8..12],
                "processing_unit_errors": c[12],
                "pdi_errors": c[13],
                "lost_links": &c[16..20],
            })
        })
        .collect();
    json!({
        "ok": true,
        "t_s": served.now_ps as f64 / 1e12,
        "epoch_s": served.faults.origin_ps().map(|o| o as f64 / 1e12),
        "stats": served.stats,
        "master_link_up": seg.master_link_up(),
        "slaves": slaves,
        "faults": served.faults.events(),
    })
}

/// `inject`: one fault of the schedule's kinds, now (`in_s` from now, or `at_s` after the
/// epoch).
fn inject(req: &Value, served: &mut Served<'_>) -> Value {
    let Some(fault) = req.get("fault") else {
        return control::error(
            "inject needs \"fault\": {\"kind\": ..., and the keys of a [[fault]] entry}",
        );
    };
    let table = match serde_json::from_value::<toml::Table>(fault.clone()) {
        Ok(t) => t,
        Err(e) => return control::error(&format!("fault: {e}")),
    };
    let fault = match ecsync_sim::fault::parse_fault_entry(&table) {
        Ok(f) => f,
        Err(e) => return control::error(&format!("fault: {e}")),
    };
    if fault.kind.is_host_fault() {
        return control::error(&format!(
            "fault: \"{}\" is a fault of the master's host, which serve cannot play; fix: play it in virtual time with `ecsync compare --faults`, or inject a fault of the segment here (any kind but host_stall and clock_step, e.g. `inject power_cycle slave=2 for_s=0.5`)",
            fault.kind.name()
        ));
    }
    // A slave or port the served network lacks, as a file's entry is refused.
    let one = ecsync_sim::fault::FaultSchedule {
        faults: vec![fault],
        ..Default::default()
    };
    if let Err(e) = one.check_segment(served.segment, "the served network") {
        let key = e.field.strip_prefix("fault[0].").unwrap_or(&e.field);
        return control::error(&format!("fault: {key}: {}; fix: {}", e.message, e.fix));
    }
    let secs = |k: &str| req.get(k).and_then(Value::as_f64);
    let at_ps = match (secs("in_s"), secs("at_s")) {
        (Some(_), Some(_)) => return control::error("give in_s or at_s, not both"),
        (Some(s), None) if s >= 0.0 && s.is_finite() => served.now_ps + (s * 1e12) as u64,
        (None, Some(s)) if s >= 0.0 && s.is_finite() => match served.faults.origin_ps() {
            Some(o) => o + (s * 1e12) as u64,
            None => {
                return control::error(
                    "at_s counts from the epoch, which has not come yet (no frame with process data): use in_s",
                );
            }
        },
        (None, None) => served.now_ps,
        _ => return control::error("in_s and at_s are seconds >= 0"),
    };
    let n = served.faults.inject(fault, at_ps);
    json!({"ok": true, "fault": n, "at_t_s": at_ps as f64 / 1e12})
}

impl ServeHooks for CliHooks {
    fn frame(&mut self, segment: &Segment, frame: &[u8], t_ps: u64, lost: FrameLoss) {
        self.judge.frame(segment, frame, t_ps, lost_of(lost));
    }

    fn frame_on_ring(&mut self, segment: &Segment, frame: &[u8], t_ps: u64, lost: FrameLoss) {
        self.judge
            .frame_on_ring(segment, frame, t_ps, lost_of(lost));
    }

    fn reply_sent(&mut self, late_ns: u64) {
        self.judge.reply_late(late_ns);
    }

    fn fault_event(&mut self, e: &FaultEvent) {
        self.judge.fault_event(e);
        if !self.quiet {
            self.say(&format!(
                "  {:>10.3} s  {} {}: {}",
                e.since_epoch_ns as f64 / 1e9,
                e.kind,
                e.edge,
                e.detail
            ));
        }
    }

    fn warning(&mut self, text: &str) {
        self.say(&format!("ecsync serve: warning: {text}"));
    }

    fn poll(&mut self, served: &mut Served<'_>) {
        while let Some(req) = self
            .control
            .as_ref()
            .and_then(|c| c.requests.try_recv().ok())
        {
            let Request { body, answer } = req;
            let a = self.answer(&body, served);
            let _ = answer.send(a);
        }
        if let Some((dir, every_s)) = &self.out
            && self.last_write.elapsed().as_secs_f64() >= *every_s
        {
            self.last_write = Instant::now();
            // The summary here (it reads the segment); the report is drawn and written on a
            // thread of its own, off the serving loop.
            let out = self.judge.summary(served.segment);
            let dir = dir.clone();
            std::thread::spawn(move || {
                if let Err(e) = write_judge(&dir, &out) {
                    eprintln!(
                        "ecsync serve: warning: writing the judge's results into {}: {e}",
                        dir.display()
                    );
                }
            });
        }
        let every_s = if self.live { 1.0 } else { STATUS_LINE_EVERY_S };
        if !self.quiet && self.last_print.elapsed().as_secs_f64() >= every_s {
            self.last_print = Instant::now();
            let s = served.stats;
            let line = format!(
                "{:>8.1} s: {} frames answered, {} not returned",
                self.t0.elapsed().as_secs_f64(),
                s.answered,
                s.not_returned
            );
            if self.live {
                eprint!("\r{line}");
                self.line_open = true;
            } else {
                eprintln!("ecsync serve: {}", line.trim_start());
            }
        }
    }

    fn poll_interval_ns(&self) -> u64 {
        if self.control.is_some() {
            control::POLL_INTERVAL_NS
        } else {
            100_000_000
        }
    }
}

/// A player for serve: the schedule's, or an empty one that control requests fill.
pub(super) fn player(schedule: Option<ecsync_sim::fault::FaultSchedule>) -> FaultPlayer {
    FaultPlayer::new(schedule.unwrap_or_default(), 0)
}

/// The judge's word for what became of a frame.
fn lost_of(lost: FrameLoss) -> Lost {
    match lost {
        FrameLoss::No => Lost::No,
        FrameLoss::Out => Lost::Out,
        FrameLoss::Back => Lost::Back,
    }
}
