"""``springtrack model show|export PRESET``: print or write a preset shape model as TOML."""
from __future__ import annotations

import sys

from ..model import PRESETS, load_model


def add_arguments(p):
    p.add_argument("action", choices=["show", "export"],
                   help="show: print the TOML to stdout; export: write it to --out")
    p.add_argument("preset", help=f"preset name ({', '.join(PRESETS)}) or a model TOML file")
    p.add_argument("--out", help="output TOML path (export)")


def run(args) -> int:
    m = load_model(args.preset)
    text = m.to_toml()
    if args.action == "show":
        sys.stdout.write(text)
        print(f"# {len(m.trackers)} trackers, {len(m.connections)} connections, "
              f"hash {m.digest()}", file=sys.stderr)
        return 0
    if not args.out:
        print("springtrack model export: error: --out is required", file=sys.stderr)
        return 2
    with open(args.out, "w") as f:
        f.write(text)
    print(f"wrote {args.out}: {len(m.trackers)} trackers, {len(m.connections)} connections",
          file=sys.stderr)
    return 0
