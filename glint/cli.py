"""``glint``: one parser for worker's commands (worker/cli.py), the server's (server/cli.py) and
the benchmarks' (bench/cli.py).

The layers run one way (server → worker; bench → worker): this module is where they meet, so
that worker needs no knowledge of the service to offer ``glint serve`` on the same command line.
"""
from __future__ import annotations

import argparse
import sys

# worker.cli first: it sets OPENBLAS_NUM_THREADS before anything loads NumPy
from worker import cli as worker_cli


def build_parser() -> argparse.ArgumentParser:
    from bench import cli as bench_cli
    from server import cli as server_cli

    p, sub = worker_cli.new_parser()
    worker_cli.add_commands(sub, bench=bench_cli.add_bench_commands)
    server_cli.add_commands(sub)
    bench_cli.add_commands(sub)
    return p


def main(argv=None) -> int:
    return worker_cli.run(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
