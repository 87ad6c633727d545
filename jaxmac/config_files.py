"""Experiments kept as files: ``jaxmac train --config FILE``, ``jaxmac sweep EXP --config FILE`` and the listing of
every setting (``jaxmac train --list-settings``).

A training file (TOML; YAML with PyYAML installed; JSON) names a scenario and a learner and changes some of their
settings; the rest are the scenario's values, exactly as ``--scenario``/``--algorithm``/``--set`` would give::

    about = "ToMacVF on Overcooked-A with a longer warm-up"   # optional, printed when the run starts
    scenario = "overcooked-A"        # default boxpushing-6x6 (or --scenario)
    algorithm = "tomacvf"            # default tomacvf (or --algorithm)
    seeds = 4                        # optional: a count N, or "A:B" (seeds A..B-1); --seeds overrides it
    paper = false                    # optional: the publication's table (--paper)
    tiny = false                     # optional: tiny networks and budgets (--tiny)
    episodes = 20_000                # any setting, at the top level ...

    [settings]                       # ... or here: shared and the learner's keys alike, as --set takes them
    start_train_episodes = 500
    mlp_sizes = [32, 32]             # a list where the field is a tuple of ints

A run folder's ``config.json`` (or the folder itself) is its exact configuration and seeds: training from it
repeats the run (``--episodes``, ``--seeds`` and ``--set`` still apply on top). Unknown keys are refused, naming
the valid ones; values keep their file types (checked against the field's type; a string is parsed as ``--set``
would, so YAML's ``1e-3`` works).

A sweep's method file lists methods that ``jaxmac sweep EXP --config FILE`` adds to the experiment's (a method of
the same name replaces the experiment's; ``replace = true``: the file's methods are the only ones)::

    [[method]]
    name = "tomacvf-ow03"            # the cells' folder name
    algorithm = "tomacvf"
    label = "ToMacVF (optimistic 0.3)"
    settings = { overestimate_weight = 0.3 }
    [method.scenario_settings.boxpushing-6x6]   # on a scenario, or a family (boxpushing, overcooked, warehouse)
    updates_per_round = 4
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import json
import os
import re
import textwrap
import tokenize
import typing
from typing import Any

from envs_jax.validation import parse_value, type_name
from jaxmac.config import TrainConfig, _block_hints, _route, settings_class

FORMATS = {".toml": "TOML", ".yaml": "YAML", ".yml": "YAML", ".json": "JSON"}
# top-level keys of a training file that are not settings
FILE_KEYS = ("about", "scenario", "algorithm", "seeds", "paper", "tiny", "settings", "algo")
METHOD_KEYS = ("name", "algorithm", "label", "paper", "settings", "scenario_settings")


@dataclasses.dataclass(frozen=True)
class ConfigFile:
    """A training file as read: either a run's exact ``config`` (a run folder's config.json) or a scenario, a
    learner and the settings that change theirs."""

    path: str
    config: TrainConfig | None = None  # a run's whole configuration (then the fields below are unused)
    scenario: str | None = None
    algorithm: str | None = None
    settings: dict[str, Any] = dataclasses.field(default_factory=dict)
    seeds: tuple[int, int] | None = None  # (first seed, count)
    paper: bool = False
    tiny: bool = False
    about: str = ""


def read_document(path: str) -> dict[str, Any]:
    """The file's top-level table (a folder means its ``config.json``)."""
    if os.path.isdir(path):
        path = os.path.join(path, "config.json")
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in FORMATS:
        raise ValueError(f"config file {path}: unknown format {suffix or '(no suffix)'!r}; give a .toml, .yaml/.yml "
                         "or .json file (or a run folder, meaning its config.json)")
    if not os.path.exists(path):
        raise ValueError(f"config file {path} does not exist")
    try:
        if FORMATS[suffix] == "TOML":
            import tomllib

            with open(path, "rb") as f:
                data = tomllib.load(f)
        elif FORMATS[suffix] == "YAML":
            try:
                import yaml
            except ImportError:
                raise ValueError(f"config file {path}: reading YAML needs PyYAML (pip install pyyaml), or write the "
                                 "file as TOML") from None
            with open(path) as f:
                data = yaml.safe_load(f)
        else:
            with open(path) as f:
                data = json.load(f)
    except OSError as err:
        raise ValueError(f"cannot read config file {path}: {err.strerror}") from err
    except ValueError as err:  # tomllib.TOMLDecodeError and json.JSONDecodeError are ValueErrors
        raise ValueError(f"config file {path} is not valid {FORMATS[suffix]}: {err}") from err
    except Exception as err:  # yaml.YAMLError
        raise ValueError(f"config file {path} is not valid {FORMATS[suffix]}: {err}") from err
    if not isinstance(data, dict):
        raise ValueError(f"config file {path} must hold a table of settings, not {type(data).__name__}")
    return data


