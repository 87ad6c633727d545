"""CLI: ``python -m envs_jax.conformance FILE.npz [FILE …]``."""

from __future__ import annotations

import argparse
import sys

from envs_jax.conformance import check_file


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m envs_jax.conformance",
        description="Replay golden traces of the original environments against the JAX envs.",
    )
    parser.add_argument("files", nargs="+",
                        help="trace files (.npz) in a format of docs/traces.md, e.g. tests/data/traces/*/*.npz")
    args = parser.parse_args(argv)
    total = matched = 0
    failed = False
    for path in args.files:
        try:
            report = check_file(path)
        except (OSError, ValueError) as err:
            print(f"ERROR {path}: {err}")
            failed = True
            continue
        print(report.summary(), flush=True)
        if report.first_mismatch is not None:
            print("  first mismatch: " + report.first_mismatch.describe(path), flush=True)
        total += report.transitions
        matched += report.matched
        failed |= not report.ok
    print(f"{matched}/{total} transitions match")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
