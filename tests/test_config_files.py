"""Experiments kept as files (``jaxmac.config_files``): ``jaxmac train --config FILE`` from TOML, YAML, JSON and a
run's own ``config.json``; ``jaxmac sweep --config`` method files; ``jaxmac train --list-settings``."""

import csv
import itertools
import json
import os

import pytest

from jaxmac.algos.registry import REGISTRY
from jaxmac.cli import main
from jaxmac.config import TrainConfig
from jaxmac.config_files import (config_from_file, field_meanings, load_config_file, load_methods, settings_listing,
                                 sweep_methods, write_config_file)
from jaxmac.presets import PRESETS, preset_config, scenario_config
from jaxmac.study.sweep import EXPERIMENTS, plan

CONFIGS = os.path.join(os.path.dirname(__file__), "..", "experiments", "configs")
TINY = dict(horizon=20, episodes=48, num_envs=8)


def _write(path, text):
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("algorithm", list(REGISTRY))
def test_a_written_toml_file_reads_back_the_same_config(tmp_path, algorithm):
    for scenario in ("boxpushing-6x6", "overcooked-B", "warehouse-E"):
        config = scenario_config(scenario, algorithm).override(episodes=1234)
        path = str(tmp_path / f"{scenario}.toml")
        write_config_file(config, path, seeds=(4, 3))
        read, loaded = config_from_file(path)
        assert read == config and loaded.seeds == (4, 3)
        assert type(read.algo) is type(config.algo)
        # tuples stay tuples, floats floats (a TOML integer where the field is a float)
        assert read.to_dict() == config.to_dict()


def test_json_layouts_read_back_the_same_config(tmp_path):
    config = scenario_config("warehouse-A", "mac_iaicc").override(lr=3e-4, critic_mlp_sizes=(16, 16))
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"config": config.to_dict(), "seeds": 3, "seed_offset": 2,
                                                 "rounds_per_chunk": 4}))
    for path in (str(run / "config.json"), str(run)):  # the file, or the run folder meaning it
        read, loaded = config_from_file(path)
        assert read == config and loaded.seeds == (2, 3) and loaded.config == config
    # TrainConfig.to_dict() alone (the block under "algo"): a scenario and every setting
    bare = _write(tmp_path / "bare.json", json.dumps(config.to_dict()))
    assert config_from_file(bare)[0] == config


def test_partial_files_start_from_the_scenario_values_and_the_command_line_applies_on_top(tmp_path):
    path = _write(tmp_path / "c.toml", """
scenario = "overcooked-A"
algorithm = "tomacvf"
seeds = "4:8"
episodes = 5_000
rnn_size = 48
[settings]
discount = 1    # an integer where the field is a float
""")
    config, loaded = config_from_file(path)
    wanted = {"episodes": 5000, "rnn_size": 48, "discount": 1.0}
    assert config == scenario_config("overcooked-A", "tomacvf", overrides=wanted)
    assert isinstance(config.discount, float) and loaded.seeds == (4, 4)
    config, _ = config_from_file(path, assignments=["rnn_size=16", "n_step=3"], episodes=100)
    assert (config.algo.rnn_size, config.algo.n_step, config.episodes, config.discount) == (16, 3, 100, 1.0)
    # the shipped examples: the quickstart file is the quickstart preset
    quick, loaded = config_from_file(os.path.join(CONFIGS, "quickstart.toml"))
    assert quick == preset_config("quickstart")[0] and loaded.seeds == (0, PRESETS["quickstart"].seeds)
    oc, _ = config_from_file(os.path.join(CONFIGS, "overcooked-A-tomacvf.toml"))
    assert oc == scenario_config("overcooked-A", "tomacvf", overrides=dict(episodes=40_000))
    # a file without a learner: its keys are checked as the command line's --algorithm's
    bare = _write(tmp_path / "bare.toml", "trace_len = 5\n")
    assert config_from_file(bare, algorithm="maccen_ddrqn")[0].algo.trace_len == 5


def test_yaml_files_parse_values_by_field_type(tmp_path):
    pytest.importorskip("yaml")
    path = _write(tmp_path / "c.yaml", "algorithm: mac_cac\nscenario: boxpushing-8x8\nsettings:\n  lr: 3e-4\n"
                                       "  critic_mlp_sizes: [16, 16]\n")
    config, _ = config_from_file(path)
    assert config.lr == 3e-4 and config.algo.critic_mlp_sizes == (16, 16)  # YAML's "3e-4" is a string
    example, loaded = config_from_file(os.path.join(CONFIGS, "warehouse-A-mac-iaicc.yaml"))
    assert (example.algorithm, example.lr, example.algo.critic_lr, loaded.seeds) == ("mac_iaicc", 3e-4, 3e-4, (0, 2))