def load_config_file(path: str, algorithm: str | None = None) -> ConfigFile:
    """Read a training file (see the module's docstring), its names and types checked (as settings of the file's
    learner, else of ``algorithm``, else of ToMacVF)."""
    data = read_document(path)
    try:
        if isinstance(data.get("config"), dict):  # a run's config.json: {"config": TrainConfig.to_dict(), "seeds": ...}
            config = TrainConfig.from_dict(data["config"])
            seeds = None
            if _is_int(data.get("seeds")) and _is_int(data.get("seed_offset", 0)):
                seeds = (data.get("seed_offset", 0), data["seeds"])
            return ConfigFile(path, config=config, seeds=seeds)
        values = dict(data)
        about = values.pop("about", "")
        scenario = values.pop("scenario", None)
        file_algorithm = values.pop("algorithm", None)
        seeds = _seeds(values.pop("seeds")) if "seeds" in values else None
        paper, tiny = values.pop("paper", False), values.pop("tiny", False)
        for name, value in (("scenario", scenario), ("algorithm", file_algorithm), ("about", about)):
            if value is not None and not isinstance(value, str):
                raise ValueError(f"{name} = {value!r} must be a string")
        for name, value in (("paper", paper), ("tiny", tiny)):
            if not isinstance(value, bool):
                raise ValueError(f"{name} = {value!r} must be true or false")
        try:
            settings = _merge_tables(values, file_algorithm or algorithm or "tomacvf")
        except ValueError as err:
            if str(err).startswith("unknown config key"):  # a misspelt file key (seed = 4) as well as a setting
                raise ValueError(f"{err}; the file's own keys: {list(FILE_KEYS)}") from None
            raise
        return ConfigFile(path, scenario=scenario, algorithm=file_algorithm, settings=settings, seeds=seeds,
                          paper=paper, tiny=tiny, about=about)
    except (ValueError, TypeError, KeyError) as err:
        raise ValueError(f"config file {path}: {err}") from err


def config_from_file(path: str, scenario: str | None = None, algorithm: str | None = None, tiny: bool = False,
                     paper: bool = False, assignments: list[str] = (), episodes: int | None = None,
                     ) -> tuple[TrainConfig, ConfigFile]:
    """The configuration ``jaxmac train --config path`` runs: the file's, with the command line's ``--set``
    assignments and ``--episodes`` on top (one validation). ``scenario``/``algorithm`` given on the command line
    must agree with the file's; ``tiny``/``paper`` cannot change a run's exact configuration."""
    from jaxmac.config import parse_assignments
    from jaxmac.presets import scenario_config

    loaded = load_config_file(path, algorithm)
    named = loaded.config or loaded
    cli = parse_assignments(list(assignments), named.algorithm or algorithm or "tomacvf")
    for key, flag_value in (("scenario", scenario), ("algorithm", algorithm)):
        held = getattr(named, key)
        for given, said in ((flag_value, f"--{key} "), (cli.get(key), f"--set {key}=")):
            if given is not None and held is not None and given != held:
                raise ValueError(f"{said}{given} conflicts with {key} = {held!r} in {path}: edit the file (or a "
                                 f"copy) to change it, or leave {said.strip()} out")
    if episodes is not None:
        cli["episodes"] = episodes
    if loaded.config is not None:
        clash = [flag for flag, on in (("--tiny", tiny), ("--paper", paper)) if on]
        if clash:
            raise ValueError(f"{path} is a run's exact configuration; {', '.join(clash)} would rebuild it from the "
                             "scenario's table: change single settings with --set instead")
        return loaded.config.override(**cli), loaded
    overrides = {**loaded.settings, **cli}
    algorithm = overrides.pop("algorithm", None) or loaded.algorithm or algorithm or "tomacvf"
    scenario = overrides.pop("scenario", None) or loaded.scenario or scenario or "boxpushing-6x6"
    try:
        config = scenario_config(scenario, algorithm, tiny=tiny or loaded.tiny, paper=paper or loaded.paper,
                                 overrides=overrides)
    except (ValueError, TypeError) as err:
        raise ValueError(f"config file {path}: {err}") from err
    return config, loaded


