#!/usr/bin/env python3
"""Splits a profile of the simulator's substep into its terms (membrane, bending, global step, ...).

The substep is one function with every force law inlined into it, so a profiler's per-function
view says nothing; this reads the cost of every instruction address, asks `addr2line -i` for the
address's chain of inlined functions, and sums the costs by the term of the solver that chain runs
in. Build with line tables (they do not change the code):

    CARGO_PROFILE_RELEASE_DEBUG=line-tables-only cargo build --release -p rlpkg-sim --example substeps

then either (instruction counts and cache misses, exact and repeatable)

    valgrind --tool=callgrind --dump-instr=yes --dump-line=no --cache-sim=yes \\
        --callgrind-out-file=cg.out target/release/examples/substeps SCENE.toml 11x13 16 200
    tools/substep_profile.py target/release/examples/substeps --callgrind cg.out

or (wall-clock samples; valgrind hides AVX-512 from the program, perf does not)

    RAYON_NUM_THREADS=1 perf record -e cpu-clock -F 4000 -o perf.data \\
        target/release/examples/substeps SCENE.toml 11x13 32 600
    tools/substep_profile.py target/release/examples/substeps --perf perf.data
"""
import argparse
import collections
import re
import subprocess


def callgrind_costs(path, binary):
    """Self cost per instruction address of `binary` (events as callgrind names them)."""
    events, costs, obj_names = None, {}, {}
    obj, last, skip = '', 0, False
    for line in open(path):
        line = line.rstrip('\n')
        if not line:
            continue
        if line.startswith('events:'):
            events = line.split()[1:]
        elif line.startswith(('ob=', 'cob=')):
            m = re.match(r'c?ob=\((\d+)\)(?: (.*))?', line)
            if m.group(2):
                obj_names[m.group(1)] = m.group(2)
            if line.startswith('ob='):
                obj = obj_names.get(m.group(1), '')
        elif line.startswith('calls='):
            skip = True  # the next cost line is a call's inclusive cost
        elif line[0].isdigit() or line[0] in '+-*':
            tokens = line.split()
            pos = tokens[0]
            if pos.startswith('+'):
                last += int(pos[1:], 0)
            elif pos.startswith('-'):
                last -= int(pos[1:], 0)
            elif pos != '*':
                last = int(pos, 0)
            if skip:
                skip = False
                continue
            if binary.split('/')[-1] not in obj:
                continue
            values = [int(t) for t in tokens[1:]] + [0] * (len(events) - len(tokens) + 1)
            old = costs.get(last)
            costs[last] = values if old is None else [a + b for a, b in zip(old, values)]
    return events, costs


def perf_costs(path, binary):
    """Samples per instruction address of `binary` (symbol + offset, so no load address)."""
    symbols = {}
    for line in subprocess.run(['nm', binary], capture_output=True, text=True).stdout.splitlines():
        parts = line.split()
        if len(parts) == 3:
            symbols[parts[2]] = int(parts[0], 16)
    script = subprocess.run(['perf', 'script', '-i', path, '-F', 'ip,sym,symoff,dso', '--no-demangle'],
                            capture_output=True, text=True).stdout
    costs = collections.Counter()
    for line in script.splitlines():
        parts = line.split()
        if len(parts) >= 3 and '+0x' in parts[1] and binary.split('/')[-1] in line:
            name, offset = parts[1].rsplit('+0x', 1)
            if name in symbols:
                costs[symbols[name] + int(offset, 16)] += 1
    return ['samples'], {a: [c] for a, c in costs.items()}


def inline_chains(binary, addresses):
    """Function names of each address's inline chain, innermost first."""
    out = subprocess.run(['addr2line', '-i', '-f', '-C', '-a', '-e', binary],
                         input='\n'.join(hex(a) for a in addresses), capture_output=True,
                         text=True).stdout.splitlines()
    chains, current, i = {}, None, 0
    while i < len(out):
        if out[i].startswith('0x'):
            current = int(out[i], 16)
            chains[current] = []
            i += 1
        else:
            name = re.sub(r'<[^<>]*>', '', re.sub(r'<[^<>]*>', '', out[i])).split('::')[-1]
            chains[current].append((name, out[i + 1] if i + 1 < len(out) else ''))
            i += 2
    return chains


# (term, functions any of which in the chain puts an address in the term), first match wins.
TERMS = [
    ('cups: attachment springs, seal model', ['update_seals', 'index_springs', 'spring_vertex']),
    ('global step: Cholesky factor', ['factor', 'factor_entries']),
    ('global step: banded solves (with the permutation)', ['solve@banded.rs', 'solve@global_descent/mod.rs']),
    ('global step: assembling P', ['prepare']),
    ('membrane, residual (per triangle, forces only)', ['membrane_forces', 'membrane_forces_across_elements']),
    ('contact (ground, disc, the disc Newton step)', ['contact_vertex', 'disc_contact', 'cylinder_distance',
                                                     'add_point', 'add_disc_contacts_across_elements']),
    ('bending (per edge, at each sweep start)', ['bending_at_sweep_start', 'bending_across_elements']),
    ('membrane, sweep (per vertex and triangle, with 3x3 stiffness)', ['add_membrane', 'add_membrane_across_elements']),
    ('inertia and the lagged bending per vertex', ['vertex_system', 'force_without_membrane']),
    ('the 3x3 Newton solves per vertex', ['solve@math.rs']),
    ('the substep\'s own loops (predictions, updates, velocities, disc)', ['substep_with', 'substep']),
    ('health checks', ['check_health']),
]


def term_of(chain):
    for term, functions in TERMS:
        for f in functions:
            name, _, file = f.partition('@')
            if any(n == name and file in loc for n, loc in chain):
                return term
    return 'other (setup, helpers left out of line)'


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('binary')
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--callgrind', metavar='FILE')
    source.add_argument('--perf', metavar='FILE')
    args = parser.parse_args()
    events, costs = (callgrind_costs(args.callgrind, args.binary) if args.callgrind
                     else perf_costs(args.perf, args.binary))
    chains = inline_chains(args.binary, sorted(costs))
    totals = collections.OrderedDict((t, [0] * len(events)) for t, _ in TERMS)
    for address, values in costs.items():
        row = totals.setdefault(term_of(chains.get(address, [])), [0] * len(events))
        for j, v in enumerate(values):
            row[j] += v
    shown = [j for j, e in enumerate(events) if e in ('Ir', 'D1mr', 'D1mw', 'DLmr', 'samples')]
    grand = [sum(r[j] for r in totals.values()) for j in range(len(events))]
    print('%-64s' % 'term (% of the whole run)', ' '.join('%8s' % events[j] for j in shown))
    for term, row in totals.items():
        print('%-64s' % term, ' '.join('%7.1f%%' % (100.0 * row[j] / max(grand[j], 1)) for j in shown))
    print('%-64s' % 'total', ' '.join('%8d' % grand[j] for j in shown))


if __name__ == '__main__':
    main()
