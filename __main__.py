"""Command line: `python -m ember render [FILE.blend] [-o PATH] [--samples N] [--frames A-B] ...`

Run `python -m ember render --help` for every option.
"""
import sys

from .engine.cli import main

sys.exit(main(sys.argv[1:]))
