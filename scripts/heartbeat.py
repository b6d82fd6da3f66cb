"""Run a command, passing its output through line by line, and print `<label>: still running
(N s)` to stderr whenever it has been silent for INTERVAL seconds (pip says nothing for
minutes while it unpacks large wheels). Exit status: the command's.
Usage: python3 scripts/heartbeat.py LABEL INTERVAL -- COMMAND [ARGS...]"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time


def main(argv: list[str]) -> int:
    if len(argv) < 4 or argv[2] != '--':
        print(__doc__.splitlines()[-1], file=sys.stderr)
        return 2
    label, interval, command = argv[0], float(argv[1]), argv[3:]
    t0 = time.monotonic()
    last = [t0]                 # when the command last printed, or we did
    # unbuffered: a Python child (pip) writes each line when it has it, not at exit
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env=dict(os.environ, PYTHONUNBUFFERED='1'))
    done = threading.Event()

    def beat():
        while not done.wait(min(1.0, interval / 4)):
            now = time.monotonic()
            if now - last[0] >= interval:
                print(f'{label}: still running ({now - t0:.0f} s)', file=sys.stderr, flush=True)
                last[0] = now

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    for line in iter(proc.stdout.readline, b''):
        last[0] = time.monotonic()
        sys.stderr.buffer.write(line)
        sys.stderr.flush()
    rc = proc.wait()
    done.set()
    thread.join()
    return rc


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
