"""metrics.csv, one row per seed and round: its columns, the rows of chunks appended (and fsynced) just before the
checkpoint that covers them, and the file read back leniently and cut to exactly the rows of a checkpoint on resume.
"""

from __future__ import annotations

import csv
import dataclasses
import os
from typing import Any

import numpy as np

from jaxmac.runs.folders import WriteFailed, append_text, fsync_dir

# The first columns of metrics.csv; every other metric the trainer and the algorithm report follows, by name.
METRIC_COLUMNS = ("seed", "round", "episodes", "epsilon", "train_return", "train_disc_return", "train_length",
                  "eval_disc_return", "eval_return", "loss")


# --- metrics.csv as a checkpoint covers it --------------------------------------------------------------------------

@dataclasses.dataclass
class MetricsFile:
    """metrics.csv read leniently: its header line and its complete, well-formed rows (raw lines, in file order);
    a partial last line (a crash or a full disk mid-write) and malformed lines are left out."""

    header: bytes | None  # the header line with its line end, None if absent or broken
    rows: list[tuple[int, int, bytes]]  # (seed, round, raw line with its end)
    dropped: int  # lines left out

    def complete_rounds(self, seed_ids: list[int]) -> int:
        """The number of leading rounds every seed has a row of."""
        have = {s: set() for s in seed_ids}
        for s, r, _ in self.rows:
            if s in have:
                have[s].add(r)
        k = 0
        while have and all(k in rounds for rounds in have.values()):
            k += 1
        return k

    def duplicate(self, below: int) -> tuple[int, int] | None:
        seen = set()
        for s, r, _ in self.rows:
            if r < below:
                if (s, r) in seen:
                    return s, r
                seen.add((s, r))
        return None


def episodes_per_seed(path: str) -> dict[str, int]:
    """{seed: training episodes at its newest row} of the metrics.csv at ``path`` ({} when there is none)."""
    last: dict[str, int] = {}
    if os.path.exists(path):
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                last[row["seed"]] = int(row["episodes"])
    return last


def read_metrics_file(path: str) -> MetricsFile:
    if not os.path.exists(path):
        return MetricsFile(None, [], 0)
    with open(path, "rb") as f:
        data = f.read()
    lines = data.split(b"\n")
    lines = [line + b"\n" for line in lines[:-1]] + ([lines[-1]] if lines[-1] else [])
    if not lines or not lines[0].endswith(b"\n"):
        return MetricsFile(None, [], len(lines))
    header = next(csv.reader([lines[0].decode("utf-8", "replace")]), [])
    if header[:2] != ["seed", "round"]:
        return MetricsFile(None, [], len(lines))
    rows, dropped = [], 0
    for line in lines[1:]:
        fields = None
        if line.endswith(b"\n"):
            try:
                fields = next(csv.reader([line.decode("utf-8")]), None)
            except (UnicodeDecodeError, csv.Error):
                fields = None
        try:
            if fields is None or len(fields) != len(header):
                raise ValueError
            rows.append((int(fields[0]), int(fields[1]), line))
        except ValueError:
            dropped += 1
    return MetricsFile(lines[0], rows, dropped)


def cut_metrics(path: str, metrics: MetricsFile, rounds_done: int) -> None:
    """Rewrite metrics.csv (atomically) as exactly its rows of rounds ``< rounds_done`` (none: no file)."""
    if metrics.header is None:  # nothing usable (no rows can be kept): the next rows start a new file
        if os.path.exists(path):
            os.remove(path)
        return
    text = metrics.header + b"".join(line for _, r, line in metrics.rows if r < rounds_done)
    with open(path, "rb") as f:
        if f.read() == text:
            return
    tmp = path + ".tmp"
    try:
        with open(tmp, "wb") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise WriteFailed(path, err, "free space, then resume again") from err
    fsync_dir(os.path.dirname(os.path.abspath(path)))


def metric_columns(metrics: dict[str, Any]) -> list[str]:
    """``METRIC_COLUMNS`` then every other reported metric in name order."""
    return list(METRIC_COLUMNS) + sorted(k for k in metrics if k not in METRIC_COLUMNS)


def _metrics_columns_of(path: str, metrics: dict[str, np.ndarray]) -> tuple[list[str], bool]:
    """The columns rows appended to ``path`` have (its header's, or the metrics' own for a new file) and whether
    the file is new (the rows must be headed)."""
    if not os.path.exists(path):
        return metric_columns(metrics), True
    with open(path, newline="") as f:
        return next(csv.reader(f)), False


def _metrics_text(columns: list[str], metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int,
                  header: bool = False) -> str:
    """The CSV text of one row per seed and round for metrics with leaves [seeds, rounds], in ``columns``."""
    import io

    seeds, rounds = np.shape(metrics["episodes"])
    out = io.StringIO()
    w = csv.writer(out)
    if header:
        w.writerow(columns)
    for s in range(seeds):
        for r in range(rounds):
            row = [seed_ids[s], first_round + r, int(metrics["episodes"][s, r])]
            for k in columns[3:]:
                value = metrics[k][s, r] if k in metrics else float("nan")
                row.append(int(value) if np.issubdtype(np.asarray(value).dtype, np.integer) else float(value))
            w.writerow(row)
    return out.getvalue()


def append_chunks(path: str, chunks: list[tuple[dict[str, np.ndarray], int]], seed_ids: list[int],
                   advice: str = "") -> None:
    """Append the rows of several chunks' metrics ((metrics, first round) each) in one write, then fsync."""
    if not chunks:
        return
    columns, new = _metrics_columns_of(path, chunks[0][0])
    text = "".join(_metrics_text(columns, m, seed_ids, first, header=new and k == 0)
                   for k, (m, first) in enumerate(chunks))
    append_text(path, text, advice)
