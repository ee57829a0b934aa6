#!/usr/bin/env python3
"""Regenerates every printed output in README.md and the book from the current release binary.

An output printed in the docs is written by this script only, between markers:

    <!-- generated: NAME -->
    ...the command and what it printed...
    <!-- /generated -->

NAME is one of GENERATORS below (a marker naming another is an error). The command reference
(docs/src/reference/commands.md) is the binary's `ecsync help-markdown` as a whole file, and
docs/report.png is a headless Chromium screenshot of the default comparison's report.html, with
the SHA-256 of the report it was taken from in docs/report.png.source (a browser's PNG bytes
are not reproducible, the report's are).

    python3 scripts/regen-docs.py            # rewrite the blocks, the reference, the screenshot
    python3 scripts/regen-docs.py --check    # exit 1 with a diff where a committed output differs

Every command here is deterministic per seed except its wall-clock time, which is normalised
out (NORMALISE) so that --check compares like with like on any machine.
"""

import argparse
import difflib
import functools
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BLOCK = re.compile(
    r"(<!-- generated: (?P<name>[a-z0-9-]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S
)
COMMANDS_MD = ROOT / "docs/src/reference/commands.md"
SCREENSHOT = ROOT / "docs/report.png"
SCREENSHOT_SOURCE = ROOT / "docs/report.png.source"
# The report's width as a reader's browser shows it; the height takes the verdict, the table
# and the first plots (the screenshot is a glimpse, the report itself is the document).
WINDOW = "1480,1900"

# Wall-clock times (the only figures that differ between two runs of the same command) and the
# temporary output folders, which the reader's run writes to the default folder instead.
NORMALISE = [
    (re.compile(r" in [0-9.]+ s on [0-9]+ threads?\."), "."),
    (re.compile(r"Wall time [0-9.]+ s on [0-9]+ threads?\."), "Wall time (not shown)."),
    # `tsn models`: the exploration's time per model and in all.
    (re.compile(r" states in +[0-9.]+ s;"), " states;"),
    (re.compile(r" \([0-9.]+ s\)$", re.M), ""),
]


class Runner:
    """Runs the binary once per distinct command line and keeps what it printed."""

    def __init__(self, binary, tmp, from_dir):
        self.binary = binary
        self.tmp = Path(tmp)
        self.from_dir = Path(from_dir) if from_dir else None

    @functools.lru_cache(maxsize=None)
    def run(self, args, out_default=None):
        """stdout of `ecsync ARGS` (a tuple), with `--out` to a fresh folder when the command
        writes one (shown as OUT_DEFAULT, the folder the reader's run writes to)."""
        argv = [str(self.binary), *args]
        out = None
        if out_default:
            out = self.tmp / f"out{len(os.listdir(self.tmp))}"
            argv += ["--out", str(out)]
        p = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
        if p.returncode != 0:
            sys.exit(f"regen-docs: `ecsync {' '.join(args)}` failed ({p.returncode}):\n{p.stderr}")
        text = p.stdout
        if out:
            text = text.replace(str(out), out_default)
        return normalise(text), out

    def default_compare(self):
        """The default comparison's stdout and output folder (reused from --from DIR when it
        holds both: `ecsync compare --out DIR > DIR/stdout.txt`)."""
        if self.from_dir and (self.from_dir / "stdout.txt").exists():
            text = (self.from_dir / "stdout.txt").read_text()
            return normalise(text.replace(str(self.from_dir), "out/compare")), self.from_dir
        return self.run(("compare", "--quiet"), "out/compare")


def normalise(text):
    for pattern, repl in NORMALISE:
        text = pattern.sub(repl, text)
    return text.rstrip("\n") + "\n"


def shown(command, output):
    """A block's body: the command as a reader types it, then what it printed."""
    return f"```text\n$ {command}\n{output}```\n"


def until(text, marker):
    """The lines of `text` before the first line starting with `marker`, trailing blank lines
    dropped."""
    lines = text.splitlines()
    end = next((i for i, l in enumerate(lines) if l.startswith(marker)), len(lines))
    return "\n".join(lines[:end]).rstrip("\n") + "\n"


