"""The bench entry points' one shape: `python bench/<entry>.py COMMAND [options]`, each
COMMAND a module of bench/lib with `main(argv) -> int`; `--help` lists the commands,
`COMMAND --help` the command's options."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def run(prog: str, doc: str, commands: dict[str, tuple[str, str]], argv=None) -> int:
    """`commands`: name -> (module in bench/lib, one line of what it does)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    usage = doc.rstrip() + '\n\ncommands:\n' + '\n'.join(
        f'  {name:12s} {what}' for name, (_, what) in commands.items()) + \
        f'\n\n`python {prog} COMMAND --help` gives the options of COMMAND.'
    if not argv or argv[0] in ('-h', '--help'):
        print(usage)
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in commands:
        print(f'{prog}: unknown command {name!r}; commands: {", ".join(commands)}', file=sys.stderr)
        return 2
    module = importlib.import_module(commands[name][0])
    return module.main(rest) or 0
