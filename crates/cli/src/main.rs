//! `ecsync`: EtherCAT clock synchronization on a virtual segment and on real networks.

use clap::{Parser, Subcommand};
use std::io::Write as _;
use std::process::ExitCode;

mod bench;
mod bringup;
mod cli_docs;
mod compare;
mod heap;
mod host;
#[cfg(target_os = "linux")]
mod net;
mod progress;
mod source;
mod stop;
mod sweep;
mod tsn;
mod tune;

/// EtherCAT Distributed Clocks: bring-up, master synchronization methods, measurement.
#[derive(Debug, Parser)]
#[command(name = "ecsync", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Brings a virtual segment up (scan, SII, topology, delays, offsets, drift compensation,
    /// SYNC0, OP) and compares what the master measured with the segment's ground truth.
    Bringup(bringup::Args),
    /// Runs every master synchronization method on the same network, host and noise, and
    /// reports the letter's Table 1 beside ours, ground truth, plots and report.html.
    Compare(compare::Args),
    /// Runs a comparison at every point of a grid or list over any scenario or method
    /// parameter; results in an SQLite database that resumes, shards and merges.
    Sweep(sweep::Args),
    /// Tunes one method's gains on the network and host for the smallest safe SYNC0 shift,
    /// weighs them against the defaults run by run, and finds the shortest cycle it holds.
    Tune(tune::Args),
    /// Measures the simulator's speed.
    Bench(bench::Args),
    /// Serves the virtual segment on a network interface: any EtherCAT master on the other
    /// end (ecsync run, ethercrab, SOEM) sees its slaves.
    #[cfg(target_os = "linux")]
    Serve(net::ServeArgs),
    /// Talks to a running `serve --control PATH`: inject or clear a fault, read the counters
    /// and the judge, reset the segment, stop.
    #[cfg(target_os = "linux")]
    Ctl(net::CtlArgs),
    /// Runs the master on a network interface: scan, DC bring-up, SYNC0, and the cyclic loop
    /// with a synchronization method, in real time.
    #[cfg(target_os = "linux")]
    Run(net::RunArgs),
    /// A twin of this host: `host record` measures its periodic loop cycle by cycle, `host fit`
    /// fits the simulator's host model to the trace (`compare --host-trace` replays it).
    Host(host::Args),
    /// TSN between master and slaves: the paper's UPPAAL models explored (`tsn models`) and
    /// its three networks built from real parts and measured (`tsn run`).
    Tsn(tsn::Args),
    /// Prints this command reference as Markdown, for the book (`scripts/regen-docs.py`).
    #[command(hide = true)]
    HelpMarkdown,
}

/// A reader that went away (`ecsync compare 2>&1 | head -2`) ends the process quietly, as it
/// ends `cat` or `grep`, instead of a panic in `println!` ("failed printing to stdout: Broken
/// pipe", exit 101): SIGPIPE back to its default action. What these commands write to files is
/// written before their text is printed, or is no longer wanted once nobody reads. Not for
/// `sweep`, whose database records each invocation: a closed output stops it as Ctrl-C does
/// (the points done kept, its log row written; see `sweep::say`); nor for `serve`, `ctl` and
/// `run`, whose control socket's peer may go away without ending them.
#[cfg(target_os = "linux")]
fn end_quietly_on_a_closed_pipe() {
    // SAFETY: sets a signal's disposition to its default before any other thread runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The simulating commands run on a heap of huge pages (see `heap`); the real-time ones
    // (`serve`, `run`) fault no 2 MiB page in the middle of a cycle.
    if matches!(
        cli.command,
        Command::Bringup(_)
            | Command::Compare(_)
            | Command::Sweep(_)
            | Command::Tune(_)
            | Command::Bench(_)
            | Command::Tsn(_)
    ) {
        heap::use_huge_pages();
    }
    #[cfg(target_os = "linux")]
    if !matches!(
        cli.command,
        Command::Sweep(_) | Command::Serve(_) | Command::Ctl(_) | Command::Run(_)
    ) {
        end_quietly_on_a_closed_pipe();
    }
    let r = match cli.command {
        Command::Bringup(a) => bringup::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Sweep(a) => sweep::run(a),
        Command::Tune(a) => tune::run(a),
        Command::Bench(a) => bench::run(a),
        #[cfg(target_os = "linux")]
        Command::Serve(a) => net::serve(a),
        #[cfg(target_os = "linux")]
        Command::Ctl(a) => net::ctl(a),
        #[cfg(target_os = "linux")]
        Command::Run(a) => net::run(a),
        Command::Host(a) => host::run(a),
        Command::Tsn(a) => tsn::run(a),
        Command::HelpMarkdown => return cli_docs::print::<Cli>(),
    };
    match r {
        Ok(code) => code,
        Err(e) => {
            // Not `eprintln!`: a closed stderr (see `end_quietly_on_a_closed_pipe`) is no panic.
            let _ = writeln!(std::io::stderr(), "ecsync: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
