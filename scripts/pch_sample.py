#!/usr/bin/env python3
"""What a precompiled header could save on one file, in CPU seconds.

Usage (from the repository root, TREE configured): scripts/pch_sample.py TREE FILE...

For each FILE (a path relative to the root), a header of every <...> include
of the file and of the project headers it includes, transitively (the
standard library, Eigen, Boost.Asio and Beast, PCL, OpenCV, gtest, ...): the
most a PCH of third-party headers could hold for that file. Then, with the
file's exact command from TREE/compile_commands.json, without ccache: the
file compiled plain, the header built as a PCH (-fpch-instantiate-templates,
as CMake does for clang), the file compiled with -include-pch, and the header
alone compiled as a source. Prints user + sys CPU seconds of each; clang
trees only (GCC's PCH flags differ). Scratch files go to $TMPDIR/pch_sample.
docs/reliability.md, "Timings", has the figures.
"""
import json
import os
import re
import resource
import shlex
import subprocess
import sys
import tempfile

root = os.getcwd()
tree, files = sys.argv[1], sys.argv[2:]
scratch = os.path.join(tempfile.gettempdir(), 'pch_sample')
os.makedirs(scratch, exist_ok=True)
commands = {os.path.relpath(e['file'], root): e for e in json.load(open(f'{tree}/compile_commands.json'))}


def cpu_seconds(cmd, cwd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode:
        sys.exit(run.stderr[-3000:])
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def system_includes(path, seen, found):
    """Appends to found every <...> include of path and of the project headers it includes."""
    if path in seen or not os.path.exists(path):
        return
    seen.add(path)
    for line in open(path, errors='replace'):
        m = re.match(r'\s*#\s*include\s*([<"])([^>"]+)[>"]', line)
        if not m:
            continue
        if m.group(1) == '<':
            if m.group(2) not in found:
                found.append(m.group(2))
            continue
        for base in (root, os.path.dirname(path)):
            if os.path.exists(os.path.join(base, m.group(2))):
                system_includes(os.path.join(base, m.group(2)), seen, found)
                break


for f in files:
    entry = commands[f]
    args = shlex.split(entry['command'])
    if os.path.basename(args[0]) == 'ccache':
        args = args[1:]
    flags, i = [], 1  # the command without its output, input and dependency file
    while i < len(args):
        if args[i] in ('-o', '-MT', '-MF', '-c'):
            i += 2
            continue
        if args[i] != '-MD':
            flags.append(args[i])
        i += 1
    includes = []
    system_includes(os.path.join(root, f), set(), includes)
    stem = os.path.join(scratch, f.replace('/', '_'))
    with open(stem + '.h', 'w') as h:
        h.writelines(f'#include <{name}>\n' for name in includes)
    src, cwd, cc = os.path.join(root, f), entry['directory'], args[0]
    plain = cpu_seconds([cc] + flags + ['-c', src, '-o', stem + '.o'], cwd)
    pch = cpu_seconds([cc] + flags + ['-fpch-instantiate-templates', '-x', 'c++-header', stem + '.h',
                                      '-o', stem + '.pch'], cwd)
    with_pch = cpu_seconds([cc] + flags + ['-include-pch', stem + '.pch', '-c', src, '-o', stem + '.pch.o'], cwd)
    headers = cpu_seconds([cc] + flags + ['-x', 'c++', '-c', stem + '.h', '-o', stem + '.h.o'], cwd)
    print(f'{f}: plain {plain:.2f}, with the PCH {with_pch:.2f} ({100 * (1 - with_pch / plain):.0f}% less), '
          f'the PCH {pch:.2f}, the headers alone {headers:.2f} ({len(includes)} includes)', flush=True)
