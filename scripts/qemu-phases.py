#!/usr/bin/env python3
"""Instructions per phase of the code under some functions, from a QEMU profile.

Usage: scripts/qemu-phases.py ELF COUNTS FUNCTIONS [DEPTH]

COUNTS is the per-address dump of `QEMU_PROFILE_DUMP=COUNTS scripts/qemu-profile.py ...`
("hex-address count" lines: instructions executed at each address). FUNCTIONS is a
comma-separated list of substrings of (mangled) symbol names; every address inside those
symbols is attributed to its chain of inlined frames (llvm-addr2line -f -i), outermost first,
cut to DEPTH frames (default 2), and the chains are printed by instructions executed. E.g. the
firmware's per-scan step (docs/performance.md, "The per-scan step on the Cortex-M4"):

  scripts/qemu-phases.py ELF COUNTS process_scan,insert_and_seed,RunWalk4mark,mark_cells,scan_box 2
"""

import collections
import re
import subprocess
import sys


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    elf, dump, fns = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
    depth = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    counts = {}
    with open(dump) as f:
        for line in f:
            a, c = line.split()
            counts[int(a, 16)] = int(c)
    nm = subprocess.run(["llvm-nm", "-n", "-S", elf], capture_output=True, text=True, check=True)
    symbols = []
    for line in nm.stdout.splitlines():
        p = line.split(None, 3)
        if len(p) == 4 and p[2].lower() == "t" and any(f in p[3] for f in fns):
            symbols.append((int(p[0], 16), int(p[1], 16)))
    phases = collections.Counter()
    for start, size in symbols:
        addrs = [a for a in counts if start <= a < start + size]
        if not addrs:
            continue
        out = subprocess.run(
            ["llvm-addr2line", "-a", "-f", "-i", "-C", "-e", elf],
            input="\n".join(hex(a) for a in addrs) + "\n",
            capture_output=True,
            text=True,
            check=True,
        ).stdout.splitlines()
        chains, cur, i = {}, None, 0
        while i < len(out):
            if out[i].startswith("0x"):
                cur = int(out[i], 16)
                chains[cur] = []
                i += 1
                continue
            if i + 1 >= len(out):
                break
            chains[cur].append(re.sub(r"::h[0-9a-f]{16}$", "", out[i]))
            i += 2  # function name, then its file:line
        for a in addrs:
            chain = chains.get(a, [])[::-1]
            key = " > ".join(f.split("::")[-1] for f in chain[:depth]) or "?"
            phases[key] += counts[a]
    total = sum(phases.values())
    print(f"{total} instructions under {','.join(fns)}")
    for key, c in phases.most_common(40):
        print(f"{c:10d} {100 * c / max(total, 1):5.1f}%  {key}")


if __name__ == "__main__":
    main()
