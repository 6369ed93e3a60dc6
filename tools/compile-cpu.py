#!/usr/bin/env python3
"""CPU seconds (user + sys) of compiling each source whose path contains PATTERN, once each, with
the exact command of a tree's compile_commands.json (objects to a scratch file, not the tree's).
Run it with ccache off and the machine otherwise quiet, e.g. the sanitizer tree's simulator:
  CCACHE_DISABLE=1 tools/compile-cpu.py build-asan/compile_commands.json /common/sim/src/
(docs/performance.md "CI budget")."""
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile


def main() -> int:
    if len(sys.argv) != 3:
        print("usage: compile-cpu.py COMPILE_COMMANDS_JSON PATTERN", file=sys.stderr)
        return 2
    path, pattern = sys.argv[1], sys.argv[2]
    try:
        with open(path, encoding="utf-8") as f:
            entries = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        print(f"compile-cpu: cannot read {path}: {e}", file=sys.stderr)
        return 1
    chosen = [e for e in entries if pattern in e["file"]]
    if not chosen:
        print(f"compile-cpu: no source in {path} matches {pattern!r}", file=sys.stderr)
        return 1
    total = 0.0
    with tempfile.TemporaryDirectory() as scratch:
        for entry in chosen:
            command = shlex.split(entry["command"])
            command[command.index("-o") + 1] = os.path.join(scratch, "object.o")
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run(command, cwd=entry["directory"], check=True)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
            total += cpu
            print(f"{cpu:7.1f} s  {os.path.relpath(entry['file'])}", flush=True)
    print(f"{total:7.1f} s  total, {len(chosen)} sources")
    return 0


if __name__ == "__main__":
    sys.exit(main())