def plain(command, out_default=None):
    """A generator that shows one command's whole output."""

    def gen(r):
        args = tuple(command.split()[1:])
        return shown(command, r.run(args, out_default)[0])

    return gen


def compare_default(r):
    return shown("ecsync compare", r.default_compare()[0])


def compare_default_verdict(r):
    text = until(r.default_compare()[0], "Ground truth")
    return shown("ecsync compare", text + "...\n")


SWEEP_EXAMPLE = (
    "ecsync sweep --preset twelve-drives --grid run.target_phase_us=0,20,40 "
    "--grid methods.median-fit.gain=0.005,0.01,0.02 --methods median-fit,soem-pi --runs 2 "
    "--cycles 100000 --quiet"
)


def sweep_example(r):
    """The sweep's answer (stdout), its database in a fresh file (sweep.db for the reader)."""
    db = r.tmp / f"sweep{len(os.listdir(r.tmp))}.db"
    text, _ = r.run((*SWEEP_EXAMPLE.split()[1:], "--db", str(db)))
    return shown(SWEEP_EXAMPLE, text)


MORE_METHODS = (
    "ecsync compare --methods median-fit,bus-shift,kickcat-pll,igh-app-time,linuxcnc-pll,des,kalman "
    "--runs 1 --cycles 200000 --quiet"
)


def compare_more_methods(r):
    """The verdict and the ground truth's table of issue 34's methods beside two of the letter's."""
    text, _ = r.run(tuple(MORE_METHODS.split()[1:]), "out/compare")
    return shown(MORE_METHODS, until(text, "Init-drift") + "...\n")


OVERSAMPLING = "ecsync compare --preset oversampling --runs 1 --cycles 20000 --quiet"


def compare_oversampling(r):
    """The oversampling preset's verdict and its per-slave table (terminal and drive)."""
    text, _ = r.run(tuple(OVERSAMPLING.split()[1:]), "out/compare")
    lines = text.splitlines()
    head = until(text, "Ground truth")
    start = next(i for i, l in enumerate(lines) if l.startswith("Per slave"))
    table = until("\n".join(lines[start:]) + "\n", "Table 1")
    return shown(OVERSAMPLING, head + "...\n" + table)


GENERATORS = {
    "compare-oversampling": compare_oversampling,
    "compare-default": compare_default,
    "compare-more-methods": compare_more_methods,
    "compare-default-verdict": compare_default_verdict,
    "compare-twelve-drives": plain(
        "ecsync compare --preset twelve-drives --runs 1 --cycles 200000 --quiet", "out/compare"
    ),
    "compare-send-modes": plain(
        "ecsync compare --methods median-fit --send plain,spin,txtime,hwstamp --runs 1 "
        "--cycles 100000 --quiet",
        "out/compare",
    ),
    "compare-faults-demo": plain(
        "ecsync compare --faults faults-demo --warmup-s 10 --cycles 70000 --runs 1 --quiet",
        "out/compare",
    ),
    "compare-full-scenario": plain(
        "ecsync compare --config docs/examples/full-scenario.toml "
        "--faults docs/examples/all-faults.toml --quiet",
        "out/compare",
    ),
    "bringup-paper-2024": plain("ecsync bringup --preset paper-2024"),
    "bringup-junction-coupler": plain("ecsync bringup --config docs/examples/junction-coupler.toml"),
    "sweep-twelve-drives": sweep_example,
    "tune-median-fit": plain(
        "ecsync tune --method median-fit --runs 3 --cycles 100000 --warmup-s 12 --quiet "
        "--send-modes --shortest-cycle --cycle-step-us 50"
    ),
    "tsn-models": plain("ecsync tsn models"),
    "tsn-run": plain("ecsync tsn run", "out/tsn"),
}


def doc_files():
    return [ROOT / "README.md", *sorted((ROOT / "docs/src").rglob("*.md"))]


def report_hash(report_html):
    return hashlib.sha256(normalise(report_html.read_text()).encode()).hexdigest()