def write_config_file(config: TrainConfig, path: str, seeds: tuple[int, int] | None = None) -> None:
    """``config`` as a TOML training file (every setting written; ``load_config_file`` reads it back equal)."""
    lines = [f"scenario = {_toml(config.scenario)}", f"algorithm = {_toml(config.algorithm)}"]
    if seeds is not None:
        lines.append(f"seeds = {_toml(f'{seeds[0]}:{seeds[0] + seeds[1]}')}")
    lines += ["", "[settings]"]
    lines += [f"{k} = {_toml(v)}" for k, v in config.flat_dict().items() if k not in ("scenario", "algorithm")]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


# --- a sweep's methods ------------------------------------------------------------------------------

def load_methods(path: str) -> tuple[tuple[Any, ...], bool]:
    """The methods of a sweep's method file (``jaxmac.study.sweep.Method``s) and whether they replace the experiment's."""
    from jaxmac.study.sweep import Method

    data = read_document(path)
    unknown = sorted(set(data) - {"method", "replace"})
    if unknown:
        raise ValueError(f"method file {path}: unknown keys {unknown}; a method file holds [[method]] tables (keys "
                         f"{list(METHOD_KEYS)}) and optionally replace = true")
    replace = data.get("replace", False)
    tables = data.get("method", [])
    if not isinstance(replace, bool) or not isinstance(tables, list) or not tables:
        raise ValueError(f"method file {path}: needs at least one [[method]] table (and replace = true or false)")
    methods, names = [], set()
    for k, table in enumerate(tables):
        where = f"method file {path}, method {k + 1}"
        try:
            if not isinstance(table, dict):
                raise ValueError("must be a table")
            unknown = sorted(set(table) - set(METHOD_KEYS))
            if unknown:
                raise ValueError(f"unknown keys {unknown}; a method's keys: {list(METHOD_KEYS)}")
            name, algorithm = table.get("name"), table.get("algorithm")
            if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.+-]*", name):
                raise ValueError(f"name = {name!r}: give a folder name (letters, digits, - _ . +)")
            if name in names:
                raise ValueError(f"name {name!r} is given twice")
            names.add(name)
            if not isinstance(algorithm, str):
                raise ValueError(f"algorithm = {algorithm!r} must name a learner")
            settings_class(algorithm)
            label, paper = table.get("label", ""), table.get("paper", False)
            if not isinstance(label, str) or not isinstance(paper, bool):
                raise ValueError("label must be a string and paper true or false")
            overrides = _typed(_table(table.get("settings", {}), "settings"), algorithm)
            per_scenario = []
            for key, extra in _table(table.get("scenario_settings", {}), "scenario_settings").items():
                _check_scenario_key(key)
                per_scenario.append((key, tuple(_typed(_table(extra, f"scenario_settings.{key}"), algorithm).items())))
            _route(algorithm, overrides)
            for _, extra in per_scenario:
                _route(algorithm, dict(extra))
        except (ValueError, TypeError) as err:
            raise ValueError(f"{where}: {err}") from err
        methods.append(Method(name, algorithm, tuple(overrides.items()), label, tuple(per_scenario), paper))
    return tuple(methods), replace


