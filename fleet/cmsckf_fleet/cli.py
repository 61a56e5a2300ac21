"""The `cmsckf-fleet` command line.

Why this module exists: one entry point whose subcommands share the Ray
options (where to run, with how many workers, which binary), and whose
`sweep` takes `cmsckf evaluate`'s own flags, so that the two commands can be
swapped. It only parses; each command lives in its own module.
"""

from __future__ import annotations

import argparse
import sys

from . import __version__


def ray_options(p: argparse.ArgumentParser, memory_mb: int) -> None:
    g = p.add_argument_group("where it runs")
    g.add_argument("--address", help="join the Ray cluster at ADDRESS (or set RAY_ADDRESS); embedded Ray otherwise")
    g.add_argument(
        "--workers", type=int, help="embedded Ray only: how many tasks at once (default: this machine's cores)"
    )
    g.add_argument("--cmsckf", metavar="PATH", help="the cmsckf binary (default: $CMSCKF_BIN, else cmsckf on PATH)")
    g.add_argument(
        "--max-in-flight", type=int, metavar="N", help="tasks submitted and unfinished at once (default: 2 per CPU)"
    )
    g.add_argument(
        "--task-memory-mb",
        type=int,
        default=memory_mb,
        metavar="MB",
        help=f"memory each task declares to Ray's scheduler (default: {memory_mb})",
    )
    g.add_argument("--quiet", action="store_true", help="no progress lines")


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(
        prog="cmsckf-fleet",
        description="Run cmsckf's review, evaluate and replay over a fleet, as Ray tasks (docs/fleet.md).",
    )
    top.add_argument("--version", action="version", version=f"cmsckf-fleet {__version__}")
    sub = top.add_subparsers(dest="command", required=True)

    r = sub.add_parser(
        "review",
        help="review every flight log: one table (Parquet, CSV) and an HTML fleet report",
        description="One task per log: cmsckf review --json --html, and optionally cmsckf replay.",
    )
    r.add_argument("logs", nargs="+", metavar="LOG|DIR", help="flight logs, or directories searched for *.mcap")
    r.add_argument("--out", default="fleet-review", help="where the table and report go (default: fleet-review)")
    r.add_argument("--force", action="store_true", help="write into --out even if it is not empty")
    r.add_argument("--replay-mode", metavar="M", help="also replay each log in mode M and compare with the flight")
    r.add_argument("--replay-config", metavar="C", help="also replay each log under config C and compare")
    r.add_argument(
        "--ship-logs",
        action="store_true",
        help="send each log to its worker through Ray's object store (when the workers cannot read the paths)",
    )
    r.add_argument("--title", default="cmsckf fleet review", help="the report's title")
    ray_options(r, 1024)

    s = sub.add_parser(
        "sweep",
        help="cmsckf evaluate over scenarios x configs x seeds, one task per seed; prints what evaluate prints",
        description="Takes cmsckf evaluate's own flags. One grid point prints exactly what cmsckf evaluate "
        "prints; several print one table each (or {\"grid\": [...]} with --json).",
    )
    s.add_argument("--scenario", action="append", help="racetrack | figure8 | hover | tum:<path>; repeat or comma-separate for a grid")
    s.add_argument("--modes", help="comma-separated modes (evaluate's default when not given)")
    s.add_argument("--seeds", type=int, default=10, help="seeds 1..=N (default: 10, as evaluate)")
    s.add_argument("--duration-s", help="flight length (s)")
    s.add_argument("--config", action="append", help="config file (TOML); repeat for a grid of configurations")
    s.add_argument("--sim-config", help="simulator settings (TOML)")
    s.add_argument("--gnss", choices=["on", "off"], help="fuse simulated GNSS (evaluate's default: off)")
    s.add_argument("--landed-state", choices=["on", "off"], help="as evaluate's --landed-state")
    s.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    s.add_argument("--csv", help="also write the per-mode rows as CSV (one file per grid point)")
    s.add_argument("--out", help="keep each seed's flights (CBOR) and each grid point's JSON here")
    ray_options(s, 512)

    g = sub.add_parser(
        "regress",
        help="replay logs under two builds and list each flight whose estimates differ",
        description="Exit 0 when no flight differs, 1 when some do, 2 when a replay failed.",
    )
    g.add_argument("old", metavar="OLD_BIN")
    g.add_argument("new", metavar="NEW_BIN")
    g.add_argument("logs", nargs="+", metavar="LOG|DIR")
    g.add_argument("--mode", help="replay both in this mode (default: the log's own)")
    g.add_argument("--config", help="replay both under this config (default: the log's own)")
    g.add_argument("--json", action="store_true", help="print every flight's comparison as JSON")
    ray_options(g, 1024)

    o = sub.add_parser("overhead", help="measure Ray's cost per task here: no-op and `cmsckf --version` tasks/s")
    o.add_argument("--tasks", type=int, default=2000)
    ray_options(o, 0)
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.command == "review":
        from .review import review as command
    elif args.command == "sweep":
        from .sweep import sweep as command
    elif args.command == "regress":
        from .regress import regress as command
    else:
        from .overhead import overhead as command
    return command(args)


if __name__ == "__main__":
    sys.exit(main())