def screenshot(report_dir):
    """docs/report.png from REPORT_DIR/report.html, and the source's hash beside it."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if not browser:
        sys.exit("regen-docs: chromium is needed for the screenshot (apt-get install chromium)")
    shot = Path(tempfile.mkdtemp()) / "report.png"
    # --no-sandbox: CI runs as root, where Chromium's sandbox refuses to start.
    subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         f"--screenshot={shot}", f"--window-size={WINDOW}",
         (report_dir / "report.html").resolve().as_uri()],
        check=True, capture_output=True,
    )
    shutil.copyfile(shot, SCREENSHOT)
    SCREENSHOT_SOURCE.write_text(source_record(report_dir))


def source_record(report_dir):
    return (
        f"sha256 {report_hash(report_dir / 'report.html')}  report.html of `ecsync compare`"
        " (wall time normalised), from which docs/report.png was taken by"
        " scripts/regen-docs.py\n"
    )


def differs(what, old, new):
    diff = difflib.unified_diff(
        old.splitlines(True), new.splitlines(True), f"{what} (committed)", f"{what} (now)"
    )
    sys.stdout.writelines(diff)
    return True


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 where stale")
    ap.add_argument("--from", dest="from_dir", metavar="DIR",
                    help="reuse the default comparison in DIR (its --out, and its stdout as stdout.txt)")
    ap.add_argument("--bin", help="the ecsync binary (default: build the release binary)")
    ap.add_argument("--no-screenshot", action="store_true",
                    help="leave docs/report.png and its source record alone")
    a = ap.parse_args()

    binary = Path(a.bin) if a.bin else build()
    stale = []
    with tempfile.TemporaryDirectory() as tmp:
        r = Runner(binary, tmp, a.from_dir)
        for path in doc_files():
            text = path.read_text()
            new = update_blocks(path, text, r)
            if new != text:
                stale.append(path.relative_to(ROOT))
                if a.check:
                    differs(path.relative_to(ROOT), text, new)
                else:
                    path.write_text(new)
        reference = subprocess.run([str(binary), "help-markdown"], capture_output=True,
                                   text=True, check=True).stdout
        reference = ("<!-- generated by scripts/regen-docs.py from `ecsync help-markdown`:"
                     " do not edit -->\n\n" + reference.rstrip("\n") + "\n")
        old = COMMANDS_MD.read_text() if COMMANDS_MD.exists() else ""
        if old != reference:
            stale.append(COMMANDS_MD.relative_to(ROOT))
            if a.check:
                differs(COMMANDS_MD.relative_to(ROOT), old, reference)
            else:
                COMMANDS_MD.write_text(reference)
        if not a.no_screenshot:
            report_dir = r.default_compare()[1]
            record = source_record(report_dir)
            old = SCREENSHOT_SOURCE.read_text() if SCREENSHOT_SOURCE.exists() else ""
            if old != record or not SCREENSHOT.exists():
                stale.append(SCREENSHOT.relative_to(ROOT))
                if a.check:
                    print(f"docs/report.png was taken from another report.html:\n"
                          f"  committed: {old.strip()}\n  now:       {record.strip()}")
                else:
                    screenshot(report_dir)
    if stale and a.check:
        print(f"\nregen-docs: stale: {', '.join(map(str, stale))}."
              " Run `python3 scripts/regen-docs.py` and commit what it rewrites.")
        return 1
    print(f"regen-docs: {'rewrote ' + ', '.join(map(str, stale)) if stale else 'all current'}")
    return 0


def update_blocks(path, text, r):
    def repl(m):
        name = m.group("name")
        if name not in GENERATORS:
            sys.exit(f"regen-docs: {path.relative_to(ROOT)} names no generator {name!r}"
                     f" (known: {', '.join(GENERATORS)})")
        return m.group(1) + GENERATORS[name](r) + m.group(4)

    return BLOCK.sub(repl, text)


def build():
    subprocess.run(["cargo", "build", "--release", "-q", "-p", "ecsync"], cwd=ROOT, check=True)
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    return (target if target.is_absolute() else ROOT / target) / "release" / "ecsync"


if __name__ == "__main__":
    sys.exit(main())