def sweep_methods(path: str, experiment: str) -> tuple:
    """``experiment``'s methods with a method file's (``jaxmac sweep EXPERIMENT --config path``)."""
    from jaxmac.study.sweep import EXPERIMENTS

    if experiment not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {experiment!r}; valid experiments: {list(EXPERIMENTS)}")
    methods, replace = load_methods(path)
    return merged_methods(EXPERIMENTS[experiment][0], methods, replace)


def merged_methods(experiment_methods: tuple, methods: tuple, replace: bool) -> tuple:
    """The experiment's methods with a file's: replaced by name, the new ones appended (``replace``: only the
    file's)."""
    if replace:
        return tuple(methods)
    by_name = {m.name: m for m in methods}
    kept = tuple(by_name.pop(m.name, m) for m in experiment_methods)
    return kept + tuple(m for m in methods if m.name in by_name)


# --- the listing of every setting ---------------------------------------------------------------------

# Meanings of fields whose source carries no comment (nor a sentence naming them in their class's docstring); a
# comment on the field's line (or just above it) takes precedence.
EXTRA_MEANINGS = {
    "scenario": "the env and its task (jaxmac.scenarios.SCENARIOS; jaxmac train --scenario)",
    "algorithm": "the learner (jaxmac.algos.registry; jaxmac train --algorithm); switching it resets the block",
    "lr": "learning rate of the Adam optimiser (the actor's for the actor-critics)",
    "eps_start": "ε of the ε-greedy behaviour policy at the start of its linear decay",
    "eps_end": "ε after eps_decay_episodes episodes of decay",
    "eps_decay_episodes": "episodes over which ε falls linearly from eps_start to eps_end",
    "eval_every_episodes": "training episodes between evaluations (a row of the learning curve)",
    "eval_episodes": "episodes per evaluation",
    "rnn_size": "GRU width of the recurrent network(s)",
    "mlp_sizes": "widths of the two fully connected layers, before and after the GRU",
    "fc_size": "width of the agent network's fully connected layers",
    "n_step": "steps of the TD target (n-step returns)",
    "actor_mlp_sizes": "the actor's fully connected widths, before and after its GRU",
    "actor_rnn_size": "the actor's GRU width",
    "critic_mlp_sizes": "the critic's fully connected widths, before and after its GRU",
    "critic_rnn_size": "the critic's GRU width",
    "critic_mid_size": "width of the middle layer of a state critic (critic='state')",
    "max_joint_actions": "refuse envs whose joint macro-action space is larger",
    "mixer": "the mixing network of Q_tot (qmix, vdn, ...)",
    "mixer_embed": "the mixer's embedding width",
    "hyper_hidden": "hidden width of the mixer's hyper-networks",
    "cen_rnn_size": "the centralised net's GRU width",
    "cen_mlp_sizes": "the centralised net's fully connected widths, before and after its GRU",
    "macro_loss_weight": "weight λ of the macro-TD loss",
    "obs_mode": "what the agent networks read: 'real' = each agent's current observation at every step, 'macro' = "
                "the observation frozen at its last decision (MacDec-POMDP)",
    "attn_dim": "width d of ATPG's tokens and of its temporal and agent attention",
    "time_pe_dim": "width of the sinusoidal encoding of the absolute time step t",
    "progress_pe_dim": "width of the sinusoidal encoding of the running macro-action's progress t_m",
    "use_time_pe": "whether the agents see the encoding of the absolute time step (it reveals the horizon)",
}


def field_meanings(cls: type) -> dict[str, str]:
    """``cls``'s fields (a dataclass, its bases' included) -> what each means: the comment on the field's line and
    the comment lines just above it, in the nearest class of the MRO that has one; else the sentences of a class
    docstring that name the field (````name````); else ``EXTRA_MEANINGS``."""
    names = [f.name for f in dataclasses.fields(cls)]
    comments = {}
    for klass in cls.__mro__:
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        for name, text in _source_comments(klass).items():
            comments.setdefault(name, text)
    meanings = {}
    for name in names:
        text = comments.get(name, "")
        if _bare(text):  # none, or only a reference ("D1", "λ (D8)"): say what it is, keeping the reference
            extra, doc = EXTRA_MEANINGS.get(name, ""), _docstring_sentences(cls, name)
            said = "; ".join(t for t in (extra, doc if not extra or len(doc) < 160 else "") if t)
            text = f"{said} ({text})" if said and text else said or text
        meanings[name] = text.replace("``", "")
    for name in names:  # a field of a group that one comment describes (above its first field)
        if not meanings[name] and "_" in name:
            other = next((n for n in names if re.search(rf"(?<![\w.]){name}(?![\w'])", meanings[n])), None)
            meanings[name] = f"see {other}" if other else ""
    return meanings