@pytest.mark.parametrize("text, message", [
    ("rnn_sise = 3\n", r"unknown config key 'rnn_sise'; shared keys: .*'lr'.*tomacvf's settings: .*'rnn_size'"),
    ("seed = 3\n", r"unknown config key 'seed'.*the file's own keys: .*'seeds'"),
    ("[settings]\ncritic_lr = 0.1\n", r"'critic_lr' belongs to algorithm\(s\) \[.*'mac_cac'.*\], not to 'tomacvf'"),
    ("[setings]\nlr = 0.1\n", r"unknown config key 'setings'"),
    ("lr = 0.1\n[settings]\nlr = 0.2\n", r"lr is given twice"),
    ("rnn_size = \"wide\"\n", r"rnn_size='wide' is not a valid int"),
    ("rnn_size = 1.5\n", r"rnn_size=1.5 must be of type int"),
    ("seeds = 0\n", r"seeds = "),
    ("algorithm = \"tomacfv\"\n", r"algorithm='tomacfv' is not valid; choices"),
    ("[algo]\nlr = 0.1\n", r"\[algo\] holds tomacvf's own settings; 'lr' is not one of them"),
    ("lr = 2.0\n", r"lr=2.0 must be in \(0, 1\)"),
])
def test_bad_files_are_refused_naming_the_file_and_the_valid_keys(tmp_path, text, message):
    path = _write(tmp_path / "bad.toml", text)
    with pytest.raises(ValueError, match=message) as err:
        config_from_file(path)
    assert path in str(err.value)


def test_unreadable_files_are_one_line_errors(tmp_path, capsys):
    with pytest.raises(ValueError, match="not valid TOML"):
        load_config_file(_write(tmp_path / "x.toml", "lr = = 1\n"))
    with pytest.raises(ValueError, match="unknown format '.ini'"):
        load_config_file(_write(tmp_path / "x.ini", "lr = 1\n"))
    with pytest.raises(ValueError, match="does not exist"):
        load_config_file(str(tmp_path / "missing.toml"))
    with pytest.raises(ValueError, match="holds invalid|not fields of|is not valid"):
        load_config_file(_write(tmp_path / "run.json", json.dumps({"config": {"algorithm": "nope"}, "seeds": 1})))
    assert main(["train", "--config", str(tmp_path / "missing.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_yaml_without_pyyaml_says_how_to_install_it(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "yaml", None)  # an import of yaml now raises ImportError
    with pytest.raises(ValueError, match=r"needs PyYAML \(pip install pyyaml\)"):
        load_config_file(_write(tmp_path / "c.yml", "lr: 0.1\n"))


def test_conflicting_flags_are_refused_with_status_2(tmp_path, capsys):
    path = _write(tmp_path / "c.toml", 'scenario = "overcooked-A"\nalgorithm = "tomacvf"\n')
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"config": scenario_config("boxpushing-6x6").to_dict(), "seeds": 1,
                                                 "seed_offset": 0}))
    for argv, message in (
            (["--scenario", "overcooked-B"], "--scenario overcooked-B conflicts with scenario = 'overcooked-A'"),
            (["--algorithm", "mac_cac"], "--algorithm mac_cac conflicts with algorithm = 'tomacvf'"),
            (["--set", "algorithm=avf"], "--set algorithm=avf conflicts with algorithm = 'tomacvf'"),
            (["--preset", "quickstart"], "--resume, --finish and --preset cannot be combined with it"),
            (["--resume", str(run)], "--resume, --finish and --preset cannot be combined with it"),
            (["--set", "lr=2"], "lr=2.0 must be in (0, 1)"),
    ):
        assert main(["train", "--config", path, *argv, "--no-progress"]) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert main(["train", "--config", str(run), "--tiny", "--no-progress"]) == 2
    assert "is a run's exact configuration; --tiny would rebuild it" in capsys.readouterr().err


