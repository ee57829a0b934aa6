#!/usr/bin/env python3
"""Checks that every test `cargo test --workspace` ignored ran and passed in the second run.

Usage: ignored-tests.py FIRST.log SECOND.log

FIRST.log is the output of `cargo test --workspace`, SECOND.log that of `cargo test --workspace
-- --ignored` (run with the tools and the shared data the ignored tests need). A test that
needs a tool or data a machine may lack is `#[ignore = "needs ..."]` (so a plain `cargo test`
lists it as ignored by name instead of passing while skipping); CI runs them all in the second
run. This fails (exit 1) unless the second run passed exactly the tests the first ignored and
ignored none, so nothing is left out in CI.

A test is named by its binary (the `Running ... (target/.../deps/name-hash)` line before it:
the same build in both runs) and its path in that binary.
"""

import re
import sys

RUNNING = re.compile(r"^\s*Running (\S+) \((\S+)\)")
DOCTESTS = re.compile(r"^\s*Doc-tests (\S+)")
TEST = re.compile(r"^test (.+?) \.\.\. (ok|FAILED|ignored(?:, (.*))?)$")
RESULT = re.compile(r"^test result: \w+\. (\d+) passed; (\d+) failed; (\d+) ignored;")


def parse(path):
    """The tests of a log as {(binary, name): (outcome, reason)} and the summed result counts."""
    tests, totals = {}, [0, 0, 0]
    binary = None
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            line = line.rstrip("\n")
            m = RUNNING.match(line)
            if m:
                binary = m.group(2)
                continue
            m = DOCTESTS.match(line)
            if m:
                binary = "doc-tests " + m.group(1)
                continue
            m = TEST.match(line)
            if m and binary is not None:
                outcome = m.group(2).split(",")[0]
                tests[(binary, m.group(1))] = (outcome, m.group(3) or "")
                continue
            m = RESULT.match(line)
            if m:
                for i in range(3):
                    totals[i] += int(m.group(i + 1))
    return tests, totals


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    first, first_totals = parse(sys.argv[1])
    second, second_totals = parse(sys.argv[2])
    ignored = {k: r for k, (o, r) in first.items() if o == "ignored"}
    problems = []
    if first_totals[2] != len(ignored):
        problems.append(
            f"the first run's results count {first_totals[2]} ignored, its test lines {len(ignored)}"
        )
    if not any(o == "ok" for o, _ in first.values()):
        problems.append("the first run passed no test: is it cargo test's output?")
    print(f"cargo test --workspace: {first_totals[0]} passed, {len(ignored)} ignored:")
    for (binary, name), reason in sorted(ignored.items(), key=lambda x: (x[1], x[0])):
        print(f"  {name} ({reason or 'no reason given'}; {binary.rsplit('/', 1)[-1]})")
    for key in sorted(ignored):
        outcome = second.get(key, ("not run", ""))[0]
        if outcome != "ok":
            problems.append(f"{key[1]} ({key[0]}): ignored in the first run, {outcome} in the second")
    extra = sorted(k for k, (o, _) in second.items() if k not in ignored)
    for key in extra:
        problems.append(f"{key[1]} ({key[0]}): run by --ignored but not ignored in the first run")
    still = [k for k, (o, _) in second.items() if o == "ignored"]
    if still or second_totals[2]:
        problems.append(f"{max(len(still), second_totals[2])} tests still ignored in the second run")
    print(
        f"cargo test --workspace -- --ignored: {second_totals[0]} passed, "
        f"{second_totals[1]} failed, {second_totals[2]} ignored"
    )
    if problems:
        print("\n".join(["ignored tests left out:"] + ["  " + p for p in problems]))
        sys.exit(1)
    print(f"every ignored test ran and passed: {len(ignored)} of {len(ignored)}, none left ignored")


if __name__ == "__main__":
    main()