def _bare(comment: str) -> bool:
    """Whether a comment only refers (to a decision, a symbol) without saying what the field is."""
    words = re.findall(r"[A-Za-z]{2,}", re.sub(r"\bD\d+\b", "", comment))
    return words in ([], ["flag"])


def settings_listing(algorithm: str = "tomacvf", width: int = 110) -> str:
    """Every key ``jaxmac train`` takes (``--set``, a config file): the shared settings and ``algorithm``'s block,
    each with its type, default and meaning."""
    from jaxmac.algos.registry import learner

    entry = learner(algorithm)
    block = settings_class(algorithm)
    shared_hints = typing.get_type_hints(TrainConfig)
    block_hints = typing.get_type_hints(block)
    shared = [(f.name, shared_hints[f.name], f.default) for f in dataclasses.fields(TrainConfig) if f.name != "algo"]
    own = [(f.name, block_hints[f.name], f.default) for f in dataclasses.fields(block)]
    rows = [(n, _type_text(h), _toml(d)) for n, h, d in shared + own]
    w_name, w_type, w_default = (max(len(r[i]) for r in rows) for i in range(3))
    indent = 2 + w_name + 2 + w_type + 2 + w_default + 2
    out = [textwrap.fill("Settings of jaxmac train: --set KEY=VALUE, or KEY = VALUE in a config file (--config "
                         "FILE, at the top level or under [settings]). Defaults are the dataclasses'; a scenario's "
                         "own values (jaxmac.presets.scenario_config) replace many of them.", width), ""]
    for title, fields, cls in ((f"shared settings (jaxmac.config.TrainConfig), {len(shared)}:", shared, TrainConfig),
                               (f"{algorithm}'s settings ({block.__module__}.{block.__name__}; {entry.summary}), "
                                f"{len(own)}:", own, block)):
        meanings = field_meanings(cls)
        out.append(title)
        out.append(f"  {'key'.ljust(w_name)}  {'type'.ljust(w_type)}  {'default'.ljust(w_default)}  meaning")
        for name, hint, default in fields:
            head = f"  {name.ljust(w_name)}  {_type_text(hint).ljust(w_type)}  {_toml(default).ljust(w_default)}  "
            text = meanings.get(name) or "-"
            lines = textwrap.wrap(text, max(30, width - indent)) or [""]
            out.append(head + lines[0])
            out += [" " * indent + line for line in lines[1:]]
        out.append("")
    from jaxmac.algos.registry import REGISTRY

    out.append(textwrap.fill(f"Other learners' blocks: jaxmac train --list-settings --algorithm A (A: "
                             f"{', '.join(REGISTRY)}).", width))
    return "\n".join(out)


# --- helpers -----------------------------------------------------------------------------------------

def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _seeds(value: Any) -> tuple[int, int]:
    from jaxmac.cli import seed_range

    if _is_int(value):
        value = str(value)
    if not isinstance(value, str):
        raise ValueError(f"seeds = {value!r}: give a count N or a range \"A:B\" (seeds A..B-1)")
    try:
        return seed_range(value)
    except Exception as err:  # argparse.ArgumentTypeError
        raise ValueError(str(err).replace("--seeds", "seeds =")) from None


