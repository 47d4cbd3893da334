"""Command-line interface: ``reflecto info``, ``reflecto tabulate``."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ReflectoError


def _progress(total: int, desc: str, enabled: bool):  # type: ignore[no-untyped-def]
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="bin", unit_scale=True, disable=not enabled, leave=False)


def cmd_info(args: argparse.Namespace) -> int:
    from .sources import load_source

    src = load_source(args.source)
    theta = np.array([0.0, 20.0, 40.0, 60.0, 80.0])
    alb = src.albedo(theta)
    info = {
        "file": str(src.path),
        "kind": src.kind,
        "isotropic": bool(src.isotropic),
        "reciprocal": bool(src.reciprocal),
        "parameters": src.parameters(),
        "albedo": {f"{t:g}deg": [round(float(v), 5) for v in a] for t, a in zip(theta, alb)},
        "albedo_range": [round(float(alb.min()), 5), round(float(alb.max()), 5)],
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"{info['file']}")
    print(f"  kind        {info['kind']}  (isotropic: {info['isotropic']}, reciprocal: {info['reciprocal']})")
    for k, v in info["parameters"].items():
        print(f"  {k:<11} {v}")
    print("  directional albedo (RGB) at θ_i:")
    for k, v in info["albedo"].items():
        print(f"    {k:>6}  {v[0]:.4f} {v[1]:.4f} {v[2]:.4f}")
    print(f"  albedo range [{info['albedo_range'][0]:.4f}, {info['albedo_range'][1]:.4f}]")
    return 0


def cmd_tabulate(args: argparse.Namespace) -> int:
    from .sources import load_source
    from .sources import merl

    src = load_source(args.source)
    out = Path(args.output)
    with _progress(merl.N_BINS, f"tabulating {src.name}", not args.quiet and sys.stderr.isatty()) as bar:
        table = merl.tabulate(src, progress=bar.update)
    merl.write_merl_table(out, table)
    if not args.quiet:
        print(f"wrote {out} ({out.stat().st_size} bytes, MERL 90x90x180, bin centres)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="reflecto",
        description="Condenser-based instant reflectometry (Lan et al. 2010): BRDF model, sources and tools.",
    )
    p.add_argument("--version", action="version", version=f"reflecto {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    q = sub.add_parser("info", help="kind, parameters and albedo range of a BRDF file")
    q.add_argument("source", help="BRDF file: .binary, .bsdf, .h5, .json/.toml, .reflecto")
    q.add_argument("--json", action="store_true", help="print machine-readable JSON")
    q.set_defaults(func=cmd_info)

    q = sub.add_parser("tabulate", help="write a MERL-format table of any BRDF source")
    q.add_argument("source", help="BRDF file")
    q.add_argument("-o", "--output", required=True, help="output .binary file")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    q.set_defaults(func=cmd_tabulate)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ReflectoError as e:
        print(f"reflecto: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("reflecto: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
