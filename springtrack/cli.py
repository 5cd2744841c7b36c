"""The ``springtrack`` command line.

Each sub-command lives in ``springtrack/commands/<name>.py`` with two functions,
``add_arguments(parser)`` and ``run(args) -> int``, and is registered in
:data:`COMMANDS`; modules are imported only when their command runs.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from . import process_end

# name -> (module, one-line help)
COMMANDS = {
    "track": ("springtrack.commands.track", "track a shape model through an event file"),
    "model": ("springtrack.commands.model", "show or export a preset shape model"),
    "info": ("springtrack.commands.info", "describe an event file: format, geometry, counts, rates, anomalies"),
    "render": ("springtrack.commands.render", "draw trackers over the events (GIF/MP4/PNG)"),
    "simulate": ("springtrack.commands.simulate", "simulate an ATIS sensor on a scene, with ground truth"),
    "score": ("springtrack.commands.score", "the paper's tracking error of a track CSV against ground truth"),
    "learn": ("springtrack.commands.learn", "learn a shape model (trackers and springs) from a recording's events"),
    "experiments": ("springtrack.commands.experiments", "reproduce the paper's section IV experiments on the simulated sensor (dask)"),
    "mcu": ("springtrack.commands.mcu", "the fixed-point kernel as microcontroller firmware: build it, profile it in an emulator"),
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="springtrack",
        description="Part-based shape tracking for event cameras (Valeiras et al. 2015). "
                    "Times are in microseconds of event time, positions in pixels.")
    from . import __version__
    p.add_argument("--version", action="version", version=f"springtrack {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, (modname, helptext) in COMMANDS.items():
        sp = sub.add_parser(name, help=helptext, description=helptext,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        sp.set_defaults(_module=modname)
    return p


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # Two-stage parse: only the chosen sub-command's module is imported.
    if argv and argv[0] in COMMANDS:
        modname = COMMANDS[argv[0]][0]
        mod = importlib.import_module(modname)
        sub = argparse.ArgumentParser(prog=f"springtrack {argv[0]}",
                                      description=COMMANDS[argv[0]][1] + ".",
                                      formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(sub)
        args = sub.parse_args(argv[1:])
        process_end.catch_sigterm()
        try:
            rc = int(mod.run(args) or 0)
            sys.stdout.flush()               # a reader gone shows here, not at exit
            return rc
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
        except process_end.Terminated:
            print(f"springtrack {argv[0]}: terminated (SIGTERM); an output being written was "
                  f"closed as it stood (see the message above, if any)", file=sys.stderr)
            return process_end.TERMINATED_STATUS
        except BrokenPipeError:              # the reader of standard output went away
            return process_end.broken_pipe()
        except (ValueError, OSError) as e:   # ModelError, ParamError, DecodeError are ValueErrors
            if isinstance(e, OSError) and e.filename is not None:   # name the file first
                e = f"{e.filename}: {e.strerror or e}"
            print(f"springtrack {argv[0]}: error: {e}", file=sys.stderr)
            return 2
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