def _table(value: Any, name: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{name} must be a table of settings, not {value!r}")
    return value


def _check_scenario_key(key: str) -> None:
    from jaxmac.scenarios import FAMILIES, SCENARIOS

    if key not in SCENARIOS and key not in FAMILIES:
        raise ValueError(f"scenario_settings.{key}: not a scenario or a family; scenarios: {list(SCENARIOS)}; "
                         f"families: {list(FAMILIES)}")


def _merge_tables(values: dict[str, Any], algorithm: str) -> dict[str, Any]:
    """Top-level settings, ``[settings]`` (shared and block keys) and ``[algo]`` (block keys, as ``to_dict``
    writes them) in one typed dict; a key given twice is refused."""
    tables = [("top level", {k: v for k, v in values.items() if k not in ("settings", "algo")}),
              ("[settings]", _table(values.get("settings", {}), "settings")),
              ("[algo]", _table(values.get("algo", {}), "algo"))]
    block_names = {f.name for f in dataclasses.fields(settings_class(algorithm))}
    merged: dict[str, Any] = {}
    where: dict[str, str] = {}
    for name, table in tables:
        for key, value in table.items():
            if key in merged:
                raise ValueError(f"{key} is given twice (at the {where[key]} and in {name})")
            if name == "[algo]" and key not in block_names:
                raise ValueError(f"[algo] holds {algorithm}'s own settings; {key!r} is not one of them (valid: "
                                 f"{sorted(block_names)})")
            merged[key], where[key] = value, name
    typed = _typed(merged, algorithm)
    _route(algorithm, dict(typed))  # names and types checked now, naming the valid keys
    return typed


def _typed(values: dict[str, Any], algorithm: str) -> dict[str, Any]:
    """File values as the fields' types: lists -> tuples, ints -> floats where the field is a float, strings parsed as
    ``--set`` parses them where the field is not a string. Unknown keys pass through (``_route`` refuses them)."""
    hints = {**typing.get_type_hints(TrainConfig), **_block_hints(settings_class(algorithm))}
    out = {}
    for key, value in values.items():
        hint = hints.get(key)
        if hint is None or hint is str:
            out[key] = value
        elif isinstance(value, str):
            out[key] = parse_value(key, value, hint)
        elif hint is float and _is_int(value):
            out[key] = float(value)
        elif getattr(hint, "__origin__", None) is tuple and isinstance(value, list):
            out[key] = tuple(value)
        else:
            out[key] = value
    return out


def _type_text(hint: Any) -> str:
    """A field's type as a file writes it: ``tuple[int, ...]`` is a list of ints (``--set``: "32,32")."""
    return "int list" if getattr(hint, "__origin__", None) is tuple else type_name(hint)


def _toml(value: Any) -> str:
    """A value as TOML writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _source_comments(klass: type) -> dict[str, str]:
    """The comments of ``klass``'s own annotated fields: the comment lines just above each and the one on its
    line(s)."""
    try:
        source = textwrap.dedent(inspect.getsource(klass))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    inline: dict[int, str] = {}
    try:
        for token in tokenize.generate_tokens(io.StringIO(source).readline):
            if token.type == tokenize.COMMENT:
                inline[token.start[0]] = token.string.lstrip("#").strip()
    except (tokenize.TokenError, SyntaxError):
        return {}
    tree = ast.parse(source)
    out = {}
    for node in tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else ():
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above = []
        row = node.lineno - 1  # 1-based line above the field
        while row >= 1 and lines[row - 1].strip().startswith("#"):
            above.insert(0, inline.get(row, ""))
            row -= 1
        on_line = [inline[r] for r in range(node.lineno, node.end_lineno + 1) if r in inline]
        text = " ".join(t for t in above + on_line if t)
        if text:
            out[node.target.id] = " ".join(text.split())
    return out


def _docstring_sentences(cls: type, name: str) -> str:
    """The sentences of the class docstrings along ``cls``'s MRO that name ````name````."""
    for klass in cls.__mro__:
        doc = klass.__dict__.get("__doc__") or ""
        if not doc or doc.startswith(f"{klass.__name__}("):  # a dataclass's generated signature
            continue
        text = " ".join(doc.split())
        sentences = re.split(r"(?<=[.!?])\s+(?=[A-Z`(])", text)
        found = [s for s in sentences if re.search(rf"``{name}(``|=)", s)]
        if found:
            return " ".join(found)
    return ""