def test_list_settings_prints_every_key_with_its_type_default_and_meaning(capsys):
    assert main(["train", "--list-settings"]) == 0
    out = capsys.readouterr().out
    for line in ("  lr ", "  rnn_size ", "  episodes ", "  mixer "):
        assert line in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("  ") and not line.startswith("   ")}
    assert rows["lr"].split()[1:3] == ["float", "0.001"] and "learning rate" in rows["lr"]
    assert rows["rnn_size"].split()[1:3] == ["int", "32"] and "GRU width" in rows["rnn_size"]
    shared = set(TrainConfig.create("tomacvf").flat_dict())
    assert shared <= set(rows)  # every key, none blank
    assert all(len(row.split()) > 3 for key, row in rows.items() if key != "key")
    assert main(["train", "--list-settings", "--algorithm", "macdec_ddrqn"]) == 0
    out = capsys.readouterr().out
    assert "cen_explore_episodes" in out and "hysteresis_start" in out and "int list  [32, 32]" in out
    # with a config file, its learner's block
    assert main(["train", "--list-settings", "--config", os.path.join(CONFIGS, "warehouse-A-mac-iaicc.yaml")]) == 0
    assert "critic_mid_size" in capsys.readouterr().out
    for name, entry in REGISTRY.items():  # every field of every learner says something
        meanings = field_meanings(entry.settings)
        assert all(meanings.values()), (name, [k for k, v in meanings.items() if not v])
        assert "rnn_size" in settings_listing(name) or "actor_rnn_size" in settings_listing(name)
    assert all(field_meanings(TrainConfig).values())


def test_sweep_method_files_add_or_replace_methods(tmp_path):
    methods = sweep_methods(os.path.join(CONFIGS, "sweep-methods.toml"), "bp")
    own = EXPERIMENTS["bp"][0]
    assert methods[:len(own)] == own and [m.name for m in methods[len(own):]] == ["tomacvf-ow03", "tomacvf-nstep5"]
    cells = plan("bp", "smoke", methods=methods, only="tomacvf-nstep5")
    assert {c.scenario for c in cells} == set(EXPERIMENTS["bp"][1])
    six = next(c for c in cells if c.scenario == "boxpushing-6x6").config()
    eight = next(c for c in cells if c.scenario == "boxpushing-8x8").config()
    assert six.algo.n_step == eight.algo.n_step == 5 and six.updates_per_round == 4 != eight.updates_per_round
    path = _write(tmp_path / "m.toml", 'replace = true\n[[method]]\nname = "tomacvf"\nalgorithm = "tomacvf"\n'
                                       'settings = { rnn_size = 16 }\n')
    (only,) = sweep_methods(path, "ablation")
    assert only.name == "tomacvf" and dict(only.overrides) == {"rnn_size": 16}
    for text, message in (('[[method]]\nname = "x"\nalgorithm = "avf"\nsettings = { critic_lr = 0.1 }\n',
                           "belongs to algorithm"),
                          ('[[method]]\nname = "x y"\nalgorithm = "avf"\n', "give a folder name"),
                          ('[[method]]\nname = "x"\nalgorithm = "avf"\n[method.scenario_settings.mars]\nlr = 0.1\n',
                           "not a scenario or a family"),
                          ('[[methods]]\nname = "x"\n', "unknown keys")):
        with pytest.raises(ValueError, match=message):
            load_methods(_write(tmp_path / "bad.toml", text))


def test_sweep_dry_run_lists_a_method_files_cells(capsys):
    path = os.path.join(CONFIGS, "sweep-methods.toml")
    assert main(["sweep", "bp", "--protocol", "smoke", "--config", path, "--only", "ow03", "--dry-run",
                 "--out", "/nonexistent-sweep"]) == 0
    out = capsys.readouterr().out
    assert "boxpushing-6x6/tomacvf-ow03/seeds0-1" in out and "5 cells" in out


def _rows(path, n):
    with open(path) as f:
        return list(itertools.islice(csv.reader(f), n + 1))


def test_training_from_a_runs_own_config_json_repeats_the_run(tmp_path, capsys):
    from jaxmac.runs import train_run

    config = scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(**TINY)
    first = tmp_path / "first"
    train_run(config, 2, str(first), seed_offset=1, progress=False)
    again = tmp_path / "again"
    assert main(["train", "--config", str(first / "config.json"), "--out", str(again), "--no-progress"]) == 0
    with open(again / "config.json") as f:
        meta = json.load(f)
    assert TrainConfig.from_dict(meta["config"]) == config and (meta["seeds"], meta["seed_offset"]) == (2, 1)
    a, b = _rows(first / "metrics.csv", 6), _rows(again / "metrics.csv", 6)
    assert len(a) == 7 and a == b  # header and the first rounds of both seeds, every metric equal
    # the same run written as a TOML file and read back trains the same too
    toml = str(tmp_path / "run.toml")
    write_config_file(config, toml, seeds=(1, 2))
    third = tmp_path / "third"
    assert main(["train", "--config", toml, "--out", str(third), "--no-progress"]) == 0
    assert _rows(third / "metrics.csv", 6) == a
    assert "config " in capsys.readouterr().out
