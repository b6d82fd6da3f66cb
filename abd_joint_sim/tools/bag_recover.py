"""bag_recover: repair a bag whose recorder was killed or whose file is damaged.

    python -m abd_joint_sim.tools.bag_recover BAG [BAG ...]
    ros2 run abd_joint_sim bag_recover BAG

Runs :func:`abd_joint_sim.record.recover` on each bag and prints what was kept, then one line
per thing dropped (docs/bag-format.md, "Recovery"). Exit status: 0 every bag usable and
nothing dropped; 1 every bag usable, something was dropped (listed); 2 a bag could not be
recovered (one line on stderr).
"""
from __future__ import annotations

import sys
from typing import Optional, Sequence

from abd_joint_sim.tools import cli

PROG = 'bag_recover'


def describe(bag: str, report) -> list[str]:
    """The lines bag_recover prints for one recovered bag."""
    if report.was_complete:
        return [f'{PROG}: {bag}: intact and complete already ({report.messages} messages); '
                'metadata.yaml rewritten from it']
    lines = [f'{PROG}: {bag}: recovered {report.messages} messages in {report.chunks} intact '
             f'chunk(s)' + (f'; original kept as {", ".join(report.backups)}'
                            if report.backups else '')]
    for c in report.dropped_chunks:
        count = f'{c.messages} message(s)' if c.messages is not None else \
            'an unknown number of messages'
        lines.append(f'  dropped chunk {c.index} at byte {c.offset} ({count}): {c.why}')
    lines += [f'  dropped {what}' for what in report.dropped_records]
    if report.bytes_dropped:
        lines.append(f'  dropped the last {report.bytes_dropped} byte(s): '
                     f'{report.stopped_because} (the chunk being written when the recorder '
                     'stopped, or damage that breaks the record framing)')
    lines += [f'  topic {topic}: channel record lost with a damaged chunk, rebuilt from '
              'metadata.yaml' for topic in report.rebuilt_channels]
    if report.lost:
        lines.append(f'{PROG}: {bag}: {report.messages_dropped} message(s) of the damaged '
                     'chunks dropped' + (' (and the partial tail)' if report.bytes_dropped
                                         else ''))
    return lines


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = cli.Parser(prog=PROG, description=(
        'Repair abd_joint_sim bags whose recorder was killed or whose file is damaged: keep '
        'every intact chunk, rewrite the summary and metadata.yaml (the replaced files are '
        'kept as *.orig, *.orig.1, ...). Exit 0 nothing dropped, 1 something dropped, '
        '2 a bag could not be recovered.'))
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bag directory')
    args = parser.parse_args(cli.own_args(argv))
    from abd_joint_sim.record import BagError, recover
    status = 0
    for bag in args.bags:
        try:
            report = recover(bag)
        except BagError as exc:
            print(f'{PROG}: error: {exc}', file=sys.stderr)
            status = 2
            continue
        print('\n'.join(describe(bag, report)))
        status = max(status, int(report.lost))
    return status


if __name__ == '__main__':
    sys.exit(main())
