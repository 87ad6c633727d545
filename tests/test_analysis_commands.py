"""Every subcommand prints its help; ``jaxmac calibrate``, ``jaxmac overlay`` and ``jaxmac qtot`` are installed
subcommands (jaxmac/study/calibrate.py, jaxmac/study/overlay.py, jaxmac/runs/qtot.py); ``overlay`` draws run folders'
and original runs' curves on one figure. (``calibrate``: tests/test_calibrate_protocol.py; ``qtot`` on a trained run:
tests/test_evaluate.py.)"""

from __future__ import annotations

import csv
import pathlib

import pytest

from jaxmac.cli import main


@pytest.mark.parametrize("command, says", [("calibrate", "--from-sweep"), ("overlay", "--original"),
                                           ("qtot", "--seed-index")])
def test_each_command_has_its_help(command, says, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: jaxmac {command}") and says in out


def test_every_command_prints_its_help(capsys):
    """argparse expands ``%`` in help texts: one unescaped ``%`` (e.g. "within 2 %") breaks that command's --help."""
    import argparse

    from jaxmac.cli import build_parser

    subparsers = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert {"train", "sweep", "results"} <= set(subparsers.choices)
    for command in subparsers.choices:
        with pytest.raises(SystemExit) as exit_:
            main([command, "--help"])
        assert exit_.value.code == 0, command
        assert capsys.readouterr().out.startswith(f"usage: jaxmac {command}"), command


def _fake_run(path: pathlib.Path, returns_per_seed: list[list[float]]) -> pathlib.Path:
    """A run folder with only a metrics.csv: one row per seed and evaluation, every 100 episodes."""
    path.mkdir()
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", "episodes", "eval_disc_return"])
        for seed, returns in enumerate(returns_per_seed):
            for i, value in enumerate(returns):
                writer.writerow([seed, 100 * (i + 1), value])
    return path


def test_overlay_writes_one_figure_of_runs_and_originals(tmp_path, capsys):
    """Two run folders and one original run of two seeds: a PNG and a PDF beside it, and per curve its seeds,
    episodes and the mean of its last 10 evaluations."""
    from PIL import Image

    a = _fake_run(tmp_path / "a", [[float(v) for v in range(20)], [float(v) + 2 for v in range(20)]])
    b = _fake_run(tmp_path / "b", [[100.0] * 12])
    originals = []
    for seed in range(2):
        folder = tmp_path / "orig" / f"seed{seed}"
        folder.mkdir(parents=True)
        rows = [f"{i},{50 * (i + 1)},{10.0 * seed}" for i in range(15 + seed)]  # seed 1 one evaluation further
        (folder / "test_returns.csv").write_text("eval,episodes,return\n" + "\n".join(rows) + "\n")
        originals.append(str(folder))
    out = tmp_path / "fig.png"
    assert main(["overlay", "--out", str(out), "--title", "t", "--optimum", "120", "--run", f"run a={a}",
                 "--run", f"run b={b}", "--original", "orig=" + ",".join(originals)]) == 0
    printed = capsys.readouterr().out
    assert "run a: 2 seeds, 2000 episodes; mean of the last 10 evaluations 15.5 (per seed 14.5 16.5)" in printed
    assert "run b: 1 seeds, 1200 episodes; mean of the last 10 evaluations 100.0 (per seed 100.0)" in printed
    assert "orig: 2 seeds, 750 episodes; mean of the last 10 evaluations 5.0 (per seed 0.0 10.0)" in printed
    assert printed.rstrip().endswith(f"wrote {out}")
    with Image.open(out) as image:
        assert image.format == "PNG" and min(image.size) > 100
    assert out.with_suffix(".pdf").stat().st_size > 0
    assert main(["overlay", "--out", str(tmp_path / "none.png"), "--run", str(a)]) == 2  # no LABEL=: one line
    assert "expected LABEL=PATH" in capsys.readouterr().err
