#!/usr/bin/env python3
"""Instructions per function of a Cortex-M7 run under QEMU (`make firmware-profile`).

QEMU does not model the DWT cycle counter and has no profiler here, so this counts from its own logs: run with
`-d in_asm,exec,nochain`, every translated block is printed once with its instructions (`in_asm`) and every
execution of a block once (`exec`, with `nochain` so that chained blocks are logged too). Instructions per
block times executions, summed by the innermost `m2smap_core` function of the block's first address
(`arm-none-eabi-addr2line -i`, so LTO-inlined code is named too), by every function of the inline chain
(inclusive of what was inlined into it), and by source line.

usage: profile.py QEMU_LOG ELF [TOP]
"""
import collections
import subprocess
import sys


def main():
    log, elf = sys.argv[1], sys.argv[2]
    top = int(sys.argv[3]) if len(sys.argv) > 3 else 40
    size, runs = {}, collections.Counter()
    block, n = None, 0
    with open(log, 'rb') as f:
        for line in f:
            c = line[:1]
            if c == b'T':  # "Trace 0: 0xhost [flags/pc/...] symbol"
                runs[int(line[line.index(b'[') + 1:].split(b'/', 2)[1], 16)] += 1
            elif c == b'I':  # "IN: symbol": a block's listing follows
                block, n = None, 0
            elif c == b'0':  # "0xaddr:  bytes  insn"
                n += 1
                if n == 1:
                    block = int(line.split(b':', 1)[0], 16)
                size[block] = n
    cost = {pc: k * size.get(pc, 1) for pc, k in runs.items()}
    total = sum(cost.values())
    pcs = sorted(cost, key=lambda p: -cost[p])[:6000]
    out = subprocess.run(['arm-none-eabi-addr2line', '-e', elf, '-a', '-f', '-i', '-C'] + [hex(p) for p in pcs],
                         capture_output=True, text=True, check=True).stdout.split('\n')
    chains, pc, chain, i = {}, None, [], 0
    while i < len(out):
        line = out[i]
        if line.startswith('0x') and ':' not in line:
            if pc is not None:
                chains[pc] = chain
            pc, chain, i = int(line, 16), [], i + 1
        elif line == '':
            i += 1
        else:
            chain.append((line, out[i + 1] if i + 1 < len(out) else ''))
            i += 2
    if pc is not None:
        chains[pc] = chain
    by_fn, by_line, inclusive = collections.Counter(), collections.Counter(), collections.Counter()
    for p in pcs:
        chain = chains.get(p, [])
        for fn in {fn.split('::{{closure}}')[0] for fn, _ in chain if 'm2smap' in fn}:
            inclusive[fn] += cost[p]
        core = [fn for fn, _ in chain if 'm2smap_core' in fn]
        name = (core[0] if core else chain[0][0] if chain else '?').split('::{{closure}}')[0]
        by_fn[name] += cost[p]
        if chain:
            by_line[(chain[0][1].rsplit('/', 1)[-1], name)] += cost[p]
    print(f'{total / 1e6:.2f} M instructions in the run')
    print('\nby innermost core function:')
    for name, k in by_fn.most_common(top):
        print(f'{k / 1e6:9.2f} M {100 * k / total:5.1f} %  {name}')
    print('\nby core function with what is inlined into it (inclusive; calls that are not inlined are not counted):')
    for name, k in inclusive.most_common(top):
        print(f'{k / 1e6:9.2f} M {100 * k / total:5.1f} %  {name}')
    print('\nby source line:')
    for (line, name), k in by_line.most_common(top):
        print(f'{k / 1e6:9.2f} M {100 * k / total:5.1f} %  {line}  {name}')


if __name__ == '__main__':
    main()
