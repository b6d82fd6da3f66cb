"""bag_recover: complete a bag whose recorder was killed (SIGKILL, power cut, full disk).

    python -m abd_joint_sim.ros.bag_recover BAG [BAG ...]
    ros2 run abd_joint_sim bag_recover BAG

sim_node closes its current MCAP chunk every second and on pause, so a killed node's bag
holds everything up to the last second or so; but without the MCAP summary (written on a
clean stop) indexed readers (``ros2 bag``, rosbags, Foxglove) refuse it. This command runs
:func:`abd_joint_sim.record.recover` on each bag: it keeps every complete chunk, rewrites
the MCAP with a summary and a complete metadata.yaml, and keeps the damaged original as
``<bag>_0.mcap.orig``. A bag that is complete already is left as it is (only its
metadata.yaml is rewritten).

Exit status: 0 every bag usable now; 2 a bag could not be recovered (one line on stderr).
"""
from __future__ import annotations

import argparse
import sys
from typing import Optional, Sequence

PROG = 'bag_recover'


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    parser = argparse.ArgumentParser(prog=PROG, description=(
        'Complete abd_joint_sim bags whose recorder was killed: keep every complete chunk, '
        'rewrite the summary and metadata.yaml (the original is kept as *.mcap.orig).'))
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bag directory')
    args = parser.parse_args(argv)
    from abd_joint_sim.record import BagError, recover
    status = 0
    for bag in args.bags:
        try:
            report = recover(bag)
        except BagError as exc:
            print(f'{PROG}: error: {exc}', file=sys.stderr)
            status = 2
            continue
        if report.was_complete:
            print(f'{PROG}: {bag}: complete already ({report.messages} messages); '
                  'metadata.yaml rewritten')
        else:
            print(f'{PROG}: {bag}: recovered {report.messages} messages in {report.chunks} '
                  f'complete chunks; dropped {report.bytes_dropped} bytes of the chunk in '
                  f'progress ({report.stopped_because})')
    return status


if __name__ == '__main__':
    sys.exit(main())
