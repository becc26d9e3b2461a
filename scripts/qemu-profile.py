#!/usr/bin/env python3
"""Instructions per source line and per function of a firmware run in QEMU.

Usage: scripts/qemu-profile.py ELF [TOP] -- COMMAND...

Runs COMMAND (e.g. `./target/release/host-sim firmware --seed 1 --max-scans 12`) with
FIRMWARE_QEMU_EXTRA set so that QEMU logs every translated block (`in_asm`) and every execution
of one (`exec,nochain`) into a FIFO, counts executions per block as they stream by, weights each
block's instructions by them and maps the addresses to (inlined) functions and source lines with
llvm-addr2line. Prints the TOP (default 40) functions and lines by instructions executed.
The log is never written to disk (it grows by ~50 bytes per executed block);
QEMU_PROFILE_DUMP=FILE keeps the per-address counts ("hex-address count" lines).
"""

import collections
import os
import re
import subprocess
import sys
import tempfile
import threading


def main():
    if "--" not in sys.argv:
        sys.exit(__doc__)
    sep = sys.argv.index("--")
    args, command = sys.argv[1:sep], sys.argv[sep + 1:]
    if not args or not command:
        sys.exit(__doc__)
    elf = args[0]
    top = int(args[1]) if len(args) > 1 else 40
    tmp = tempfile.mkdtemp()
    fifo = os.path.join(tmp, "qemu.log")
    os.mkfifo(fifo)
    env = dict(os.environ, FIRMWARE_QEMU_EXTRA=f"-d in_asm,exec,nochain -D {fifo}")
    blocks = {}  # block start -> instruction addresses
    execs = collections.Counter()
    trace = re.compile(r"^Trace \d+: \S+ \[[0-9a-f]+/([0-9a-f]+)/")
    insn = re.compile(r"^0x([0-9a-f]+):")

    def consume():
        current = None
        with open(fifo, "r", errors="replace") as f:
            for line in f:
                if line.startswith("Trace"):
                    m = trace.match(line)
                    if m:
                        execs[int(m.group(1), 16)] += 1
                    continue
                if line.startswith("IN:"):
                    current = []
                    continue
                if current is not None:
                    m = insn.match(line)
                    if m:
                        current.append(int(m.group(1), 16))
                    elif current:
                        blocks[current[0]] = current
                        current = None

    reader = threading.Thread(target=consume)
    reader.start()
    status = subprocess.call(command, env=env)
    reader.join()
    os.unlink(fifo)
    os.rmdir(tmp)

    per_addr = collections.Counter()
    for start, n in execs.items():
        for a in blocks.get(start, [start]):
            per_addr[a] += n
    total = sum(per_addr.values())
    dump = os.environ.get("QEMU_PROFILE_DUMP")
    if dump:
        with open(dump, "w") as f:
            for a in sorted(per_addr):
                f.write(f"{a:x} {per_addr[a]}\n")
    addrs = sorted(per_addr)
    out = subprocess.run(
        ["llvm-addr2line", "-f", "-i", "-C", "-e", elf] + [hex(a) for a in addrs],
        capture_output=True, text=True, check=True).stdout.splitlines()
    # With -i each address gives pairs (function, file:line), innermost first; addr2line
    # separates addresses only by order, so ask again per address when the counts disagree.
    funcs, lines = collections.Counter(), collections.Counter()
    if len(out) == 2 * len(addrs):
        for a, i in zip(addrs, range(0, len(out), 2)):
            funcs[out[i]] += per_addr[a]
            lines[f"{out[i + 1]}  ({out[i][:60]})"] += per_addr[a]
    else:
        for a in addrs:
            o = subprocess.run(["llvm-addr2line", "-f", "-i", "-C", "-e", elf, hex(a)],
                               capture_output=True, text=True).stdout.splitlines()
            if len(o) >= 2:
                funcs[o[0]] += per_addr[a]
                lines[f"{o[1]}  ({o[0][:60]})"] += per_addr[a]
    print(f"{total} instructions executed (command exit {status})")
    print("\n== innermost function ==")
    for name, n in funcs.most_common(top):
        print(f"{n:>12} {100 * n / max(total, 1):5.1f}%  {name[:110]}")
    print("\n== source line ==")
    for name, n in lines.most_common(top):
        print(f"{n:>12} {100 * n / max(total, 1):5.1f}%  {name[:150]}")


if __name__ == "__main__":
    main()
